"""Channel meshes: a structured P1 triangulation of [0, Lx] × [0, Ly], periodic in x.

Node numbering of the periodic channel ("grid order"): node (iy, ix) is dof ``iy * nx + ix``,
with ix = 0 … nx−1 (x = ix·h; the seam x = Lx is the same node as x = 0) and
iy = 0 … ny−1 (y = iy·h; iy = 0 and iy = ny−1 are the walls). The walls carry the natural
(homogeneous Neumann) condition ∇φ·ŷ = 0: nothing is imposed on them.

The non-periodic mesh (nx + 1 columns of nodes, the last a copy of the first) is what is
written to and read from disk: scikit-fem's periodic meshes cannot be saved, so fields are
mapped onto the underlying non-periodic mesh for output.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from skfem import MeshTri

from femphase.config import DIAGONAL_PATTERNS
from femphase.errors import SceneError

__all__ = ["MAX_GRID_NODES", "ChannelGrid", "channel_grid", "grid_dof_map", "structured_channel_mesh"]

#: Most nodes a structured channel may have: 2·10⁷ nodes are ~1 GB of mesh and operators,
#: far beyond the paper's 17 000; a larger grid is almost always a mistyped Lx, Ly or h.
MAX_GRID_NODES = 20_000_000


@dataclass(frozen=True)
class ChannelGrid:
    """The node lattice of the periodic channel: nx × ny nodes with spacing h (lattice units)."""

    nx: int
    ny: int
    h: float

    @property
    def length(self) -> float:
        """Lx, the period in x."""
        return self.nx * self.h

    @property
    def width(self) -> float:
        """Ly, the distance between the walls."""
        return (self.ny - 1) * self.h

    @property
    def n_nodes(self) -> int:
        return self.nx * self.ny

    def coordinates(self) -> tuple[np.ndarray, np.ndarray]:
        """x (nx,) and y (ny,) coordinates of the node columns and rows."""
        return np.arange(self.nx) * self.h, np.arange(self.ny) * self.h


def channel_grid(length: float, width: float, spacing: float) -> ChannelGrid:
    """The grid of the channel [0, length) × [0, width]; both must be multiples of spacing."""
    if not spacing > 0:
        raise SceneError("domain.h", spacing, "the mesh spacing must be > 0")
    for key, extent in (("domain.Lx", length), ("domain.Ly", width)):
        if not extent > 0:
            raise SceneError(key, extent, "must be > 0")
        cells = extent / spacing
        if abs(cells - round(cells)) > 1e-9 * max(1.0, cells) or round(cells) < 2:
            raise SceneError(
                key, extent, f"must be a whole multiple (≥ 2) of the spacing h = {spacing}"
            )
    nx, ny = round(length / spacing), round(width / spacing) + 1
    if nx * ny > MAX_GRID_NODES:
        raise SceneError(
            "domain.h", spacing, f"a spacing that gives at most {MAX_GRID_NODES:.0e} nodes: domain.Lx = {length:g} "
            f"and domain.Ly = {width:g} at h = {spacing:g} make {nx * ny:.3g} nodes",
        )
    return ChannelGrid(nx=nx, ny=ny, h=float(spacing))


def structured_channel_mesh(grid: ChannelGrid, diagonals: str = "right") -> MeshTri:
    """The non-periodic P1 mesh of the channel, nodes ordered row by row (x fastest).

    ``diagonals``: "right" splits every cell along its rising diagonal, "left" along its
    falling one, "alternating" switches between them like a chequerboard. All three give
    right isosceles triangles, whose P1 stiffness matrix is the 5-point Laplacian.
    """
    if diagonals not in DIAGONAL_PATTERNS:
        raise SceneError("numerics.diagonals", diagonals, f"one of {DIAGONAL_PATTERNS}")
    columns = grid.nx + 1
    x = np.arange(columns) * grid.h
    y = np.arange(grid.ny) * grid.h
    points = np.stack([np.tile(x, grid.ny), np.repeat(y, columns)])
    ix, iy = np.meshgrid(np.arange(grid.nx), np.arange(grid.ny - 1))
    ix, iy = ix.ravel(), iy.ravel()
    sw = iy * columns + ix
    se, nw, ne = sw + 1, sw + columns, sw + columns + 1
    rising = np.full(sw.shape, diagonals != "left")
    if diagonals == "alternating":
        rising = (ix + iy) % 2 == 0
    lower = np.where(rising, np.stack([sw, se, ne]), np.stack([sw, se, nw]))
    upper = np.where(rising, np.stack([sw, ne, nw]), np.stack([se, ne, nw]))
    return MeshTri(points, np.hstack([lower, upper]))


def grid_dof_map(mesh: MeshTri, grid: ChannelGrid) -> np.ndarray:
    """For each node of a non-periodic channel mesh, its dof in grid order.

    Nodes on x = Lx are identified with their partners on x = 0. Raises SceneError when the
    mesh's nodes are not the nodes of ``grid`` (an unstructured mesh, or another spacing).
    """
    columns = mesh.p[0] / grid.h
    rows = mesh.p[1] / grid.h
    ix, iy = np.rint(columns).astype(int), np.rint(rows).astype(int)
    off_lattice = (np.abs(columns - ix) > 1e-6) | (np.abs(rows - iy) > 1e-6)
    outside = (ix < 0) | (ix > grid.nx) | (iy < 0) | (iy >= grid.ny)
    if off_lattice.any() or outside.any():
        raise SceneError(
            "domain.mesh",
            f"{int(off_lattice.sum() + outside.sum())} nodes off the lattice",
            f"a structured channel mesh with spacing {grid.h} on [0, {grid.length}] × [0, {grid.width}]",
        )
    dofs = iy * grid.nx + ix % grid.nx
    if np.unique(dofs).size != grid.n_nodes:
        raise SceneError(
            "domain.mesh", f"{np.unique(dofs).size} distinct nodes",
            f"every one of the {grid.n_nodes} lattice nodes exactly once (up to the periodic seam)",
        )
    return dofs
