"""Semi-implicit time stepping of all phase fields.

One step of length dt is Lie splitting of advection and relaxation:

1. advection over dt (:mod:`femphase.advection`; skipped without flow);
2. relaxation, linearly implicit in the gradient term, explicit in the rest:

       (G/dt + J0 S M_L + J0 2γλ K) φ¹ = (G/dt + J0 S M_L) φ* − J0 M_L g(φ*) + M_L s

   with G the mass matrix of the time derivative (lumped M_L or consistent M), g the
   explicit part of δF/δφ (:func:`femphase.energy.explicit_derivative`), s an optional
   source term (manufactured solutions) and S the stabilisation
   (:func:`femphase.model.stabilisation_for` unless set), which makes the no-flow step
   decrease the discrete free energy for any dt.

The matrix is symmetric positive definite and the same for all particles; every window
solves its principal submatrix (see :mod:`femphase.windows`), one solver per window key,
all windows of a key in one multi-right-hand-side call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

from .advection import advect_row_flow, advect_semi_lagrangian
from .discretisation import P1Operators, assemble_operators, line_operators
from .energy import explicit_derivative
from .errors import BlowUpError, SceneError
from .flows import Flow, no_flow
from .mesh import ChannelGrid, grid_dof_map, structured_channel_mesh
from .model import ModelParameters, stabilisation_for
from .solvers import TensorSolver, make_solver
from .state import State
from .windows import Layout, Window, WindowPolicy, transfer

MASS_TYPES = ("lumped", "consistent")
FD_ADVECTION = ("upwind3", "upwind1")


@dataclass(frozen=True)
class Numerics:
    """Discretisation choices (scene table ``[numerics]``).

    mass            "lumped" (default) or "consistent" mass matrix in the time derivative
    stabilisation   "auto" (the smallest energy-stable S for each dt) or a number ≥ 0
    solver          "auto", "direct" (cached LU), "amg" (pyamg-preconditioned CG) or "tensor"
                    (exact tensor-product solve; structured mesh, one diagonal direction,
                    lumped mass). "auto": tensor where it applies, else LU up to
                    DIRECT_MAX_DOFS, else AMG
    tolerance       relative residual of the AMG-Krylov solves
    windows         False: every field on the whole mesh (full-mesh mode)
    threshold       φ above which a node belongs to a particle (window fitting)
    margin          lattice units kept between a particle and its window's edge
    diagonals       "right", "left" or "alternating" (structured mesh pattern)
    fd_advection    the finite-difference reference's advection differences (``--method fd``
                    only): "upwind3" (default, third order) or "upwind1" (first order)
    blowup_margin   a step fails when φ leaves [−blowup_margin, 1 + blowup_margin]. Discs
                    started at R/2 overshoot physically to φ ≈ 1.4 while the area constraint
                    inflates them (2.1 with μ × 10), so the default, 2, flags only runaways
    """

    mass: str = "lumped"
    stabilisation: float | str = "auto"
    solver: str = "auto"
    tolerance: float = 1e-10
    windows: bool = True
    threshold: float = 0.01
    margin: float = 4.0
    diagonals: str = "right"
    blowup_margin: float = 2.0
    fd_advection: str = "upwind3"

    def __post_init__(self) -> None:
        if self.mass not in MASS_TYPES:
            raise SceneError("numerics.mass", self.mass, f"one of {MASS_TYPES}")
        if self.stabilisation != "auto" and not (
            isinstance(self.stabilisation, (int, float)) and self.stabilisation >= 0
        ):
            raise SceneError("numerics.stabilisation", self.stabilisation, '"auto" or a number ≥ 0')
        if not 0 < self.threshold < 0.5:
            raise SceneError("numerics.threshold", self.threshold, "a number in (0, 0.5)")
        if not self.margin > 0:
            raise SceneError("numerics.margin", self.margin, "a length > 0 (lattice units)")
        if not self.tolerance > 0:
            raise SceneError("numerics.tolerance", self.tolerance, "a number > 0")
        if self.fd_advection not in FD_ADVECTION:
            raise SceneError("numerics.fd_advection", self.fd_advection, f"one of {FD_ADVECTION}")
        if not self.blowup_margin > 0:
            raise SceneError("numerics.blowup_margin", self.blowup_margin, "a number > 0")


@dataclass(frozen=True)
class Discretisation:
    """The channel's grid, mesh and assembled P1 operators (built once per scene)."""

    grid: ChannelGrid
    operators: P1Operators
    alternating: bool
    mesh: object  # the non-periodic skfem.MeshTri (what output files are written on)
    dof_map: np.ndarray  # its nodes' dofs in grid order

    @classmethod
    def structured(cls, grid: ChannelGrid, diagonals: str = "right", mesh=None) -> "Discretisation":
        """Operators on the structured channel mesh, or on ``mesh`` (a non-periodic MeshTri
        whose nodes are the grid's, e.g. read from a file)."""
        mesh = structured_channel_mesh(grid, diagonals) if mesh is None else mesh
        dof_map = grid_dof_map(mesh, grid)
        operators = assemble_operators(mesh, dof_map, grid.n_nodes)
        return cls(grid, operators, _has_alternating_diagonals(mesh, grid), mesh, dof_map)


def _has_alternating_diagonals(mesh, grid: ChannelGrid) -> bool:
    """True unless every cell is split along the same diagonal (then windows of a shape share
    one submatrix regardless of position)."""
    p = mesh.p[:, mesh.t] / grid.h
    spans = np.ptp(p[0], axis=0) + np.ptp(p[1], axis=0)  # 2 for the right-angle triangles
    corner_sum = np.rint(p[0] + p[1]).astype(int)
    rising = (np.ptp(corner_sum, axis=0) == 2) & (spans == 2)
    return bool(rising.any() and not rising.all())


def relaxation_system(
    ops: P1Operators, params: ModelParameters, numerics: Numerics, dt: float, radii: np.ndarray | None,
) -> tuple[float, sp.csr_matrix, sp.csr_matrix | None]:
    """(S, G/dt + J0 S M_L + J0 2γλ K, G if consistent else None): the relaxation system
    shared by the structured and unstructured steppers, with the stabilisation S of
    ``numerics`` ("auto": :func:`femphase.model.stabilisation_for`)."""
    smallest_radius = float(np.min(radii)) if radii is not None and len(radii) else params.radius
    consistent = numerics.mass == "consistent"
    if numerics.stabilisation == "auto":
        pairs = radii is None or len(radii) > 1
        stabilisation = stabilisation_for(params, dt, smallest_radius, 0.25 if consistent else 1.0, pairs)
    else:
        stabilisation = float(numerics.stabilisation)
    time_mass = ops.mass if consistent else sp.diags(ops.lumped_mass)
    system = (
        time_mass / dt
        + params.mobility * stabilisation * sp.diags(ops.lumped_mass)
        + params.diffusivity * ops.stiffness
    ).tocsr()
    return stabilisation, system, sp.csr_matrix(time_mass) if consistent else None


#: ``solver = "auto"`` uses the tensor solver for windows up to this ny + nx (nodes):
#: benchmarks/solver_crossover.py measured it 1.5–3.7× faster than the cached LU up to
#: 256 × 256 nodes (ny + nx = 512) and 0.8–1.0× from ny + nx = 621 on (its dense products
#: grow as (ny + nx)·ny·nx, the LU's triangular solves slower).
TENSOR_MAX_SIDES = 512


def tensor_solver(block: sp.spmatrix, window: Window, grid: ChannelGrid, a: float, b: float) -> TensorSolver | None:
    """A :class:`TensorSolver` for ``block`` = a M_L + b K on ``window``'s nodes, or None when
    the block is not that tensor product (alternating diagonals, a file mesh, a consistent
    mass), checked entry by entry against the assembled block."""
    rows, columns = window.rows(), window.columns(grid)
    factors = []
    for n_nodes, periodic, keep in ((grid.ny, False, rows), (grid.nx, True, columns)):
        mass, stiffness = line_operators(n_nodes, grid.h, periodic)
        factors.append(tuple(m[keep][:, keep] for m in (mass, stiffness)))
    (my, ky), (mx, kx) = factors
    candidate = a * sp.kron(my, mx) + b * (sp.kron(ky, mx) + sp.kron(my, kx))
    if abs(candidate - block).max() > 1e-12 * abs(block).max():
        return None
    return TensorSolver(a, b, (my.toarray(), ky.toarray()), (mx.toarray(), kx.toarray()))


def check_fields(phi: np.ndarray, margin: float, step: int, time: float) -> None:
    """Raise BlowUpError when phi is not finite or leaves [−margin, 1 + margin]."""
    if not np.all(np.isfinite(phi)):
        raise BlowUpError(step, time, "φ is not finite (NaN or inf)")
    low, high = float(phi.min()), float(phi.max())
    if low < -margin or high > 1.0 + margin:
        raise BlowUpError(
            step, time,
            f"φ left [{-margin:g}, {1 + margin:g}] (min {low:.3g}, max {high:.3g}); "
            "try a smaller dt (with the FEM stepper, also numerics.stabilisation > 0), or, if "
            "the overshoot is physical, a larger numerics.blowup_margin",
        )


class SemiImplicitStepper:
    """Advances a :class:`State` by steps of fixed dt under a fixed flow."""

    def __init__(
        self,
        discretisation: Discretisation,
        params: ModelParameters,
        numerics: Numerics,
        dt: float,
        flow: Flow | None = None,
        radii: np.ndarray | None = None,
        source: Callable[[np.ndarray, np.ndarray, float], np.ndarray] | None = None,
    ) -> None:
        if not (dt > 0 and np.isfinite(dt)):
            raise SceneError("phases.dt", dt, "a time step > 0")
        self.disc, self.params, self.numerics, self.dt = discretisation, params, numerics, dt
        self.flow = flow or no_flow()
        self.source = source
        self.policy = WindowPolicy.for_spacing(
            discretisation.grid.h, threshold=numerics.threshold, margin=numerics.margin,
            enabled=numerics.windows,
        )
        self.stabilisation, self.system, self._time_mass = relaxation_system(
            discretisation.operators, params, numerics, dt, radii
        )
        self._solvers: dict[tuple, tuple] = {}
        self._layout: Layout | None = None

    # -- structure reused between steps ---------------------------------------------------
    def layout(self, windows) -> Layout:
        if self._layout is None or self._layout.windows != tuple(windows):
            self._layout = Layout(windows, self.disc.grid, self.disc.alternating)
            self._node_mass = self.disc.operators.lumped_mass[self._layout.node_index]
        return self._layout

    def _solver(self, key: tuple, window: Window) -> tuple:
        """(solver, consistent-mass submatrix or None) for windows with this key."""
        if key not in self._solvers:
            nodes = window.node_indices(self.disc.grid)
            block = self.system[nodes][:, nodes]
            mass = self._time_mass[nodes][:, nodes] if self._time_mass is not None else None
            method = self.numerics.solver
            solver = None
            if mass is None and (method == "tensor" or (method == "auto" and window.ny + window.nx <= TENSOR_MAX_SIDES)):
                solver = tensor_solver(block, window, self.disc.grid,
                                       1.0 / self.dt + self.params.mobility * self.stabilisation,
                                       self.params.diffusivity)
            self._solvers[key] = (solver or make_solver(block, method, self.numerics.tolerance), mass)
        return self._solvers[key]

    # -- one step -------------------------------------------------------------------------
    def step(self, state: State) -> None:
        """Advance ``state`` by dt in place; raises BlowUpError (state unchanged) on failure."""
        layout = self.layout(state.windows)
        phi = layout.gather(state.fields)
        if self.flow.row_velocity is not None:
            moved = advect_row_flow(phi, layout, state.grid, self.flow, self.dt)
            fields = layout.scatter(phi)
        elif not self.flow.is_still:
            fields, moved = advect_semi_lagrangian(state.fields, state.windows, state.grid, self.flow, self.dt)
        if not self.flow.is_still:
            previous, layout = layout, self.layout(moved)
            # moving windows can regroup them (alternating diagonals): gather again then
            if self.flow.row_velocity is None or not np.array_equal(layout.order, previous.order):
                phi = layout.gather(fields)
        windows = layout.windows
        phi_new = self._relax(phi, layout, state.radii, state.time + self.dt)
        check_fields(phi_new, self.numerics.blowup_margin, state.step + 1, state.time + self.dt)
        new_fields = layout.scatter(phi_new)
        new_windows = list(windows)
        for group, (_, members, *_) in enumerate(layout.groups):
            block = layout.group_block(phi_new, group)
            for i in members[self.policy.misfits(block, [windows[i] for i in members], state.grid)]:
                fitted = self.policy.fit(new_fields[i], windows[i], state.grid)
                if fitted == windows[i]:
                    continue
                new_fields[i] = transfer(new_fields[i], windows[i], fitted, state.grid)
                new_windows[i] = fitted
        state.fields, state.windows = new_fields, new_windows
        state.time += self.dt
        state.step += 1

    def _relax(self, phi: np.ndarray, layout: Layout, radii: np.ndarray, new_time: float) -> np.ndarray:
        params, grid = self.params, self.disc.grid
        j0, dt = params.mobility, self.dt
        nodes = layout.node_index
        mass = self._node_mass
        radius = np.asarray(radii, dtype=float)[layout.order]
        squares = phi**2
        ratio = np.add.reduceat(mass * squares, layout.offsets[:-1]) / (np.pi * radius**2)
        # repulsion only where windows overlap: elsewhere Σ_{j≠i} φ_j² is exactly zero
        others = np.zeros_like(phi)
        shared = layout.overlap_positions
        if shared.size:
            total = np.bincount(nodes[shared], weights=squares[shared], minlength=grid.n_nodes)
            others[shared] = total[nodes[shared]] - squares[shared]
        g = explicit_derivative(
            phi, others, np.repeat(ratio, layout.sizes), np.repeat(radius, layout.sizes), params
        )
        # M_L (φ/dt + J0 S φ − J0 g + s); the consistent time mass adds G φ/dt per group below
        rhs_all = phi * ((0.0 if self._time_mass is not None else 1.0 / dt) + j0 * self.stabilisation)
        g *= j0
        rhs_all -= g
        if self.source is not None:
            x = (nodes % grid.nx) * grid.h
            y = (nodes // grid.nx) * grid.h
            rhs_all += self.source(x, y, new_time)
        rhs_all *= mass
        out = np.empty_like(phi)
        for group, (key, members, start, stop, size) in enumerate(layout.groups):
            solver, time_mass = self._solver(key, layout.representative(group))
            # (size, members) views in Fortran order, as SuperLU wants them: no copies
            current = phi[start:stop].reshape(len(members), size).T
            rhs = rhs_all[start:stop].reshape(len(members), size).T
            if time_mass is not None:
                rhs = rhs + (time_mass @ current) / dt
            out[start:stop].reshape(len(members), size).T[...] = solver.solve(rhs, current)
        return out
