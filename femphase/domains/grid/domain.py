"""The structured periodic channel (``[domain] kind = "grid"``): the Domain with fast paths.

The channel [0, Lx) × [0, Ly] is a lattice of nx × ny nodes of spacing h (:mod:`femphase.domains.grid.lattice`),
triangulated with right isosceles triangles. Dof (iy, ix) is ``iy * nx + ix`` ("grid order").
Its fast paths, all exact or checked against the general ones:

* windows are rectangular node blocks (:class:`femphase.domains.grid.windows.Window`); windows of one
  shape share one system matrix, one solver and one multi-right-hand-side solve;
* with one diagonal direction and the lumped mass, a window's matrix is the tensor product
  a My⊗Mx + b (Ky⊗Mx + My⊗Kx) of 1D P1 operators, solved exactly by
  :class:`femphase.fem.solvers.TensorSolver` (used only after checking the assembled block
  entry by entry);
* row flows (u(y, t), 0) are advected by an exact shift of every row
  (:class:`femphase.domains.grid.advection.RowShift`); other flows semi-Lagrangian;
* shape tensors use nodal central differences, which have the lattice's square symmetry
  (a centred disc has elongation exactly 0).
"""

from __future__ import annotations

from functools import cache, cached_property
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from femphase.config import Numerics
from femphase.domains.base import DOMAINS, Domain
from femphase.domains.grid.advection import RowShift, SemiLagrangian
from femphase.domains.grid.lattice import (
    ChannelGrid,
    channel_grid,
    grid_dof_map,
    structured_channel_mesh,
)
from femphase.domains.grid.windows import (
    GridLayout,
    Window,
    WindowPolicy,
    pad_window,
    transfer,
    window_corners,
)
from femphase.domains.layout import Layout
from femphase.errors import SceneError
from femphase.fem.meshfiles import load_mesh
from femphase.fem.operators import assemble_operators, line_operators
from femphase.fem.solvers import TensorBasis, TensorSolver
from femphase.flows import Flow
from femphase.placement import random_centres

__all__ = ["GRID_KEYS", "TENSOR_MAX_SIDES", "GridDomain", "RowOffsets", "tensor_basis", "tensor_solver"]


#: ``solver = "auto"`` uses the tensor solver for windows up to this ny + nx (nodes):
#: benchmarks/solver_crossover.py measured it 1.5–3.7× faster than the cached LU up to
#: 256 × 256 nodes (ny + nx = 512) and 0.8–1.0× from ny + nx = 621 on (its dense products
#: grow as (ny + nx)·ny·nx, the LU's triangular solves slower).
TENSOR_MAX_SIDES = 512

#: Keys of a ``[domain]`` table of kind "grid".
GRID_KEYS = ("kind", "Lx", "Ly", "h", "mesh")


@DOMAINS.register("grid")
class GridDomain(Domain):
    """The structured channel (keys: `Lx`, `Ly` lengths, multiples of the spacing `h`, lattice
    units; optional `mesh`, a meshio file of the same lattice's triangulation)."""

    kind = "grid"

    def __init__(self, grid: ChannelGrid, diagonals: str = "right", mesh=None) -> None:
        """``mesh``: a non-periodic MeshTri whose nodes are the grid's (e.g. read from a
        file); by default the structured triangulation with ``diagonals``."""
        self.grid = grid
        self.mesh = structured_channel_mesh(grid, diagonals) if mesh is None else mesh
        self.dof_map = grid_dof_map(self.mesh, grid)
        self.operators = assemble_operators(self.mesh, self.dof_map, grid.n_nodes)
        self.alternating = _has_alternating_diagonals(self.mesh, grid)
        self.period, self.spacing = grid.length, grid.h
        self.lattice = (grid.ny, grid.nx)
        self._layout: Layout | None = None
        #: the rows of the last layout moved to: what a move that keeps them reuses
        self._rows: RowOffsets | None = None
        lumped = self.operators.lumped_mass.reshape(grid.ny, grid.nx)
        #: the lumped mass of every row where it depends on the row alone (then a move along
        #: x keeps it), else None
        self._row_mass = lumped[:, 0].copy() if np.all(lumped == lumped[:, :1]) else None

    @classmethod
    def from_table(cls, table: dict, base_dir: Path, numerics: Numerics) -> "GridDomain":
        for key, value in table.items():
            if key not in GRID_KEYS:
                raise SceneError(f"domain.{key}", value, f"not a key of a grid domain; valid: {', '.join(GRID_KEYS)}")
        sizes = {key: table.get(key, default) for key, default in (("Lx", 70.0), ("Ly", 240.0), ("h", 1.0))}
        for key, value in sizes.items():
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value) and value > 0):
                raise SceneError(f"domain.{key}", value, "a finite number > 0 (lattice units)")
        grid = channel_grid(sizes["Lx"], sizes["Ly"], sizes["h"])
        mesh = load_mesh(base_dir / table["mesh"]) if table.get("mesh") else None
        try:
            return cls(grid, numerics.diagonals, mesh)
        except SceneError as exc:  # the mesh's nodes are not the lattice's: name the file, not a count
            if exc.key != "domain.mesh":
                raise
            raise SceneError("domain.mesh", table["mesh"], f"{exc.valid} ({exc.value}; a mesh of other nodes is "
                             'a domain of kind "mesh")') from None

    def describe(self) -> dict:
        return {"kind": self.kind, "nx": self.grid.nx, "ny": self.grid.ny, "h": self.grid.h,
                "n_dofs": self.n_dofs, "alternating": self.alternating}

    # -- geometry -------------------------------------------------------------------------
    @property
    def coordinates(self) -> np.ndarray:
        x, y = self.grid.coordinates()
        return np.stack([np.tile(x, self.grid.ny), np.repeat(y, self.grid.nx)])

    @property
    def y_range(self) -> tuple[float, float]:
        return 0.0, self.grid.width

    @property
    def x0(self) -> float:
        return 0.0

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return (np.asarray(y) >= 0) & (np.asarray(y) <= self.grid.width) & np.isfinite(x)

    def random_centres(self, n: int, radius: float, seed: int) -> np.ndarray:
        """The rectangle's own sampler (x uniform in [0, Lx), y in [radius, Ly − radius]),
        whose seeded layouts the verification runs use."""
        return random_centres(n, self.grid.length, self.grid.width, radius, seed)

    def wall_points(self) -> np.ndarray:
        x, _ = self.grid.coordinates()
        return np.stack([np.concatenate([x, x]), np.concatenate([np.zeros_like(x), np.full_like(x, self.grid.width)])])

    def wall_normals(self) -> tuple[np.ndarray, np.ndarray]:
        points = self.wall_points()
        points[0] += 0.5 * self.grid.h  # the facets' midpoints
        return points, np.stack([np.zeros(points.shape[1]), np.ones(points.shape[1])])

    # -- windows --------------------------------------------------------------------------
    def single_precision_steps(self, numerics: Numerics) -> bool:
        # the tensor solves and row shifts have single-precision paths
        # (docs/decisions/0012-single-precision-flow-steps.md)
        return True

    def window_policy(self, numerics: Numerics) -> WindowPolicy:
        return WindowPolicy.for_spacing(self.grid.h, threshold=numerics.threshold, margin=numerics.margin,
                                        enabled=numerics.windows)

    def full_window(self) -> Window:
        return Window(0, self.grid.ny, 0, self.grid.nx)

    def disc_window(self, centre, reach: float, policy: WindowPolicy) -> Window:
        grid, (cx, cy) = self.grid, centre
        rows = (max(0, int(np.floor((cy - reach) / grid.h))), min(grid.ny - 1, int(np.ceil((cy + reach) / grid.h))))
        cols = (int(np.floor((cx - reach) / grid.h)), int(np.ceil((cx + reach) / grid.h)))
        return policy.cover(rows, cols, self.lattice)

    def window_dofs(self, window: Window) -> np.ndarray:
        return (window.rows()[:, None] * self.grid.nx + window.columns(self.grid.nx)[None, :]).ravel()

    def window_key(self, window: Window) -> tuple:
        return window.key(self.grid.ny, self.grid.nx, self.alternating)

    def _group_dofs(self, windows: list[Window]) -> np.ndarray:
        w = windows[0]
        iy0 = np.array([v.iy0 for v in windows])
        ix0 = np.array([v.ix0 for v in windows])
        rows = iy0[:, None, None] + np.arange(w.ny)[None, :, None]
        cols = (ix0[:, None, None] + np.arange(w.nx)[None, None, :]) % self.grid.nx
        return (rows * self.grid.nx + cols).reshape(len(windows), -1)

    def layout(self, windows: Sequence[Window]) -> Layout:
        # the last layout is reused while the windows do not change (most steps), and moved
        # while only their positions do (every advection)
        last, windows = self._layout, tuple(windows)
        if last is not None and last.windows == windows:
            return last
        if last is not None and len(last.windows) == len(windows) and self._same_keys(last.windows, windows):
            self._layout = self._moved(last, windows)
        else:
            self._layout = GridLayout(windows, self.window_key, self._group_dofs, self.operators.lumped_mass,
                                      self.lattice)
        return self._layout

    def _same_keys(self, old: Sequence[Window], new: Sequence[Window]) -> bool:
        """Whether every window of ``new`` has the key of its counterpart in ``old``. A window
        moved along its rows keeps its key (bar the parity of alternating diagonals); only the
        others need theirs built (twice as fast as building all keys: the advection moves
        most windows every substep)."""
        key, parity_free = self.window_key, not self.alternating
        return all(a is b or (parity_free and a.iy0 == b.iy0 and a.ny == b.ny and a.nx == b.nx) or key(a) == key(b)
                   for a, b in zip(old, new))

    def moved_along_rows(self, layout: GridLayout, first_columns: np.ndarray) -> GridLayout:
        """``layout`` with its windows' first columns (layout order) moved to
        ``first_columns``, their rows and shapes kept: the advection's whole-node moves,
        whose keys stay (with alternating diagonals an odd move changes a key's parity: then
        the layout is regrouped as any other)."""
        moving = np.flatnonzero(first_columns != layout.corners[:, 2])
        if moving.size == 0:
            return layout
        windows = list(layout.windows)
        for slot in moving:
            i = layout.order[slot]
            w = windows[i]
            windows[i] = Window(w.iy0, w.ny, int(first_columns[slot]), w.nx)
        if self.alternating:
            return self.layout(windows)
        corners = layout.corners.copy()
        corners[:, 2] = first_columns
        self._layout = self._moved(layout, tuple(windows), corners)
        return self._layout

    def _moved(self, last: Layout, windows: tuple[Window, ...], corners: np.ndarray | None = None) -> Layout:
        """``last`` with its windows moved to ``windows`` (of the same keys; ``corners``, in
        layout order, if known), their corners given (:attr:`GridLayout.corners`, all the
        substeps' sums over windows need). Its dofs and lumped masses are computed on first
        use: a substep moves the layout twice (the advection, then the refit's recentred
        windows) and, the sums running from the corners, needs the dofs of
        neither (at γ̇ = 1 on the random packing, 0.2–0.3 ms a move); frames and T1 looks
        still use them. The dofs of all positions come at once from the windows' corners
        and :attr:`Layout.cells`; their rows' part, and the masses where they depend on the
        row alone, are shared by the moves that keep the rows (the advection's)."""
        slot, row, column = last.cells
        if corners is None:
            corners = window_corners([windows[i] for i in last.order])
        iy0, ix0 = corners[:, 0], corners[:, 2]
        rows = self._rows
        # the cache describes ``last`` itself: it is the layout the last move made (a layout
        # built afresh has new groups)
        if rows is None or rows.groups is not last.groups or not np.array_equal(rows.iy0, iy0):
            rows = self._rows = RowOffsets(last.groups, iy0, slot, row, self.grid.nx, self._row_mass, last.offsets,
                                           corners)
        nx, lumped = self.grid.nx, self.operators.lumped_mass

        @cache
        def node_index() -> np.ndarray:
            dofs = np.take(ix0, slot)
            dofs += column
            np.subtract(dofs, nx, out=dofs, where=dofs >= nx)  # 0 ≤ ix0 < nx and column < nx
            dofs += rows.offsets
            return dofs

        mass = (lambda: rows.mass) if self._row_mass is not None else (lambda: lumped[node_index()])
        moved = last.moved(windows, node_index, mass)
        moved.corners = corners
        return moved

    def refit(self, layout: Layout, phi: np.ndarray, policy: WindowPolicy,
              motion: Callable[[], np.ndarray] | None) -> tuple[Layout, np.ndarray]:
        if not policy.enabled:
            return layout, phi
        boxes = policy.occupied(layout, phi)
        misfits = np.flatnonzero(policy.misfits(layout, phi, self.lattice, boxes))
        windows, changed = list(layout.windows), {}  # changed: slot → the field on its new window
        for slot in misfits:
            i = layout.order[slot]
            w = windows[i]
            field = phi[layout.offsets[slot]:layout.offsets[slot + 1]].reshape(w.shape)
            fitted = policy.fit(field, w, self.lattice, boxes[slot])
            if fitted != w:
                changed[slot] = transfer(field, w, fitted, self.grid.nx).ravel()
                windows[i] = fitted
        if not changed:  # most substeps
            return layout, phi
        refitted = self.layout(windows)
        if refitted.groups is not layout.groups:  # a window changed shape: new groups
            fields = layout.scatter(phi)
            for slot, field in changed.items():
                fields[layout.order[slot]] = field
            return refitted, refitted.gather(fields)
        # windows moved within their groups (under shear nearly every refit: recentred
        # windows, :meth:`WindowPolicy.fit`): the same slots, only theirs rewritten (with a
        # scatter and gather of all windows a refit takes 0.91 ms at γ̇ = 1 instead of 0.83)
        phi = phi.copy()
        for slot, field in changed.items():
            phi[layout.offsets[slot]:layout.offsets[slot + 1]] = field
        return refitted, phi

    def windows_to_array(self, windows: Sequence[Window]) -> np.ndarray:
        return window_corners(windows)

    def windows_from_array(self, array: np.ndarray, positions: dict[str, np.ndarray] | None = None) -> list[Window]:
        return [Window(*map(int, row)) for row in array]

    # -- fast paths -----------------------------------------------------------------------
    def solver(self, window: Window, block: Callable[[], sp.csr_matrix], a: float, b: float, lumped: bool,
               method: str, tolerance: float):
        if lumped and (method == "tensor" or (method == "auto" and window.ny + window.nx <= TENSOR_MAX_SIDES)):
            # the eigenpairs depend on the window's shape only (its key), not on a and b: a
            # new time step size then costs one division per node, which lets the adaptive
            # scheme choose its substeps freely
            basis = self._tensor_bases.setdefault(self.window_key(window),
                                                  lambda: tensor_basis(block(), window, self.grid, a, b))
            if basis is not None:
                return basis.solver(a, b)
        return super().solver(window, block, a, b, lumped, method, tolerance)

    @cached_property
    def _tensor_bases(self):
        """Per window key: its :class:`~femphase.fem.solvers.TensorBasis`, or None where the
        tensor solver does not apply."""
        return self.caches.cache("tensor bases")

    def advection(self, flow: Flow, dt: float, numerics: Numerics) -> RowShift | SemiLagrangian:
        if flow.row_velocity is not None:
            return RowShift(self, flow, dt)
        return SemiLagrangian(self, flow, dt)

    def shape_moments(self, layout: Layout, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Area, centroid and shape tensor with the nodal quadrature; the shape tensor
        R_i = −Σ_k m_k ∇_h φ_ik ∇_h φ_ikᵀ with central differences ∇_h, the field mirrored at
        the walls (∂yφ = 0) and zero beyond a window's edge; in double whatever φ's precision."""
        h = self.grid.h
        n = len(layout.windows)
        area, tensors = np.empty(n), np.empty((n, 2, 2))
        for group, (_, members, start, stop, _) in enumerate(layout.groups):
            w = layout.representative(group)
            # a single-precision step's fields differenced in float32 round each gradient to
            # 1e-7 (relative): the shapes of the same values in double
            block = layout.group_block(phi, group).astype(np.float64, copy=False)  # (k, ny, nx)
            mass = layout.mass[start:stop].reshape(block.shape)[0]
            area[members] = np.einsum("kij,ij,kij->k", block, mass, block)
            padded = pad_window(block, w, self.lattice, 1)
            dx = (padded[:, 1:-1, 2:] - padded[:, 1:-1, :-2]) / (2 * h)
            dy = (padded[:, 2:, 1:-1] - padded[:, :-2, 1:-1]) / (2 * h)
            xx, yy, xy = (-np.einsum("kij,ij,kij->k", a, mass, b) for a, b in ((dx, dx), (dy, dy), (dx, dy)))
            tensors[members] = np.stack([np.stack([xx, xy], -1), np.stack([xy, yy], -1)], -2)
        return area, self.centroids(layout, phi), tensors


class RowOffsets:
    """The rows of a moved layout's positions (:meth:`GridDomain._moved`): its groups, its
    windows' first rows in layout order, and, computed on first use, each position's row
    times nx (its dof at column 0) and, for a lumped mass that depends on the row alone
    (``row_mass``, per lattice row), each position's mass (from the windows' ``offsets``
    and ``corners``, :func:`femphase.domains.grid.kernels.row_values`)."""

    def __init__(self, groups: list, iy0: np.ndarray, slot: np.ndarray, row: np.ndarray, nx: int,
                 row_mass: np.ndarray | None, offsets: np.ndarray, corners: np.ndarray) -> None:
        self.groups, self.iy0 = groups, iy0
        self._slot, self._row, self._nx = slot, row, nx
        self._row_mass, self._offsets, self._corners = row_mass, offsets, corners

    @cached_property
    def offsets(self) -> np.ndarray:
        offsets = np.take(self.iy0, self._slot)
        offsets += self._row
        offsets *= self._nx
        return offsets

    @cached_property
    def mass(self) -> np.ndarray:
        from femphase.domains.grid import (
            kernels,  # numba loads only where a scene needs it
        )

        return kernels.row_values(self._row_mass, self._offsets, self._corners)


def _has_alternating_diagonals(mesh, grid: ChannelGrid) -> bool:
    """True unless every cell is split along the same diagonal (then windows of a shape share
    one submatrix regardless of position)."""
    p = mesh.p[:, mesh.t] / grid.h
    spans = np.ptp(p[0], axis=0) + np.ptp(p[1], axis=0)  # 2 for the right-angle triangles
    corner_sum = np.rint(p[0] + p[1]).astype(int)
    rising = (np.ptp(corner_sum, axis=0) == 2) & (spans == 2)
    return bool(rising.any() and not rising.all())


def tensor_basis(block: sp.spmatrix, window: Window, grid: ChannelGrid, a: float, b: float) -> TensorBasis | None:
    """The :class:`TensorBasis` of ``window`` when ``block`` = a M_L + b K on its nodes is the
    tensor product of 1D P1 operators, None when it is not (alternating diagonals, a file
    mesh, a consistent mass), checked entry by entry against the assembled block."""
    rows, columns = window.rows(), window.columns(grid.nx)
    factors = []
    for n_nodes, periodic, keep in ((grid.ny, False, rows), (grid.nx, True, columns)):
        mass, stiffness = line_operators(n_nodes, grid.h, periodic)
        factors.append(tuple(m[keep][:, keep] for m in (mass, stiffness)))
    (my, ky), (mx, kx) = factors
    candidate = a * sp.kron(my, mx) + b * (sp.kron(ky, mx) + sp.kron(my, kx))
    if abs(candidate - block).max() > 1e-12 * abs(block).max():
        return None
    return TensorBasis((my.toarray(), ky.toarray()), (mx.toarray(), kx.toarray()))


def tensor_solver(block: sp.spmatrix, window: Window, grid: ChannelGrid, a: float, b: float) -> TensorSolver | None:
    """A :class:`TensorSolver` for ``block`` = a M_L + b K on ``window``'s nodes, or None when
    the block is not that tensor product (:func:`tensor_basis`)."""
    basis = tensor_basis(block, window, grid, a, b)
    return None if basis is None else basis.solver(a, b)
