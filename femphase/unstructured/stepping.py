"""Semi-implicit time stepping of all phase fields on a meshed channel.

The scheme of :mod:`femphase.stepping`, on windows that are dof subsets
(:mod:`femphase.unstructured.windows`). One step of length dt is Lie splitting:

1. advection over dt: Galerkin in space (consistent mass M, skew-symmetric advection matrix
   C of :mod:`femphase.unstructured.transport`), and in time the (2,2) Padé approximant of
   the exact propagator exp(−dt M⁻¹C),

       φ* = R(dt M⁻¹C) φ⁰,   R(z) = (1 − z/2 + z²/12) / (1 + z/2 + z²/12)
                                  = 1 + 2 Re[−2i√3 / (1 − z/r)],   r = −3 + i√3,

   i.e. one complex solve per window, φ* = φ⁰ + 4√3 Im w with (M − (dt/r) C) w = M φ⁰;
2. relaxation, linearly implicit in the gradient term, explicit in the rest, exactly as on
   the structured mesh:

       (G/dt + J0 S M_L + J0 2γλ K) φ¹ = (G/dt + J0 S M_L) φ* − J0 M_L g(φ*) + M_L s.

Why Galerkin and not semi-Lagrangian advection: semi-Lagrangian with P1 interpolation at the
departure points adds a numerical diffusion ~ h² C(1 − C)/(2 dt) (C the Courant number u dt/h)
that grows as dt shrinks; at the paper's u ~ 1, h = 1 it is as large as the model's own
diffusivity J0·2γλ = 0.12 (cell Péclet number u h/(J0·2γλ) ≈ 8) and widens every moving
interface. Galerkin advection has no numerical diffusion, P1 with consistent mass has a small
O(h²) phase error, and cell Péclet numbers above 2 do not make it oscillate here: the
interface is resolved (width ~2λ = 4h) and held to its tanh profile by the double well, so
there is no unresolved advective layer.

Why Padé (2,2) and not Crank–Nicolson (the (1,1) approximant): both are A-stable and, for the
skew C, conserve ∫φ² exactly at any dt, but CN's phase error (ω dt)²/12 at the interface's
wavenumbers made a disc translating at u = 1 with dt = 1 lag by 1.2 % and stretch spuriously
(elongation +0.024); the fourth-order Padé step costs one complex solve instead of one real
solve and cuts both to 0.1 % and +0.002 (at dt = 4, Courant number 4: 1.1 % and +0.07; see
verification/MESHES.md). The advection is split from the relaxation (rather than added to its
matrix) so that the relaxation keeps the lumped time mass and its energy-stability bound
(c = 1 in :func:`femphase.model.stabilisation_for`) while the advection gets the consistent
mass.

Every window's two matrices are principal submatrices of global ones (zero data beyond the
window), factorised once per window (LU below the crossover, pyamg + Krylov above, as
:func:`femphase.solvers.make_solver` decides) and kept until the window's dof set changes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

from ..energy import explicit_derivative
from ..errors import SceneError
from ..flows import Flow
from ..model import ModelParameters
from ..solvers import make_solver
from ..stepping import Numerics, check_fields, relaxation_system
from ..stokes import StokesFlow
from .domain import MeshDomain
from .state import MeshState
from .transport import advection_matrix, nodal_velocity
from .windows import Box, MeshLayout, MeshWindowPolicy, circular_extent, local_x


#: The pole r of the (2,2) Padé approximant R(z) = 1 + 2 Re[−2i√3/(1 − z/r)] of exp(−z).
PADE_POLE = -3.0 + 1j * np.sqrt(3.0)


@dataclass
class _WindowSystems:
    """One window's factorised systems (None where not needed)."""

    relax: object
    time_mass: sp.csr_matrix | None
    advect: object | None  # the complex M − (dt/r) C
    advect_rhs: sp.csr_matrix | None  # M


class UnstructuredStepper:
    """Advances a :class:`MeshState` by steps of fixed dt under a fixed flow.

    Same constructor as :class:`femphase.stepping.SemiImplicitStepper`, with a
    :class:`MeshDomain` in place of the structured discretisation and ``flow`` a
    :class:`~femphase.flows.Flow` or a :class:`~femphase.stokes.StokesFlow` on the domain's mesh.
    """

    def __init__(
        self,
        domain: MeshDomain,
        params: ModelParameters,
        numerics: Numerics,
        dt: float,
        flow: Flow | StokesFlow | None = None,
        radii: np.ndarray | None = None,
        source: Callable[[np.ndarray, np.ndarray, float], np.ndarray] | None = None,
    ) -> None:
        if not (dt > 0 and np.isfinite(dt)):
            raise SceneError("phases.dt", dt, "a time step > 0")
        self.domain, self.params, self.numerics, self.dt = domain, params, numerics, dt
        self.source = source
        self.policy = MeshWindowPolicy.for_spacing(
            domain.spacing, threshold=numerics.threshold, margin=numerics.margin, enabled=numerics.windows,
        )
        ops = domain.operators
        self.stabilisation, self.system, self._time_mass = relaxation_system(ops, params, numerics, dt, radii)
        moving = flow is not None and not (isinstance(flow, Flow) and flow.is_still)
        self.velocity = nodal_velocity(domain, flow) if moving else None
        if moving:
            self._advect = (ops.mass - (dt / PADE_POLE) * advection_matrix(domain, flow)).tocsr()
            self._advect_rhs = ops.mass.tocsr()
        self._systems: dict[Box, _WindowSystems] = {}
        self._layout: tuple[tuple, MeshLayout] | None = None

    # -- structure reused between steps ---------------------------------------------------
    def layout(self, boxes: list[Box], nodes: list[np.ndarray]) -> MeshLayout:
        key = tuple(boxes)
        if self._layout is None or self._layout[0] != key:
            self._layout = (key, MeshLayout(nodes, self.domain.operators.lumped_mass))
        return self._layout[1]

    def systems(self, box: Box, nodes: np.ndarray) -> _WindowSystems:
        """The window's factorised systems, built on first use."""
        if box not in self._systems:
            method, tol = self.numerics.solver, self.numerics.tolerance
            sub = (lambda m: m[nodes][:, nodes].tocsr())
            moving = self.velocity is not None
            self._systems[box] = _WindowSystems(
                relax=make_solver(sub(self.system), method, tol),
                time_mass=sub(self._time_mass) if self._time_mass is not None else None,
                advect=make_solver(sub(self._advect), method, tol) if moving else None,
                advect_rhs=sub(self._advect_rhs) if moving else None,
            )
        return self._systems[box]

    # -- one step -------------------------------------------------------------------------
    def step(self, state: MeshState) -> None:
        """Advance ``state`` by dt in place; raises BlowUpError (state unchanged) on failure."""
        boxes, nodes, fields = self.refit(state)
        layout = self.layout(boxes, nodes)
        # keep only the current windows' factorisations
        current = set(boxes)
        self._systems = {b: s for b, s in self._systems.items() if b in current}
        phi = np.concatenate(fields)
        if self.velocity is not None:
            phi = self._advect_all(phi, layout, boxes, nodes)
        phi_new = self._relax(phi, layout, boxes, nodes, state.radii, state.time + self.dt)
        check_fields(phi_new, self.numerics.blowup_margin, state.step + 1, state.time + self.dt)
        state.boxes, state.nodes, state.fields = boxes, nodes, layout.split(phi_new)
        state.time += self.dt
        state.step += 1

    def particle_steps(self, phi: np.ndarray, layout: MeshLayout) -> np.ndarray:
        """(N, 2): each particle's displacement over one step, its φ²-weighted mean velocity × dt."""
        if self.velocity is None:
            return np.zeros((len(layout.sizes), 2))
        weight = layout.mass * phi**2
        total = layout.reduce(np.add, weight)
        u = self.velocity[:, layout.node_index]
        mean = np.stack([layout.reduce(np.add, weight * u[0]), layout.reduce(np.add, weight * u[1])], axis=1)
        return self.dt * mean / np.maximum(total, 1e-300)[:, None]

    def refit(self, state: MeshState) -> tuple[list[Box], list[np.ndarray], list[np.ndarray]]:
        """Boxes, dofs and fields after refitting every window that no longer fits the field
        and the coming step's motion (see :class:`MeshWindowPolicy`)."""
        domain, policy = self.domain, self.policy
        boxes, nodes, fields = list(state.boxes), list(state.nodes), list(state.fields)
        layout = self.layout(boxes, nodes)
        phi = np.concatenate(fields)
        steps = self.particle_steps(phi, layout)
        occupied = phi > policy.threshold
        x, y = domain.coordinates[:, layout.node_index]
        lx = local_x(x, np.array([b.x0 for b in boxes])[layout.owner], domain.period)
        extents = np.stack([
            layout.reduce(np.minimum, np.where(occupied, lx, np.inf)),
            layout.reduce(np.maximum, np.where(occupied, lx, -np.inf)),
            layout.reduce(np.minimum, np.where(occupied, y, np.inf)),
            layout.reduce(np.maximum, np.where(occupied, y, -np.inf)),
        ], axis=1)
        extents[~np.isfinite(extents[:, 0])] = np.nan
        scratch = np.zeros(domain.n_dofs)
        for i in np.flatnonzero(policy.misfits(extents, boxes, domain, steps)):
            box = boxes[i]
            if box.width >= domain.period:
                mine = occupied[layout.offsets[i]:layout.offsets[i + 1]]
                x_range = circular_extent(x[layout.offsets[i]:layout.offsets[i + 1]][mine], domain.period)
            else:
                x_range = (box.x0 + extents[i, 0], box.x0 + extents[i, 1])
            fitted = policy.cover(domain, x_range, tuple(extents[i, 2:]), tuple(steps[i]))
            if fitted == box:
                continue
            new_nodes = fitted.nodes(domain)
            scratch[nodes[i]] = fields[i]
            fields[i] = scratch[new_nodes]
            scratch[nodes[i]] = 0.0
            boxes[i], nodes[i] = fitted, new_nodes
        return boxes, nodes, fields

    def _advect_all(self, phi: np.ndarray, layout: MeshLayout, boxes, nodes) -> np.ndarray:
        out = np.empty_like(phi)
        for i, (box, dofs) in enumerate(zip(boxes, nodes)):
            part = slice(layout.offsets[i], layout.offsets[i + 1])
            systems = self.systems(box, dofs)
            w = systems.advect.solve((systems.advect_rhs @ phi[part]).astype(complex))
            out[part] = phi[part] + 4.0 * np.sqrt(3.0) * w.imag
        return out

    def _relax(self, phi: np.ndarray, layout: MeshLayout, boxes, nodes, radii: np.ndarray,
               new_time: float) -> np.ndarray:
        params, dt = self.params, self.dt
        mass, index = layout.mass, layout.node_index
        radius = np.asarray(radii, dtype=float)
        squares = phi**2
        ratio = layout.reduce(np.add, mass * squares) / (np.pi * radius**2)
        # repulsion only where windows overlap: elsewhere Σ_{j≠i} φ_j² is exactly zero
        others = np.zeros_like(phi)
        shared = layout.overlap_positions
        if shared.size:
            total = np.bincount(index[shared], weights=squares[shared], minlength=self.domain.n_dofs)
            others[shared] = total[index[shared]] - squares[shared]
        g = explicit_derivative(phi, others, ratio[layout.owner], radius[layout.owner], params)
        rhs = params.mobility * mass * (self.stabilisation * phi - g)
        if self.source is not None:
            x, y = self.domain.coordinates[:, index]
            rhs += mass * self.source(x, y, new_time)
        lumped = self._time_mass is None
        if lumped:
            rhs += mass * phi / dt
        out = np.empty_like(phi)
        for i, (box, dofs) in enumerate(zip(boxes, nodes)):
            part = slice(layout.offsets[i], layout.offsets[i + 1])
            systems = self.systems(box, dofs)
            if not lumped:
                rhs[part] += systems.time_mass @ phi[part] / dt
            out[part] = systems.relax.solve(rhs[part], phi[part])
        return out
