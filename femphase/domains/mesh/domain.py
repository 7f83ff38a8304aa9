"""Meshed channels: any 2D triangulation, periodic in x, with named boundaries.

A channel is read from any file meshio reads (gmsh ``.msh``, ``.vtu``, ``.xdmf``, …):

* triangle cells are the domain (first-order triangles only: the phase fields are P1);
* line cells are boundary facets, each with an integer tag in the cell data
  (``gmsh:physical`` as gmsh writes it, or ``boundary``, ``medit:ref``, ``cell_tags``);
* tags are named by the file's ``field_data`` ``{name: [tag, 1]}`` when the format keeps it
  (gmsh's physical names), else by a mapping the caller passes, else by
  :data:`BOUNDARY_TAGS` (what ``meshes/make_*.py`` write into ``.vtu`` files, whose format
  drops ``field_data``);
* a file without line cells is a plain channel: its facets at the smallest and largest x are
  the periodic pair ``left``/``right``, every other boundary facet is a wall.

Two named boundaries, by default ``left`` and ``right``, are the periodic pair: both must be
straight sides x = const, and ``right`` must be ``left`` moved by the period along x (the
period is measured from the mesh). :func:`femphase.fem.periodic.periodic_dof_map` matches their
nodes by position and names any node without a partner. Every other boundary (``bottom``,
``top``, ``obstacle``, … and untagged boundary facets) is a wall: the phase fields carry the
natural (homogeneous Neumann) condition there, the Stokes flow no-slip.

Dofs of the periodic P1 space number the mesh's nodes with each right-side node identified
with its left-side partner; a dof's coordinates are its left-side node's, so x lies in
[x0, x0 + period). Lengths are in the mesh's unit (lattice units for femphase scenes).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Callable, Sequence

import meshio
import numpy as np
from scipy.spatial import cKDTree
from skfem import MeshTri

from femphase.config import Numerics
from femphase.domains.advection import nodal_velocity
from femphase.domains.base import DOMAINS, Domain
from femphase.domains.layout import Layout
from femphase.domains.mesh import semi_lagrangian
from femphase.domains.mesh.advection import GalerkinPade, GalerkinRungeKutta, TaylorGalerkin
from femphase.domains.mesh.boxes import Box, BoxPolicy, circular_extent
from femphase.domains.mesh.location import locate
from femphase.domains.mesh.shapes import Shape, ShapePolicy
from femphase.errors import SceneError
from femphase.fem.meshfiles import read_meshio
from femphase.fem.operators import (
    P1Operators,
    assemble_operators,
    element_gradients,
    shape_tensors,
)
from femphase.fem.periodic import fold_matrix, periodic_dof_map
from femphase.flows import Flow

__all__ = ["BOUNDARY_TAGS", "MESH_KEYS", "PERIODIC_PAIR", "TAG_KEYS", "MeshDomain", "PeriodicPairError",
           "channel_sides", "facet_indices", "mesh_checksum", "read_domain", "write_domain"]


#: Tag numbers of the boundary names when a file cannot store names (``.vtu``, ``.xdmf``).
BOUNDARY_TAGS = {"left": 1, "right": 2, "bottom": 3, "top": 4, "obstacle": 5, "wall": 6}
#: The default periodic pair: ``right`` is ``left`` moved by the period in +x.
PERIODIC_PAIR = ("left", "right")
#: Cell-data keys that may hold the line cells' integer tags, in order of preference.
TAG_KEYS = ("gmsh:physical", "boundary", "medit:ref", "cell_tags")


#: Keys of a ``[domain]`` table of kind "mesh".
MESH_KEYS = ("kind", "mesh", "h", "periodic", "boundaries", "Lx", "Ly")


#: How far a scene's nominal ``h`` may lie from the mesh's effective spacing √(area/dofs),
#: either way: room for graded meshes, not for an h that describes another mesh (its
#: margins, tolerances and resolution check would then be another mesh's).
NOMINAL_SPACING_FACTOR = 2.0
#: Nodes closer than this fraction of the median edge are one point meshed twice: a mesh of
#: pieces whose shared nodes were not merged (the closest distinct nodes of a valid mesh are
#: an edge apart, a graded mesh's shortest edge rarely below 1e-3 of its median).
COINCIDENT_NODES = 1e-6


class PeriodicPairError(ValueError):
    """The periodic pair names a boundary the mesh does not have, or one that is not a side
    x = const, or its sides in the wrong order (scene key domain.periodic)."""


@DOMAINS.register("mesh")
@dataclass(frozen=True, eq=False)
class MeshDomain(Domain):
    """Any triangle mesh meshio reads, periodic in x (keys: `mesh`, the file, relative to the
    scene; `periodic`, the periodic pair of boundary names, default ["left", "right"];
    `boundaries`, names of the file's integer tags; `h`, a nominal spacing, optional: without
    it the mesh is judged by its effective spacing √(area/dofs); `Lx`, `Ly`, if given, must
    match the mesh).

    A channel on a triangular mesh, periodic in x, with its P1 operators.

    ================ ============================================================================
    mesh             the non-periodic mesh as read (what output files are written on)
    boundaries       name → indices into ``mesh.facets`` of the boundary facets with that name
    periodic         the names of the periodic pair (min side, max side)
    period           the length of the periodic cell in x
    dof_map          (n_nodes,) the periodic dof of every mesh node (``dof_map`` of
                     every :class:`femphase.domains.base.Domain`, so output code serves both)
    operators        P1 mass, stiffness, lumped mass and element gradients on the dofs
    source           the mesh file it was read from ("" if built in memory: no Stokes cache then)
    nominal_spacing  the scene's ``h`` if it gave one (else :attr:`spacing` is the median edge)
    ================ ============================================================================
    """

    mesh: MeshTri
    boundaries: dict
    periodic: tuple
    period: float
    dof_map: np.ndarray
    operators: P1Operators
    source: str = ""
    nominal_spacing: float | None = None
    kind = "mesh"
    batched_solves = True

    @classmethod
    def from_mesh(
        cls,
        mesh: MeshTri,
        boundaries: dict[str, np.ndarray] | None = None,
        periodic: tuple[str, str] = PERIODIC_PAIR,
        tolerance: float | None = None,
    ) -> "MeshDomain":
        """Identify the periodic pair of ``mesh`` and assemble its operators.

        ``boundaries`` maps names to facet indices; without it, :func:`channel_sides` names
        the facets. ``tolerance`` (length) is the matching tolerance of the periodic nodes,
        by default 1e-8 of the period. Raises ValueError naming what does not match.
        """
        _check_mesh(mesh)
        return cls._from_checked_mesh(mesh, boundaries, periodic, tolerance)

    @classmethod
    def _from_checked_mesh(cls, mesh: MeshTri, boundaries: dict[str, np.ndarray] | None,
                           periodic: tuple[str, str], tolerance: float | None) -> "MeshDomain":
        """:meth:`from_mesh` for a mesh :func:`_check_mesh` has passed (a file's is checked
        before its boundaries are named; checking it again cost 60 ms on 40 000 nodes)."""
        boundaries = channel_sides(mesh) if boundaries is None else dict(boundaries)
        low, high = periodic
        for name in periodic:
            if name in boundaries and len(boundaries[name]) == 0:
                raise ValueError(f"the periodic boundary {name!r} has no facets (a side x = const)")
            if name not in boundaries:
                raise PeriodicPairError(
                    f"the periodic boundary {name!r} is not in the mesh; its boundaries are "
                    f"{sorted(boundaries)} (name the pair with domain.periodic = [min side, max side]; in a file "
                    "with tagged lines every untagged boundary facet is a wall, so the sides must be tagged too)"
                )
        low_nodes = np.unique(mesh.facets[:, boundaries[low]])
        high_nodes = np.unique(mesh.facets[:, boundaries[high]])
        x = mesh.p[0]
        # the mesh spans one period in x, from one side of the pair to the other
        tol = 1e-8 * float(np.ptp(x)) if tolerance is None else tolerance
        for name, nodes in ((low, low_nodes), (high, high_nodes)):
            if np.ptp(x[nodes]) > tol:
                raise PeriodicPairError(
                    f"the periodic boundary {name!r} is not a straight side x = const: its "
                    f"nodes span x from {x[nodes].min():.6g} to {x[nodes].max():.6g}"
                )
        period = float(np.mean(x[high_nodes]) - np.mean(x[low_nodes]))
        if not period > 0:
            raise PeriodicPairError(
                f"the periodic boundary {high!r} (at x = {np.mean(x[high_nodes]):.6g}) must lie "
                f"at larger x than {low!r} (at x = {np.mean(x[low_nodes]):.6g}): the pair is (min side, max side)"
            )
        side = np.concatenate([low_nodes, np.setdiff1d(high_nodes, low_nodes)])
        try:
            local = periodic_dof_map(mesh.p[:, side], period, axis=0, tol=tol)
        except ValueError as exc:
            raise ValueError(f"boundaries {low!r} and {high!r} are no periodic pair: {exc}") from None
        partner = np.arange(mesh.p.shape[1])
        partner[side] = side[local]
        _, dof_map = fold_matrix(partner)
        operators = assemble_operators(mesh, dof_map, int(dof_map.max()) + 1)
        return cls(mesh, boundaries, tuple(periodic), period, dof_map, operators)

    @classmethod
    def from_table(cls, table: dict, base_dir: Path, numerics: Numerics) -> "MeshDomain":
        for key, value in table.items():
            if key not in MESH_KEYS:
                raise SceneError(f"domain.{key}", value, f"not a key of a mesh domain; valid: {', '.join(MESH_KEYS)}")
        if not table.get("mesh") or not isinstance(table["mesh"], str):
            raise SceneError("domain.mesh", table.get("mesh"), "the mesh file of a mesh domain (a path relative "
                             "to the scene)")
        periodic = table.get("periodic", list(PERIODIC_PAIR))
        if (not isinstance(periodic, (list, tuple)) or len(periodic) != 2
                or not all(isinstance(name, str) and name for name in periodic) or periodic[0] == periodic[1]):
            raise SceneError("domain.periodic", periodic, "two different boundary names [min side, max side]")
        names = table.get("boundaries")
        if names is not None and not (
            isinstance(names, dict) and names
            and all(isinstance(tag, int) and not isinstance(tag, bool) for tag in names.values())
        ):
            raise SceneError("domain.boundaries", names, "a table {name = integer tag, …} of the file's line tags")
        for key in ("h", "Lx", "Ly"):
            value = table.get(key)
            if value is not None and not (isinstance(value, (int, float)) and not isinstance(value, bool)
                                          and np.isfinite(value) and value > 0):
                raise SceneError(f"domain.{key}", value, "a finite number > 0" + (" (the nominal spacing)" if key == "h"
                                                                                   else " (or leave it out)"))
        h = table.get("h")
        path = (base_dir / table["mesh"]).resolve()
        domain = read_domain(path, periodic=tuple(periodic), names=names)
        domain = replace(domain, source=str(path), nominal_spacing=None if h is None else float(h))
        for key, value in (("Lx", domain.period), ("Ly", domain.width)):
            if key in table and not np.isclose(table[key], value, rtol=1e-6):
                raise SceneError(f"domain.{key}", table[key], f"the mesh's value {value:g} (or leave it out)")
        measured = domain.effective_spacing
        if h is not None and not measured / NOMINAL_SPACING_FACTOR <= h <= measured * NOMINAL_SPACING_FACTOR:
            raise SceneError("domain.h", h, f"a nominal spacing within a factor {NOMINAL_SPACING_FACTOR:g} of the "
                             f"mesh's effective spacing √(area/dofs) = {measured:.3g}, i.e. from "
                             f"{measured / NOMINAL_SPACING_FACTOR:.3g} to {measured * NOMINAL_SPACING_FACTOR:.3g} "
                             f"(its median edge is {domain.median_edge:.3g}), or leave it out")
        return domain

    def describe(self) -> dict:
        return {"kind": self.kind, "n_dofs": self.n_dofs, "n_elements": int(self.mesh.t.shape[1]),
                "period": self.period, "mesh_checksum": mesh_checksum(self.mesh)}

    # -- geometry of the dofs --------------------------------------------------------------
    @cached_property
    def x0(self) -> float:
        """The x of the min periodic side; dof x lies in [x0, x0 + period)."""
        return float(self.mesh.p[0].min())

    @cached_property
    def coordinates(self) -> np.ndarray:
        """(2, n_dofs): x and y of every dof (x of its min-side node)."""
        out = np.empty((2, self.n_dofs))
        # the max-side copies are written first so their min-side partners overwrite them
        order = np.argsort(self.mesh.p[0])[::-1]
        out[:, self.dof_map[order]] = self.mesh.p[:, order]
        return out

    @cached_property
    def y_range(self) -> tuple[float, float]:
        """Lowest and highest y of the mesh (the walls' extremes)."""
        return float(self.mesh.p[1].min()), float(self.mesh.p[1].max())

    @cached_property
    def spacing(self) -> float:
        """The scene's nominal spacing ``h``, else the median edge length: the spacing of
        window margins and tolerances."""
        return self.median_edge if self.nominal_spacing is None else self.nominal_spacing

    @cached_property
    def effective_spacing(self) -> float:
        """√(area / dofs): the structured grid spacing with as many nodes per area, the
        resolution to compare with its h (a Delaunay mesh made for h,
        :func:`~femphase.domains.mesh.generation.edge_for_spacing`, has edges 1.07 h)."""
        return float(np.sqrt(self.area / self.n_dofs))

    @property
    def resolution(self) -> float:
        """The effective spacing √(area/dofs), or the nominal h where that is coarser: a mesh
        is judged by its node density, as the grid by its h, and a nominal h may judge it
        coarser, never finer than its nodes are."""
        nominal = self.nominal_spacing
        return self.effective_spacing if nominal is None or nominal < self.effective_spacing else nominal

    def coarse_area(self, length: float) -> float:
        """The fraction of the area whose local spacing √(m_k) exceeds ``length`` (m_k a
        dof's lumped mass, its share of the area; on a uniform mesh √(m_k) is its effective
        spacing within a few per cent: a Delaunay mesh made for h = 1 has 90 % of its area
        at ≤ 1.053, 0.25 % above 1.25). The effective spacing averages a graded mesh's fine
        and coarse parts."""
        mass = self.operators.lumped_mass
        return float(mass[mass > length**2].sum() / mass.sum())

    @cached_property
    def median_edge(self) -> float:
        """The median edge length (the window policy's spacing)."""
        ends = self.mesh.p[:, self.mesh.facets]
        return float(np.median(np.hypot(*(ends[:, 1] - ends[:, 0]))))

    @cached_property
    def wall_facets(self) -> np.ndarray:
        """Every boundary facet that is not on the periodic pair."""
        periodic = np.concatenate([self.boundaries[name] for name in self.periodic])
        return np.setdiff1d(self.mesh.boundary_facets(), periodic)

    def nodal(self, values: np.ndarray) -> np.ndarray:
        """Values given per dof (..., n_dofs) on every mesh node (..., n_nodes)."""
        return np.asarray(values)[..., self.dof_map]

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether points (x wrapped into the period) lie in the meshed domain."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        x = self.x0 + np.mod(x - self.x0, self.period)
        return locate(self.mesh, np.vstack([x.ravel(), y.ravel()])).reshape(x.shape) >= 0

    def wall_points(self) -> np.ndarray:
        return self.mesh.p[:, np.unique(self.mesh.facets[:, self.wall_facets])]

    def wall_normals(self) -> tuple[np.ndarray, np.ndarray]:
        ends = self.mesh.p[:, self.mesh.facets[:, self.wall_facets]]
        tangent = ends[:, 1] - ends[:, 0]
        return 0.5 * (ends[:, 0] + ends[:, 1]), np.stack([tangent[1], -tangent[0]]) / np.hypot(*tangent)

    # -- windows: the dofs inside boxes -----------------------------------------------------
    @cached_property
    def _dofs(self):
        """Per box: its dofs, for the last layout's boxes and those asked since (boxes last
        many substeps; a box left is rarely met again, and kept by count these took 36 MB)."""
        return self.caches.cache("window dofs")

    @property
    def extent(self) -> tuple[float, float, float, float]:
        low, high = self.y_range
        return (self.x0, self.period, low, high)

    def single_precision_steps(self, numerics: Numerics) -> bool:
        # the batched CG solves and the explicit advection apply block-diagonal matrices
        # in the fields' precision; per-box LU and Padé solves are double only
        # (docs/decisions/0028-single-precision-mesh-steps.md)
        return self.solves_batched(numerics)

    def window_policy(self, numerics: Numerics) -> BoxPolicy | ShapePolicy:
        """Shapes (:mod:`~femphase.domains.mesh.shapes`) by ``numerics.mesh_windows``, else
        boxes; a mesh without windows (``numerics.windows = false``) runs on the whole-domain
        box."""
        if numerics.windows and self.shaped_windows(numerics):
            return ShapePolicy.for_spacing(self.median_edge, threshold=numerics.threshold, margin=numerics.margin)
        # boxes refitted together serve the windows solved all at once: a layout costs the
        # same however many boxes change, a factorisation per box does not
        return BoxPolicy.for_spacing(self.median_edge, threshold=numerics.threshold, margin=numerics.margin,
                                     enabled=numerics.windows, together=self.solves_batched(numerics))

    def shaped_windows(self, numerics: Numerics) -> bool:
        """Whether ``numerics.mesh_windows`` asks for shapes: "shapes", or "auto" with the
        batched solves (a shape is its own window key: with a factorisation per key every
        shape made anew would be factorised anew, docs/decisions/0057-shaped-mesh-windows.md)."""
        return numerics.mesh_windows == "shapes" or (numerics.mesh_windows == "auto" and self.solves_batched(numerics))

    def full_window(self) -> Box:
        low, high = self.y_range
        return Box(self.x0, self.period, low, high)

    def disc_window(self, centre, reach: float, policy: BoxPolicy | ShapePolicy) -> Box | Shape:
        cx, cy = centre
        if isinstance(policy, ShapePolicy):
            return self._disc_shape(centre, reach, policy)
        return policy.cover((cx - reach, cx + reach), (cy - reach, cy + reach), self.extent)

    def _disc_shape(self, centre: tuple[float, float], reach: float, policy: ShapePolicy) -> Shape:
        """The shape made for the dofs within ``reach`` of ``centre``: the dofs within
        ``reach + policy.reach`` of it, each at its distance beyond ``reach`` (x by the
        minimum image)."""
        cx, cy = centre
        outer = reach + policy.reach()
        low, high = self.y_range
        box = Box(self.x0 + float(np.mod(cx - outer - self.x0, self.period)), min(2 * outer, self.period),
                  max(cy - outer, low), min(cy + outer, high))
        dofs = self._dofs_inside([box])[0]
        x, y = self.coordinates[:, dofs]
        distance = np.hypot(np.mod(x - cx + 0.5 * self.period, self.period) - 0.5 * self.period, y - cy)
        inside = distance <= outer
        return self._new_shape(dofs[inside].astype(np.int64), np.maximum(distance[inside] - reach, 0.0),
                               policy.reach())

    @cached_property
    def _shape_serials(self) -> list[int]:
        """[the serial of the next shape made] (:class:`Shape`: serials order shapes)."""
        return [0]

    def _new_shape(self, dofs: np.ndarray, distances: np.ndarray, reach: float) -> Shape:
        serial = self._shape_serials[0]
        self._shape_serials[0] += 1
        return Shape(serial, dofs, distances, float(reach))

    def window_dofs(self, window: Box | Shape) -> np.ndarray:
        """A shape's dofs, or the dofs inside the box, sorted (kept in :attr:`caches`: boxes
        last many substeps)."""
        if isinstance(window, Shape):
            return window.dofs
        return self._dofs.setdefault(window, lambda: self._dofs_inside([window])[0])

    def find_window_dofs(self, boxes: Sequence[Box]) -> None:
        """Find the dofs of every box of ``boxes`` not kept yet, all in one compiled call, and
        keep them for :meth:`window_dofs` (a refit that moves boxes early makes dozens)."""
        missing = list(dict.fromkeys(box for box in boxes if box not in self._dofs))
        for box, dofs in zip(missing, self._dofs_inside(missing)):
            self._dofs.put(box, dofs)

    #: Width of the strips :meth:`_dofs_inside` sorts the dofs into, in median edges.
    STRIP_EDGES = 2.0

    @cached_property
    def _strips(self) -> tuple[np.ndarray, np.ndarray, float, float, int]:
        """The dofs in vertical strips of x, sorted by strip then y, and their sort keys
        strip · span + (y − y_low), span longer than the channel is wide: (dofs in that
        order, their keys, the strips' width, span, number of strips)."""
        x, y = self.coordinates
        width = self.STRIP_EDGES * self.median_edge
        count = max(1, int(np.ceil(self.period / width)))
        strip = np.minimum(((x - self.x0) / width).astype(np.int64), count - 1)
        low, high = self.y_range
        span = 2.0 * (high - low) + 1.0
        keys = strip * span + (y - low)
        order = np.argsort(keys, kind="stable")
        return order, keys[order], width, span, count

    def _dofs_inside(self, boxes: Sequence[Box]) -> list[np.ndarray]:
        """The dofs inside each box, sorted: tested among the strips it crosses, each cut to
        the box's y-range, in one compiled pass over all boxes
        (:func:`~femphase.domains.mesh.kernels.dofs_in_boxes`). On examples/straight_mesh.toml
        a box of 32 × 32 (1019 dofs) costs 14 µs in a call of its own; the boxes a refit moves
        (about 90 under flow) share one call, 1.4 ms for 100."""
        from femphase.domains.mesh import kernels  # numba loads only where a mesh refits

        if not boxes:
            return []
        order, keys, width, span, count = self._strips
        x, y = self.coordinates
        dofs, offsets = kernels.dofs_in_boxes(order, keys, span, self.y_range[0], 1e-9 * span, x, y,
                                              self.windows_to_array(boxes), float(self.period), float(self.x0),
                                              width, count)
        # copies, so that a box kept alone does not hold the whole call's array
        return [dofs[offsets[b]:offsets[b + 1]].copy() for b in range(len(boxes))]

    @cached_property
    def advection_operators(self):
        """Per flow: its advection matrix and what is derived from it, shared by the flow's
        advections over every dt (:class:`~femphase.domains.mesh.advection.GalerkinAdvection`);
        and the map from any velocity at the quadrature points to the advection matrix
        (:class:`~femphase.domains.mesh.advection.QuadratureAdvection`)."""
        return self.caches.cache("advection operators")

    @cached_property
    def _last_layout(self):
        return self.caches.cache("layout")

    def _group_dofs(self, boxes: list[Box]) -> np.ndarray:
        """(k, size): the dofs of k equal boxes (one, but for particles sharing a box), a view
        where there is one."""
        dofs = self.window_dofs(boxes[0])
        return dofs[None] if len(boxes) == 1 else np.broadcast_to(dofs, (len(boxes), dofs.size))

    def layout(self, windows: Sequence[Box]) -> Layout:
        last = self._last_layout.get("last")
        if last is None or last.windows != tuple(windows):
            last = self._last_layout.put("last", Layout(
                windows, lambda box: box, self._group_dofs, lambda box: (self.window_dofs(box).size,),
                self.operators.lumped_mass))
            self._dofs.retain(set(last.windows))
        return last

    def refit(self, layout: Layout, phi: np.ndarray, policy: BoxPolicy | ShapePolicy,
              motion: Callable[[], np.ndarray] | None) -> tuple[Layout, np.ndarray]:
        """Boxes refitted to the field and to the coming step's motion (see BoxPolicy), or
        shapes made anew where their particles outgrew them (see ShapePolicy)."""
        if isinstance(policy, ShapePolicy):
            return self._refit_shapes(layout, phi, policy, motion)
        return self._refit_boxes(layout, phi, policy, motion)

    def _refit_boxes(self, layout: Layout, phi: np.ndarray, policy: BoxPolicy,
                     motion: Callable[[], np.ndarray] | None) -> tuple[Layout, np.ndarray]:
        from femphase.domains.mesh import kernels  # numba loads only where a mesh refits

        # a shape (a run resumed with boxes) counts as the whole period: it is boxed anew
        boxes = [w if isinstance(w, Box) else self.full_window() for w in layout.windows]
        steps = np.zeros((len(boxes), 2)) if motion is None else motion()
        extents = np.empty((len(boxes), 4))
        x, y = self.coordinates
        extents[layout.order] = kernels.occupied_extents(
            phi, layout.node_index, layout.offsets, x, y, np.array([boxes[i].x0 for i in layout.order]),
            float(self.period), float(policy.threshold))
        slot = layout.slots
        fitted = {i: self.full_window() for i, w in enumerate(layout.windows) if not isinstance(w, Box)}
        for i in np.flatnonzero(policy.misfits(extents, boxes, self.extent, steps)):
            box = boxes[i]
            if box.width >= self.period:
                part = slice(layout.offsets[slot[i]], layout.offsets[slot[i] + 1])
                x_range = circular_extent(x[layout.node_index[part]][phi[part] > policy.threshold], self.period)
            else:
                x_range = (box.x0 + extents[i, 0], box.x0 + extents[i, 1])
            new_box = policy.cover(x_range, tuple(extents[i, 2:]), self.extent, tuple(steps[i]))
            if new_box != layout.windows[i]:
                fitted[i] = new_box
        if not fitted:
            return layout, phi
        self.find_window_dofs(list(fitted.values()))
        return self._transferred(layout, phi, fitted)

    def _transferred(self, layout: Layout, phi: np.ndarray, replaced: dict) -> tuple[Layout, np.ndarray]:
        """(layout, φ) with the windows of particles ``replaced`` ({particle: window}) in
        place of ``layout``'s, each field carried over to its new window (zero where it was
        not) in one compiled pass (:func:`~femphase.domains.mesh.kernels.carry_over`); φ keeps
        its precision."""
        from femphase.domains.mesh import kernels  # numba loads only where a mesh refits

        particles = np.fromiter(replaced, dtype=np.int64, count=len(replaced))
        new_dofs = [self.window_dofs(window) for window in replaced.values()]
        dof_offsets = np.concatenate([[0], np.cumsum([dofs.size for dofs in new_dofs])]).astype(np.int64)
        carried = kernels.carry_over(phi, layout.node_index, layout.offsets, layout.slots[particles],
                                     np.concatenate(new_dofs).astype(np.int64), dof_offsets,
                                     self._carry_scratch(phi.dtype))
        fields, windows = layout.scatter(phi), list(layout.windows)
        for k, (i, window) in enumerate(replaced.items()):
            windows[i] = window
            fields[i] = carried[dof_offsets[k]:dof_offsets[k + 1]]
        refitted = self.layout(windows)
        return refitted, refitted.gather(fields)

    def _refit_shapes(self, layout: Layout, phi: np.ndarray, policy: ShapePolicy,
                      motion: Callable[[], np.ndarray] | None) -> tuple[Layout, np.ndarray]:
        """Shapes made anew for the particles :meth:`ShapePolicy.to_remake` names, each for
        its dofs where φ > threshold swept along its particle's ``motion()`` over the coming
        span (a window that is no shape, as after a resume with boxes: made anew at once;
        for a field that exceeds the threshold nowhere, its dofs kept), in compiled passes
        over all of them at once."""
        from femphase.domains.mesh import kernels  # numba loads only where a mesh refits

        # each position's distance to the set its shape was made for, and each shape's reach:
        # kept with the layout's blocks, asked at every substep (inf and −inf for a box)
        made, reaches = self.per_layout(layout, "shape distances", lambda: (np.concatenate([
            layout.windows[i].distances if isinstance(layout.windows[i], Shape)
            else np.full(layout.sizes[slot], np.inf) for slot, i in enumerate(layout.order)]),
            np.array([w.reach if isinstance(w, Shape) else -np.inf for w in layout.windows])))
        moved = np.empty(len(layout.windows))
        moved[layout.order] = kernels.largest_made_distance(phi, made, layout.offsets, float(policy.threshold))
        steps = np.zeros((len(layout.windows), 2)) if motion is None else motion()
        remade = policy.to_remake(moved, reaches, np.hypot(*steps.T))
        if not remade.any():
            return layout, phi
        particles = np.flatnonzero(remade)
        members, set_offsets = kernels.occupied_dofs(phi, layout.node_index, layout.offsets, layout.slots[particles],
                                                     float(policy.threshold))
        pieces = self._dilate(members, set_offsets, np.full(particles.size, policy.reach()), steps[particles])
        for k in np.flatnonzero(np.diff(set_offsets) == 0):
            dofs = self.window_dofs(layout.windows[particles[k]]).astype(np.int64)
            pieces[k] = (dofs, np.zeros(dofs.size))
        return self._transferred(layout, phi, {i: self._new_shape(dofs, distances, policy.reach())
                                               for i, (dofs, distances) in zip(particles, pieces)})

    def _carry_scratch(self, dtype) -> np.ndarray:
        """A zero array over the dofs in ``dtype``, kept (:func:`~femphase.domains.mesh.kernels.carry_over`
        leaves it zero)."""
        return self._carry_scratches.setdefault(np.dtype(dtype), np.zeros(self.n_dofs, dtype=dtype))

    @cached_property
    def _carry_scratches(self) -> dict:
        return {}

    @cached_property
    def _dilation_scratch(self) -> tuple[np.ndarray, ...]:
        """The scratch arrays of :func:`~femphase.domains.mesh.kernels.dilate`, kept: a
        refit of shapes makes dozens at once."""
        n = self.n_dofs
        return (np.full(n, np.inf), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
                np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64))

    def dilation(self, sets: Sequence[np.ndarray], reach: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """For each set of dofs, the dofs within ``reach`` of it (sorted) and their distances
        to it, measured along the mesh's edges (:func:`~femphase.domains.mesh.kernels.dilate`),
        all sets in one compiled call."""
        starts = np.concatenate([[0], np.cumsum([len(members) for members in sets])]).astype(np.int64)
        members = np.concatenate(sets).astype(np.int64) if sets else np.zeros(0, dtype=np.int64)
        return self._dilate(members, starts, np.full(len(sets), float(reach)), np.zeros((len(sets), 2)))

    def _dilate(self, members: np.ndarray, starts: np.ndarray, reaches: np.ndarray, motions: np.ndarray
                ) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`dilation` of the sets ``members[starts[k]:starts[k + 1]]``, set k swept
        along ``motions[k]`` and to ``reaches[k]``."""
        from femphase.domains.mesh import kernels  # numba loads only where a mesh refits

        x, y = self._contiguous_coordinates
        pattern = self.block_pattern
        capacity = 4 * int(starts[-1]) + 16  # doubled while too short
        while True:
            dofs, distances = np.empty(capacity, dtype=np.int64), np.empty(capacity)
            offsets = np.zeros(starts.size, dtype=np.int64)
            total = kernels.dilate(members, starts, pattern.indptr, pattern.indices, x, y, float(self.period),
                                   np.asarray(reaches, dtype=float), np.ascontiguousarray(motions, dtype=float),
                                   self._dilation_scratch, dofs, distances, offsets)
            if total >= 0:
                return [(dofs[offsets[k]:offsets[k + 1]].copy(), distances[offsets[k]:offsets[k + 1]].copy())
                        for k in range(starts.size - 1)]
            self._dilation_scratch[0][:] = np.inf  # a call cut short leaves its window's distances
            capacity *= 2

    @cached_property
    def _contiguous_coordinates(self) -> tuple[np.ndarray, np.ndarray]:
        return tuple(np.ascontiguousarray(c) for c in self.coordinates)

    def windows_to_array(self, windows: Sequence[Box | Shape]) -> np.ndarray:
        """A box as (x0, width, y0, y1); a shape as (serial, −1, dofs, reach), its dofs and
        distances in :meth:`window_positions`."""
        return np.array([[w.x0, w.width, w.y0, w.y1] if isinstance(w, Box) else [w.serial, -1.0, w.dofs.size, w.reach]
                         for w in windows], dtype=float).reshape(-1, 4)

    def window_positions(self, windows: Sequence[Box | Shape]) -> dict[str, np.ndarray]:
        """The shapes' dofs and distances, each concatenated in particle order."""
        shapes = [w for w in windows if isinstance(w, Shape)]
        if not shapes:
            return {}
        return {"shape_dofs": np.concatenate([w.dofs for w in shapes]),
                "shape_distances": np.concatenate([w.distances for w in shapes])}

    def windows_from_array(self, array: np.ndarray, positions: dict[str, np.ndarray] | None = None
                           ) -> list[Box | Shape]:
        rows = np.asarray(array, dtype=float).reshape(-1, 4)
        shaped = rows[:, 1] < 0
        if not shaped.any():
            return [Box(*map(float, row)) for row in rows]
        positions = positions or {}
        if "shape_dofs" not in positions or "shape_distances" not in positions:
            raise ValueError("shaped windows without their dofs and distances (shape_dofs, shape_distances)")
        cuts = np.cumsum(rows[shaped, 2].astype(np.int64))[:-1]
        pieces = zip(np.split(np.asarray(positions["shape_dofs"], dtype=np.int64), cuts),
                     np.split(np.asarray(positions["shape_distances"], dtype=float), cuts))
        windows = [Shape(int(row[0]), *next(pieces), float(row[3])) if row[1] < 0 else Box(*map(float, row))
                   for row in rows]
        serials = self._shape_serials
        serials[0] = max(serials[0], int(rows[shaped, 0].max()) + 1)  # shapes made after these order after them
        return windows

    # -- fast paths and flows ---------------------------------------------------------------
    def advection(self, flow: Flow, dt: float, numerics: Numerics
                  ) -> TaylorGalerkin | GalerkinRungeKutta | GalerkinPade | semi_lagrangian.SemiLagrangian:
        """By ``numerics.mesh_advection``: semi-Lagrangian in a steady flow ("auto": with the
        batched window solves, from the Courant number
        :data:`~femphase.domains.mesh.semi_lagrangian.COURANT` on; "semi-lagrangian": always;
        :mod:`femphase.domains.mesh.semi_lagrangian`); "runge-kutta": the explicit Runge–Kutta
        step; else the explicit Taylor–Galerkin step with the batched window solves and
        Galerkin–Padé, the exact-solve reference, with per-window factorisations
        (:mod:`femphase.domains.mesh.advection`)."""
        mode, batched = numerics.mesh_advection, self.solves_batched(numerics)
        if flow.steady and (mode == "semi-lagrangian" or mode == "auto" and batched and (
                semi_lagrangian.courant_number(self, nodal_velocity(self, flow), dt) >= semi_lagrangian.COURANT)):
            return semi_lagrangian.SemiLagrangian(self, flow, dt)
        if mode == "runge-kutta":
            return GalerkinRungeKutta(self, flow, dt, numerics)
        if not batched:
            return GalerkinPade(self, flow, dt, numerics)
        return TaylorGalerkin(self, flow, dt, numerics)

    def shape_moments(self, layout: Layout, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Area with the nodal quadrature; shape tensor the exact integral of the P1 element
        gradients (on an irregular mesh its O(h²) bias varies with position)."""
        area, tensors = np.empty(len(layout.windows)), np.empty((len(layout.windows), 2, 2))
        area[layout.order] = layout.reduce(np.add, layout.mass * phi**2)
        tensors[layout.order] = shape_tensors(self.operators, layout.node_index, layout.offsets, phi)
        return area, self.centroids(layout, phi), tensors


def _check_mesh(mesh: MeshTri) -> None:
    """Refuse triangulations that would run with a wrong domain: degenerate triangles,
    coincident nodes and edges shared by more than two triangles."""
    with np.errstate(divide="ignore", invalid="ignore"):  # a degenerate triangle's gradients: refused below
        _, areas = element_gradients(mesh)
    small = areas <= 1e-12 * np.median(areas)
    if small.any():
        k = int(np.flatnonzero(small)[0])
        corners = ", ".join(f"({a:.6g}, {b:.6g})" for a, b in mesh.p[:, mesh.t[:, k]].T)
        raise ValueError(f"{int(small.sum())} degenerate triangles (zero area), e.g. {corners}")
    edges = np.sort(mesh.t[[0, 1, 2, 1, 2, 0]].reshape(2, -1), axis=0).astype(np.int64)
    lengths = np.hypot(*(mesh.p[:, edges[1]] - mesh.p[:, edges[0]]))
    # pieces meshed apart and joined without merging their shared nodes: each piece's edge
    # along the seam is then a boundary facet, i.e. a no-slip wall inside the fluid
    # (a seam across the channel blocks it, and its Stokes flow is round-off scaled up)
    pairs = cKDTree(mesh.p.T).query_pairs(COINCIDENT_NODES * float(np.median(lengths)), output_type="ndarray")
    if len(pairs):
        x, y = mesh.p[:, pairs[0, 0]]
        raise ValueError(
            f"{len(pairs)} pairs of coincident nodes (closer than {COINCIDENT_NODES:g} of the median edge), e.g. at "
            f"({x:.6g}, {y:.6g}): pieces joined without merging their shared nodes, whose seam would be a wall "
            "inside the fluid; merge them (gmsh: Coherence, or remove duplicate nodes)")
    corners = np.sort(mesh.t, axis=0)
    order = np.lexsort(corners)
    repeated = order[1:][(np.diff(corners[:, order], axis=1) == 0).all(axis=0)]
    if repeated.size:
        corners = ", ".join(f"({a:.6g}, {b:.6g})" for a, b in mesh.p[:, mesh.t[:, repeated[0]]].T)
        raise ValueError(f"{repeated.size} triangles repeat others, e.g. {corners}")
    codes, counts = np.unique(edges[0] * mesh.p.shape[1] + edges[1], return_counts=True)
    if (counts > 2).any():
        a, b = np.divmod(codes[counts > 2][0], mesh.p.shape[1])
        raise ValueError(
            f"{int((counts > 2).sum())} edges belong to more than two triangles (repeated or overlapping "
            f"triangles), e.g. the edge from ({mesh.p[0, a]:.6g}, {mesh.p[1, a]:.6g}) to "
            f"({mesh.p[0, b]:.6g}, {mesh.p[1, b]:.6g})")


def channel_sides(mesh: MeshTri, tolerance: float | None = None) -> dict[str, np.ndarray]:
    """Names for an untagged channel: boundary facets at the smallest x are ``left``, at
    the largest x ``right``, all others ``wall``."""
    facets = mesh.boundary_facets()
    x = mesh.p[0, mesh.facets[:, facets]]
    tol = 1e-8 * np.ptp(mesh.p[0]) if tolerance is None else tolerance
    left = np.all(np.abs(x - mesh.p[0].min()) <= tol, axis=0)
    right = np.all(np.abs(x - mesh.p[0].max()) <= tol, axis=0)
    return {"left": facets[left], "right": facets[right], "wall": facets[~(left | right)]}


def facet_indices(mesh: MeshTri, lines: np.ndarray) -> np.ndarray:
    """Indices into ``mesh.facets`` of node pairs ``lines`` (2, n); raises when a pair is
    no edge of the mesh."""
    n = mesh.p.shape[1]
    # 64-bit keys: mesh indices are int32, whose n² overflows beyond 46 340 nodes
    keys = np.sort(mesh.facets, axis=0).astype(np.int64)
    keys = keys[0] * n + keys[1]
    wanted = np.sort(lines, axis=0).astype(np.int64)
    wanted = wanted[0] * n + wanted[1]
    order = np.argsort(keys)
    position = np.searchsorted(keys, wanted, sorter=order).clip(0, keys.size - 1)
    found = keys[order[position]] == wanted
    if not found.all():
        a, b = np.sort(lines, axis=0)[:, ~found][:, 0]
        raise ValueError(
            f"{int((~found).sum())} line cells are no edges of the triangles, e.g. the line "
            f"from ({mesh.p[0, a]:.6g}, {mesh.p[1, a]:.6g}) to ({mesh.p[0, b]:.6g}, {mesh.p[1, b]:.6g})"
        )
    return order[position]


def read_domain(
    path: str | Path,
    *,
    periodic: tuple[str, str] = PERIODIC_PAIR,
    names: dict[str, int] | None = None,
    tolerance: float | None = None,
) -> MeshDomain:
    """Read a meshed channel (see the module docstring for the file convention).

    ``names`` maps boundary names to the file's integer tags when the file cannot hold
    names itself; it overrides the file's names and :data:`BOUNDARY_TAGS`.
    Raises :class:`~femphase.errors.SceneError` (key ``domain.mesh``) when the file cannot
    be used, naming the reason.
    """
    data = read_meshio(path)
    try:
        mesh, lines, tags = _mesh_and_lines(data)
        _check_mesh(mesh)  # before the boundaries: a broken mesh breaks them, and would be blamed on them
        boundaries = None
        if names:
            _check_names(names, tags)
        if lines.shape[1]:
            table = names or _file_names(data) or BOUNDARY_TAGS
            boundaries = _named_facets(mesh, lines, tags, table)
        return MeshDomain._from_checked_mesh(mesh, boundaries, periodic, tolerance)
    except SceneError:
        raise
    except PeriodicPairError as exc:
        raise SceneError("domain.periodic", list(periodic), f"the names of two boundaries of {path} ({exc})") from None
    except Exception as exc:  # a damaged file fails anywhere: name the file and the reason
        reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
        raise SceneError("domain.mesh", str(path), f"a periodic channel mesh ({reason})") from None


def _mesh_and_lines(data: meshio.Mesh) -> tuple[MeshTri, np.ndarray, np.ndarray]:
    """The triangles as a MeshTri (unused points dropped) and the tagged line cells."""
    kinds = {block.type for block in data.cells}
    if "triangle" not in kinds:
        raise ValueError(f"no linear triangle cells (the file has {sorted(kinds)})")
    others = sorted(kinds - {"triangle", "line", "vertex"})
    if others:  # a part of the domain meshed in other cells would be left out, silently
        raise ValueError(f"cells other than linear triangles and boundary lines: {others}; the domain must be "
                         "meshed in linear triangles alone (the phase fields are P1)")
    if data.points.ndim != 2 or data.points.shape[1] < 2 or not np.isfinite(data.points).all():
        raise ValueError("the points are not finite (x, y) coordinates")
    if data.points.shape[1] > 2 and np.ptp(data.points[:, 2]) > 0:
        raise ValueError("the points are not in a plane z = const")
    triangles = np.vstack([b.data for b in data.cells if b.type == "triangle"])
    if triangles.size and (triangles.min() < 0 or triangles.max() >= len(data.points)):
        raise ValueError("triangles refer to points that are not in the file")
    used, renumbered = np.unique(triangles, return_inverse=True)
    new_index = np.full(len(data.points), -1)
    new_index[used] = np.arange(used.size)
    mesh = MeshTri(np.ascontiguousarray(data.points[used, :2].T, dtype=float),
                   np.ascontiguousarray(renumbered.reshape(triangles.shape).T, dtype=np.int64))
    key = next((k for k in TAG_KEYS if k in data.cell_data), None)
    _check_one_surface(data, key)
    line_blocks = [i for i, b in enumerate(data.cells) if b.type == "line"]
    if not line_blocks:
        return mesh, np.zeros((2, 0), dtype=int), np.zeros(0, dtype=int)
    if key is None:
        raise ValueError(
            f"line cells without integer tags (cell data {sorted(data.cell_data)}; expected "
            f"one of {list(TAG_KEYS)})"
        )
    lines = np.vstack([data.cells[i].data for i in line_blocks])
    tags = np.concatenate([np.asarray(data.cell_data[key][i]).ravel() for i in line_blocks])
    unused = np.flatnonzero((new_index[lines] < 0).any(axis=1))
    if unused.size:
        x, y = data.points[lines[unused[0]][new_index[lines[unused[0]]] < 0][0], :2]
        raise ValueError(f"{unused.size} line cells use points that belong to no triangle, e.g. the point "
                         f"({x:.6g}, {y:.6g}): lines drawn where no triangle is (a hole, or a solid left unmeshed)")
    lines = new_index[lines.T]
    return mesh, lines, tags.astype(int)


def _check_one_surface(data: meshio.Mesh, key: str | None) -> None:
    """Refuse triangles tagged as several physical surfaces: every triangle is taken as
    fluid, and a file that meshes a solid obstacle as a second surface would run through it."""
    if key is None:
        return
    tags = np.unique(np.concatenate([np.asarray(data.cell_data[key][i]).ravel()
                                     for i, block in enumerate(data.cells) if block.type == "triangle"]))
    if tags.size > 1:
        names = {int(np.ravel(v)[0]): name for name, v in data.field_data.items()
                 if np.size(v) >= 2 and int(np.ravel(v)[1]) == 2}
        surfaces = ", ".join(f"{int(t)} ({names[int(t)]})" if int(t) in names else str(int(t)) for t in tags)
        raise ValueError(f"the triangles belong to {tags.size} physical surfaces ({key}: {surfaces}); every "
                         "triangle is taken as fluid, so a solid meshed as a surface would be flowed through: "
                         "write the fluid as one physical surface (gmsh: Physical Surface(\"fluid\") = {…}) and "
                         "leave solids unmeshed")


def _check_names(names: dict[str, int], tags: np.ndarray) -> None:
    """SceneError (key ``domain.boundaries``) when the scene's names give one tag two names,
    or name a tag the file's line cells do not have."""
    named: dict[int, list[str]] = {}
    for name, tag in names.items():
        named.setdefault(tag, []).append(name)
    shared = {tag: group for tag, group in named.items() if len(group) > 1}
    if shared:
        tag, group = next(iter(shared.items()))
        raise SceneError("domain.boundaries", names, f"one name per tag (tag {tag} is named {', '.join(group)})")
    absent = sorted(set(named) - {int(t) for t in np.unique(tags)})
    if absent:
        have = ", ".join(str(int(t)) for t in np.unique(tags)) or "none"
        raise SceneError("domain.boundaries", names, f"names of the file's line tags ({have}); "
                         f"{', '.join(f'{named[t][0]} = {t}' for t in absent)} names a tag it does not have")


def _file_names(data: meshio.Mesh) -> dict[str, int]:
    """gmsh's physical names of dimension 1: {name: [tag, dim]} in field_data."""
    return {name: int(v[0]) for name, v in data.field_data.items()
            if np.size(v) >= 2 and int(np.ravel(v)[1]) == 1}


def _named_facets(mesh: MeshTri, lines: np.ndarray, tags: np.ndarray,
                  table: dict[str, int]) -> dict[str, np.ndarray]:
    facets = facet_indices(mesh, lines)
    by_tag = {tag: name for name, tag in table.items()}
    unknown = sorted(int(t) for t in set(np.unique(tags)) - set(by_tag))
    if unknown:
        raise ValueError(f"line tags {unknown} have no name (names: {table}); name them in the scene with "
                         "domain.boundaries = {left = TAG, right = TAG, …}")
    boundaries = {by_tag[t]: np.unique(facets[tags == t]) for t in np.unique(tags)}
    interior = np.setdiff1d(facets, mesh.boundary_facets())
    if interior.size:
        (xa, xb), (ya, yb) = mesh.p[:, mesh.facets[:, interior[0]]]
        raise ValueError(f"{interior.size} tagged line cells lie inside the domain, not on its boundary, e.g. the "
                         f"line from ({xa:.6g}, {ya:.6g}) to ({xb:.6g}, {yb:.6g})")
    untagged = np.setdiff1d(mesh.boundary_facets(), facets)
    if untagged.size:  # documented: untagged boundary is wall
        boundaries["wall"] = np.union1d(boundaries.get("wall", np.zeros(0, int)), untagged)
    return boundaries


def write_domain(path: str | Path, mesh: MeshTri, boundaries: dict[str, np.ndarray]) -> None:
    """Write ``mesh`` with its named boundary facets as tagged line cells.

    Tags follow :data:`BOUNDARY_TAGS` (so formats without names read back correctly);
    ``.msh`` files are written as gmsh 2.2 with the names as physical names.
    """
    path = Path(path)
    unknown = set(boundaries) - set(BOUNDARY_TAGS)
    if unknown:
        raise ValueError(f"boundary names {sorted(unknown)} are not in {sorted(BOUNDARY_TAGS)}")
    names = sorted(boundaries, key=BOUNDARY_TAGS.get)
    lines = np.hstack([mesh.facets[:, boundaries[n]] for n in names]).T
    tags = np.concatenate([np.full(len(boundaries[n]), BOUNDARY_TAGS[n]) for n in names])
    points = np.vstack([mesh.p, np.zeros(mesh.p.shape[1])]).T
    cells = [("triangle", mesh.t.T), ("line", lines)]
    tag_data = [np.zeros(mesh.t.shape[1], dtype=int), tags]
    field_data = {n: np.array([BOUNDARY_TAGS[n], 1]) for n in names}
    if path.suffix == ".msh":
        cell_data = {"gmsh:physical": tag_data, "gmsh:geometrical": tag_data}
        meshio.write(path, meshio.Mesh(points, cells, cell_data=cell_data, field_data=field_data),
                     file_format="gmsh22", binary=False)
    else:
        meshio.write(path, meshio.Mesh(points, cells, cell_data={"boundary": tag_data},
                                       field_data=field_data))


def mesh_checksum(mesh: MeshTri) -> str:
    """A short digest of a mesh's nodes and triangles (checkpoints record it)."""
    digest = hashlib.sha256()
    for array in (mesh.p, mesh.t):
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:16]
