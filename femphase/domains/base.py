"""The Domain interface: where the phase fields live, and what a time step asks of it.

A domain is a P1 space on a triangulated channel, periodic in x with period ``period``,
bounded by walls that carry the natural (homogeneous Neumann) condition ∇φ·n = 0. It owns

* geometry: dof coordinates (2, n_dofs), the period, the walls' y-range, the spacing h;
* operators: the assembled P1 mass, stiffness, lumped mass and element gradients
  (:class:`femphase.fem.operators.P1Operators`) on its periodic dofs;
* output: the non-periodic mesh and ``dof_map`` (mesh node → dof) that files are written on;
* windows: how a window covers a particle (:meth:`window_policy`, :meth:`disc_window`,
  :meth:`refit`), which dofs it holds, and how windows are grouped (:meth:`layout`);
* fast paths: a solver for a window's system (:meth:`solver`), advection in a flow
  (:meth:`advection`), shape moments (:meth:`shape_moments`);
* memory: :attr:`caches`, the one byte budget of everything the run keeps for reuse, its
  own caches' and those of the steppers and advections on it (:mod:`femphase.caches`).

Two implementations are registered in :data:`DOMAINS` under the scene's ``[domain] kind``:
``grid``, the structured channel (:class:`femphase.domains.grid.domain.GridDomain`: rectangular
windows, the exact tensor-product solver and the exact row-shift advection are its fast
paths), and ``mesh``, any meshio triangle mesh (:class:`femphase.domains.mesh.domain.MeshDomain`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import cached_property
from typing import Callable, ClassVar, Hashable, Protocol, Sequence

import numpy as np
import scipy.sparse as sp

from femphase.caches import ByteBudget, nbytes_of
from femphase.config import Numerics
from femphase.domains.layout import Layout
from femphase.fem.blocks import BlockPattern, aligned_data
from femphase.fem.operators import P1Operators
from femphase.fem.solvers import make_solver
from femphase.flows import Flow
from femphase.model.parameters import interface_profile
from femphase.placement import random_centres_inside
from femphase.registry import Registry

__all__ = ["DOMAINS", "Advection", "Domain", "window_block"]


class Advection(Protocol):
    """Advection over one step of fixed dt, split from the relaxation."""

    def advect(self, phi: np.ndarray, layout: Layout, time: float) -> tuple[np.ndarray, Layout]:
        """φ (layout order) advected from ``time`` over dt (``phi`` may be overwritten), and
        the layout it lives on after."""


class Domain(ABC):
    """A periodic channel with walls and its P1 space (see the module docstring)."""

    kind: ClassVar[str]
    #: whether ``numerics.solver = "auto"`` solves all windows at once by a Krylov method on
    #: their block-diagonal matrix (:mod:`femphase.fem.blocks`) rather than one solver per
    #: window key: meshes, whose every box is its own submatrix, so a factorisation per box
    #: would be built for one window and rebuilt whenever the box changes
    batched_solves: ClassVar[bool] = False
    operators: P1Operators
    mesh: object          # the non-periodic skfem.MeshTri
    dof_map: np.ndarray   # (n_mesh_nodes,) the dof of every mesh node
    period: float
    spacing: float

    # -- geometry -----------------------------------------------------------------------
    @property
    def n_dofs(self) -> int:
        return self.operators.lumped_mass.size

    @property
    def resolution(self) -> float:
        """The spacing that judges how well the domain resolves an interface (the checks
        h ≤ λ and the adaptive scheme's fine-grid tolerance): here :attr:`spacing`."""
        return self.spacing

    def coarse_area(self, length: float) -> float:
        """The fraction of the area whose local spacing exceeds ``length`` (a graded mesh's
        check of its coarse parts); here the spacing is one everywhere: 0 or 1."""
        return float(self.resolution > length)

    @property
    @abstractmethod
    def coordinates(self) -> np.ndarray:
        """(2, n_dofs): x and y of every dof, x in [x0, x0 + period)."""

    @property
    @abstractmethod
    def y_range(self) -> tuple[float, float]:
        """Lowest and highest y of the domain (the walls' extremes)."""

    @property
    def x0(self) -> float:
        return float(self.mesh.p[0].min())

    @property
    def width(self) -> float:
        """Ly: the distance between the lowest and highest wall points."""
        low, high = self.y_range
        return high - low

    @property
    def area(self) -> float:
        return float(self.operators.element_area.sum())

    @abstractmethod
    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether points (x wrapped into the period) lie in the domain."""

    @abstractmethod
    def wall_points(self) -> np.ndarray:
        """(2, n) points on the walls (for keeping initial discs clear of them)."""

    @abstractmethod
    def wall_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """(points, normals), each (2, n): the midpoints of the walls' facets and their unit
        normals (either sign), where a flow must be tangential."""

    def random_centres(self, n: int, radius: float, seed: int) -> np.ndarray:
        """Uniformly random centres (n, 2) of non-overlapping discs of ``radius`` inside the
        domain, each clear of every wall."""
        low, high = self.y_range
        return random_centres_inside(n, radius, seed, x0=self.x0, period=self.period, y_range=(low, high),
                                     inside=self.inside, walls=self.wall_points())

    @abstractmethod
    def describe(self) -> dict:
        """What identifies the discretisation (kind, dofs, spacing, period, …): a resumed run
        must find the same values in its checkpoint."""

    # -- windows --------------------------------------------------------------------------
    @abstractmethod
    def window_policy(self, numerics: Numerics):
        """The policy by which windows follow particles."""

    @abstractmethod
    def full_window(self) -> Hashable:
        """The window that is the whole domain."""

    @abstractmethod
    def disc_window(self, centre: tuple[float, float], reach: float, policy) -> Hashable:
        """The window of a disc of radius ``reach`` (where φ crosses the threshold)."""

    @abstractmethod
    def window_dofs(self, window: Hashable) -> np.ndarray:
        """The dofs of a window, in the order its field is stored."""

    @abstractmethod
    def layout(self, windows: Sequence[Hashable]) -> Layout:
        """All windows grouped by the key their system depends on."""

    @abstractmethod
    def refit(self, layout: Layout, phi: np.ndarray, policy, motion: Callable[[], np.ndarray] | None
              ) -> tuple[Layout, np.ndarray]:
        """(layout, φ in its order) after refitting every window that no longer fits its
        field (``layout`` and ``phi`` themselves where none changed; ``phi`` is never
        written); ``motion()`` gives every particle's displacement (N, 2) over the coming
        step, for domains that leave room for it."""

    @abstractmethod
    def windows_to_array(self, windows: Sequence[Hashable]) -> np.ndarray:
        """Windows as an (N, 4) array for checkpoints."""

    def window_positions(self, windows: Sequence[Hashable]) -> dict[str, np.ndarray]:
        """What a checkpoint stores of the windows beyond :meth:`windows_to_array`'s rows,
        arrays by name (the dofs of windows described by their dofs); none here."""
        return {}

    @abstractmethod
    def windows_from_array(self, array: np.ndarray, positions: dict[str, np.ndarray] | None = None) -> list:
        """The inverse of :meth:`windows_to_array` and :meth:`window_positions`."""

    def window_coordinates(self, window: Hashable) -> tuple[np.ndarray, np.ndarray]:
        """x and y of a window's dofs, in storage order."""
        x, y = self.coordinates[:, self.window_dofs(window)]
        return x, y

    # -- fast paths -----------------------------------------------------------------------
    def solver(self, window: Hashable, block: Callable[[], sp.csr_matrix], a: float, b: float, lumped: bool,
               method: str, tolerance: float):
        """A solver of the window's submatrix of a G + b K, G the time mass (lumped or not),
        which ``block()`` extracts (only when needed: the structured channel's tensor solver
        does not). The base class factorises or builds an AMG hierarchy
        (:func:`femphase.fem.solvers.make_solver`)."""
        return make_solver(block(), method, tolerance)

    @abstractmethod
    def advection(self, flow: Flow, dt: float, numerics: Numerics) -> Advection:
        """The advection of all windows over one step of dt in ``flow``."""

    @abstractmethod
    def shape_moments(self, layout: Layout, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per particle (particle order): area ∫φ² (N,), φ-weighted centroid (N, 2; x as a
        circular mean over the period) and shape tensor −∫∇φ∇φᵀ (N, 2, 2)."""

    # -- derived --------------------------------------------------------------------------
    def offsets(self, window: Hashable, centre: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """x and y of a window's dofs relative to ``centre`` (lengths, storage order), x by the
        minimum image over the period."""
        x, y = self.window_coordinates(window)
        return np.mod(x - centre[0] + 0.5 * self.period, self.period) - 0.5 * self.period, y - centre[1]

    def disc_field(self, window: Hashable, centre: tuple[float, float], radius: float, width: float) -> np.ndarray:
        """The equilibrium profile (1 + tanh((radius − d)/λ))/2 of a disc on ``window``; d is
        the distance to ``centre`` with the minimum image in x."""
        return interface_profile(radius - np.hypot(*self.offsets(window, centre)), width)

    @cached_property
    def _circle(self) -> np.ndarray:
        """(4, n_dofs): cos and sin of every dof's x as an angle over the period, its y and
        its x (:meth:`centroids`; a grid builds its coordinates anew at every call)."""
        x, y = self.coordinates
        angle = 2 * np.pi * (x - self.x0) / self.period
        return np.stack([np.cos(angle), np.sin(angle), y, x])

    def centroids(self, layout: Layout, phi: np.ndarray) -> np.ndarray:
        """φ-weighted centroids ∫xφ/∫φ, ∫yφ/∫φ (N, 2) in particle order, x unwrapped about
        the circular mean over the period (so that a particle across the periodic seam is
        measured whole) and in [x0, x0 + period); NaN for a field that is zero everywhere
        (a vanished particle, :func:`femphase.analysis.shape.present`). The circular mean
        alone, arg ∫φ e^{2πix/Lx}, differs from ∫xφ/∫φ for a shape asymmetric in x (by 0.07 and
        0.28 for ellipses of 32 × 10 and 40 × 10 cut by a wall)."""
        cos, sin, y, x = np.take(self._circle, layout.node_index, axis=1)  # 7× faster than [:, index]
        weight = layout.mass * phi
        total = layout.reduce(np.add, weight)
        cos, sin = layout.reduce(np.add, weight * cos), layout.reduce(np.add, weight * sin)
        circular = self.x0 + np.arctan2(sin, cos) * self.period / (2 * np.pi)
        x -= np.repeat(circular, np.diff(layout.offsets))
        x = np.mod(x + 0.5 * self.period, self.period) - 0.5 * self.period  # minimum image about it
        # a node half a period away lies on both sides: split evenly, i.e. at the mean (its tail
        # there, φ ≈ 5e-7 on a full mesh, put a symmetric disc 5.7e-7 off to one side)
        x[np.abs(np.abs(x) - 0.5 * self.period) <= 1e-9 * self.period] = 0.0
        out = np.empty((len(layout.windows), 2))
        with np.errstate(divide="ignore", invalid="ignore"):
            centre = circular + layout.reduce(np.add, weight * x) / total
            out[layout.order, 1] = layout.reduce(np.add, weight * y) / total
        fraction = np.mod((centre - self.x0) / self.period, 1.0)
        out[layout.order, 0] = self.x0 + self.period * np.where(fraction < 1.0, fraction, 0.0)  # 1 − ε rounds to 1
        return out

    def single_precision_steps(self, numerics: Numerics) -> bool:
        """Whether flow steps may compute in single precision (``numerics.precision =
        "mixed"``): where every solve and advection has a single-precision path. Not here;
        the structured channel and meshes with batched solves say so."""
        return False

    def solves_batched(self, numerics: Numerics) -> bool:
        """Whether windows are solved all at once (:mod:`femphase.fem.blocks`): ``numerics.solver``
        "batched", or "auto" on a domain with :attr:`batched_solves`."""
        return numerics.solver == "batched" or (numerics.solver == "auto" and self.batched_solves)

    @cached_property
    def block_pattern(self) -> sp.csr_matrix:
        """The sparsity pattern of the P1 operators (mass ∪ stiffness, canonical CSR): every
        matrix the windows solve with or the advection applies has its entries there."""
        ops = self.operators
        pattern = (abs(ops.mass) + abs(ops.stiffness)).tocsr()
        pattern.sum_duplicates()
        pattern.sort_indices()
        pattern.data[:] = 1.0
        return pattern

    def aligned(self, matrix: sp.spmatrix) -> np.ndarray:
        """``matrix``'s entries aligned to :attr:`block_pattern` (:func:`~femphase.fem.blocks.aligned_data`)."""
        return aligned_data(matrix, self.block_pattern)

    @cached_property
    def _operator_data(self) -> dict[tuple[str, type], np.ndarray]:
        """The P1 mass and stiffness aligned to :attr:`block_pattern`, in double and single
        precision, by (name, dtype)."""
        double = {"mass": self.aligned(self.operators.mass), "stiffness": self.aligned(self.operators.stiffness)}
        return {(name, dtype): data.astype(dtype) for name, data in double.items() for dtype in (np.float64, np.float32)}

    #: The default of :attr:`caches`' limit (``numerics.cache_mib`` sets it for a scene).
    CACHE_BYTES = 256 * 2**20

    @cached_property
    def caches(self) -> ByteBudget:
        """The byte budget every cache of a run on this domain draws on (:mod:`femphase.caches`)."""
        return ByteBudget(self.CACHE_BYTES)

    @cached_property
    def _layout_blocks(self):
        """The last layout's block-diagonal map, operators and diagonals, each entry
        (layout, tag, value) (:meth:`per_layout`)."""
        return self.caches.cache("layout blocks")

    def per_layout(self, layout: Layout, name: Hashable, build: Callable[[], object], tag: object = None):
        """What ``build()`` makes for ``layout`` (a block-diagonal matrix, a diagonal), kept
        under ``name`` for the last layout only, in :attr:`caches`; ``tag`` tells apart the
        operators one name may stand for (compared by identity and held with the entry: e.g.
        the advection matrix's data, which changes with the flow)."""
        kept = self._layout_blocks.get(name)
        if kept is not None and kept[0] is not layout:
            # a new layout: what earlier ones kept under any name serves none that comes
            self._layout_blocks.retain({key for key, entry in self._layout_blocks.items() if entry[0] is layout})
        if kept is None or kept[0] is not layout or kept[1] is not tag:
            value = build()
            kept = self._layout_blocks.put(name, (layout, tag, value), nbytes_of(value))
        return kept[2]

    def window_blocks(self, layout: Layout) -> BlockPattern:
        """The block-diagonal map of ``layout``'s windows (:class:`~femphase.fem.blocks.BlockPattern`),
        for the last layout asked."""
        return self.per_layout(layout, "pattern",
                               lambda: BlockPattern(self.block_pattern, layout.node_index, layout.offsets))

    def window_matrix(self, layout: Layout, name: Hashable, aligned: np.ndarray) -> sp.csr_matrix:
        """The block-diagonal matrix of every window's principal submatrix of a full-domain
        matrix given by its entries ``aligned`` to :attr:`block_pattern` (:meth:`aligned`),
        kept under ``name`` for the last layout asked."""
        return self.per_layout(layout, name, lambda: self.window_blocks(layout).block(aligned), tag=aligned)

    def window_operator(self, layout: Layout, name: str, dtype: type = np.float64) -> sp.csr_matrix:
        """The block-diagonal matrix of every window's principal submatrix of the P1
        operator ``name`` ("mass" or "stiffness") with entries of ``dtype`` (float64, or
        float32 for single-precision steps), for the last layout asked."""
        dtype = np.dtype(dtype).type
        return self.window_matrix(layout, (name, dtype), self.aligned_operator(name, dtype))

    def aligned_operator(self, name: str, dtype: type = np.float64) -> np.ndarray:
        """The P1 operator ``name`` ("mass" or "stiffness")'s entries aligned to
        :attr:`block_pattern` (:meth:`aligned`) in ``dtype``, made once per domain."""
        return self._operator_data[name, np.dtype(dtype).type]

    def window_diagonal(self, layout: Layout, name: Hashable, diagonal: np.ndarray) -> np.ndarray:
        """The diagonal of :meth:`window_matrix` from the full matrix's ``diagonal`` (or any
        entrywise function of it, such as its inverse): a principal submatrix's diagonal is
        the full matrix's at its dofs, so one gather (kept under ``name`` with the layout's
        blocks: a Krylov solve's Jacobi preconditioner needs it at every call)."""
        return self.per_layout(layout, name, lambda: diagonal[layout.node_index], tag=diagonal)

    @cached_property
    def _stiffness_blocks(self):
        """Per window key: its principal submatrix of K, for :meth:`stiffness_apply`."""
        return self.caches.cache("stiffness blocks")

    def stiffness_apply(self, layout: Layout) -> Callable[[np.ndarray], np.ndarray]:
        """φ ↦ K φ window by window (each window's principal submatrix of K). On domains
        with :attr:`batched_solves` (meshes) by the layout's block-diagonal K, which the
        window solves use too: every box is its own key there, and blocks kept per key
        were rebuilt for almost every layout and piled up in the budget."""
        if self.batched_solves:
            return lambda phi: self.window_operator(layout, "stiffness") @ phi

        def apply(phi: np.ndarray) -> np.ndarray:
            out = np.empty_like(phi)
            for group, (key, members, start, stop, size) in enumerate(layout.groups):
                block = self._stiffness_blocks.setdefault(
                    key, lambda: window_block(self.operators.stiffness, self.window_dofs(layout.representative(group))))
                out[start:stop].reshape(members.size, size).T[...] = block @ phi[start:stop].reshape(members.size, size).T
            return out
        return apply


DOMAINS: Registry[type] = Registry("Domains", "domain.kind")


def window_block(matrix: sp.spmatrix, dofs: np.ndarray) -> sp.csr_matrix:
    """The principal submatrix of ``matrix`` on ``dofs``, in canonical form (sorted indices).

    Canonical, because windows of one key share the block of whichever window was seen
    first: a window across the periodic seam would otherwise store its rows' entries in
    another order, and the sums in products and factorisations would differ in the last
    bit between runs that met the windows in another order (a resumed run would then not
    be bit-identical to an uninterrupted one)."""
    block = sp.csr_matrix(matrix[dofs][:, dofs])
    block.sum_duplicates()
    block.sort_indices()
    return block
