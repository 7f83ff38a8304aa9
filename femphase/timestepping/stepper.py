"""The stepper: advances a State by steps of fixed dt on any Domain, with any time scheme.

One step:

1. refit the windows that no longer fit their fields (:meth:`femphase.domains.base.Domain.refit`);
2. the time scheme (:mod:`femphase.timestepping.base`, chosen by ``numerics.scheme``)
   advances the gathered fields, using what the stepper offers: the advection of the domain in the flow
   (:attr:`Stepper.advection`), the explicit part g of δF/δφ
   (:meth:`Stepper.explicit_derivative`), window-by-window solves of
   (c G + J0 S M_L + J0 D K) φ = rhs (:meth:`Stepper.solve`), and the source term;
3. a check that φ is finite and near [0, 1] (else :class:`~femphase.errors.BlowUpError`
   naming the step, with the state untouched).

Every window solves the principal submatrix of the full-domain system on its dofs (see
:mod:`femphase.domains.layout`). Either solvers are built once per window key and system,
all windows of a key are solved in one multi-right-hand-side call, and the solvers are kept
in the domain's byte budget (:mod:`femphase.caches`, least recently used dropped first);
or, batched (meshes), all windows are solved at once by CG on their block-diagonal matrix
(:mod:`femphase.fem.blocks`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np
import scipy.sparse as sp

from femphase.config import Numerics
from femphase.domains.advection import nodal_velocity
from femphase.domains.base import Domain, window_block
from femphase.domains.layout import Layout
from femphase.errors import ExtensionError, SceneError
from femphase.fem.blocks import conjugate_gradient
from femphase.flows import Flow, no_flow
from femphase.model.energy import FreeEnergy, WindowedFields
from femphase.model.parameters import ModelParameters
from femphase.registry import blamed
from femphase.state import State
from femphase.timestepping.base import SCHEMES, check_fields, scheme_class

__all__ = ["Stepper"]


class Stepper:
    """Advances a :class:`State` on ``domain`` by steps of fixed dt under one flow.

    ``energy`` defaults to the paper's three terms with ``params``; ``source`` s(x, y, t) is
    added to the right-hand side of the equation of motion (manufactured solutions);
    ``scheme`` overrides ``numerics.scheme``.
    """

    def __init__(
        self,
        domain: Domain,
        params: ModelParameters,
        numerics: Numerics,
        dt: float,
        flow: Flow | None = None,
        radii: np.ndarray | None = None,
        source: Callable[[np.ndarray, np.ndarray, float], np.ndarray] | None = None,
        energy: FreeEnergy | None = None,
        scheme: str | None = None,
    ) -> None:
        if not (isinstance(dt, (int, float)) and dt > 0 and np.isfinite(dt)):
            raise SceneError("phases.dt", dt, "a time step > 0")
        self.domain, self.params, self.numerics, self.dt = domain, params, numerics, float(dt)
        self.flow = flow or no_flow()
        self.source = source
        self.energy = energy or FreeEnergy.paper(params)
        self.radii = None if radii is None else np.asarray(radii, dtype=float)
        self.policy = domain.window_policy(numerics)
        self.advection = None if self.flow.is_still else domain.advection(self.flow, self.dt, numerics)
        #: full-domain system matrices per (shift, stabilisation), and per-window-key solvers
        #: with their consistent mass blocks, in the domain's byte budget
        self._systems = domain.caches.cache("systems")
        self._solvers = domain.caches.cache("window solvers")
        #: whether window solves run on all windows at once (:meth:`~femphase.domains.base.Domain.solves_batched`)
        self.batched = domain.solves_batched(numerics)
        #: CG iterations of the batched solves so far, in products with the whole layout's
        #: matrix (each window runs its own CG; a diagnostic)
        self.krylov_iterations = 0.0
        #: the last batched solve's right-hand side and final residual (:meth:`last_product`)
        self._last_solve: tuple[np.ndarray, np.ndarray] | None = None
        #: a steady flow's largest nodal speed (:meth:`_largest_speed`)
        self._speed: float | None = None
        #: the time scheme, and where it is defined if in the user's own module (its faults are
        #: named so)
        self.scheme, self._scheme_origin = _built_scheme(scheme or numerics.scheme, self)
        #: whether steps compute in single precision (numerics.precision, under flow only)
        self.single_precision = (numerics.single_precision_allowed(self.scheme.name) and not self.flow.is_still
                                 and domain.single_precision_steps(numerics) and self.scheme.mixed_precision)

    @property
    def mobility(self) -> float:
        return self.params.mobility

    @property
    def smallest_radius(self) -> float:
        return float(np.min(self.radii)) if self.radii is not None and len(self.radii) else self.params.radius

    @property
    def lumped(self) -> bool:
        """Whether the time derivative's mass is lumped (else consistent)."""
        return self.numerics.mass != "consistent"

    @property
    def pairs(self) -> bool:
        """Whether particles can overlap (more than one): the repulsion's curvature counts."""
        return self.radii is None or len(self.radii) > 1

    # -- what time schemes use ------------------------------------------------------------
    def explicit_derivative(self, phi: np.ndarray, layout: Layout, radii: np.ndarray) -> np.ndarray:
        """g = the explicitly treated part of δF/δφ at every position (layout order)."""
        return self.energy.explicit_derivative(WindowedFields(phi, layout, radii))

    def source_term(self, layout: Layout, time: float) -> np.ndarray | None:
        """s(x, y, t) at every position, or None without a source."""
        if self.source is None:
            return None
        x, y = np.take(self.domain.coordinates, layout.node_index, axis=1)
        return self.source(x, y, time)

    def system(self, shift: float, stabilisation: float) -> tuple[sp.csr_matrix, sp.csr_matrix | None]:
        """(shift·G + J0 S M_L + J0 D K, G if the time mass is consistent else None)."""
        def build() -> tuple[sp.csr_matrix, sp.csr_matrix | None]:
            ops = self.domain.operators
            consistent = not self.lumped
            time_mass = ops.mass if consistent else sp.diags(ops.lumped_mass)
            matrix = (shift * time_mass + self.mobility * stabilisation * sp.diags(ops.lumped_mass)
                      + self.mobility * self.energy.diffusivity * ops.stiffness).tocsr()
            return matrix, sp.csr_matrix(time_mass) if consistent else None
        return self._systems.setdefault((shift, stabilisation), build)

    def solve(self, nodal_rhs: np.ndarray, previous: np.ndarray, layout: Layout, shift: float,
              stabilisation: float, guess: np.ndarray | None = None,
              tolerance: float | None = None, guess_product: np.ndarray | None = None) -> np.ndarray:
        """φ with (shift·G + J0 S M_L + J0 D K) φ = M_L nodal_rhs + shift·G previous, window by
        window (all vectors in layout order). ``guess`` (default ``previous``) starts the
        iterative solvers (batched CG, AMG); the others are exact. ``tolerance`` (default
        ``numerics.krylov_tolerance`` of the phase) stops the batched CG; ``guess_product``,
        the system times ``guess`` where the caller knows it, spares the batched CG its first
        product."""
        lumped = self.lumped
        if lumped:  # M_L (nodal_rhs + shift·previous), in place
            rhs = previous * shift
            rhs += nodal_rhs
            rhs *= layout.mass_like(rhs)
        else:
            rhs = layout.mass * nodal_rhs
        if self.batched:
            if tolerance is None:
                tolerance = self.numerics.krylov_tolerance(self.flow.is_still)
            return self._solve_batched(rhs, previous, layout, shift, stabilisation,
                                       previous if guess is None else guess, tolerance, guess_product)
        out = np.empty_like(previous)
        for group, (key, members, start, stop, size) in enumerate(layout.groups):
            solver, mass_block = self._solver(key, layout.representative(group), shift, stabilisation)
            # (size, members) views in Fortran order, as SuperLU wants them: no copies
            current = previous[start:stop].reshape(members.size, size).T
            group_rhs = rhs[start:stop].reshape(members.size, size).T
            if not lumped:
                group_rhs = group_rhs + shift * (mass_block @ current)
            start_from = current if guess is None else guess[start:stop].reshape(members.size, size).T
            out[start:stop].reshape(members.size, size).T[...] = solver.solve(group_rhs, start_from)
        return out

    def last_product(self) -> np.ndarray:
        """A x of the last batched solve's system and solution x, as rhs − r from its final
        residual r (no product; the residual as CG updated it, which differs from the true
        one by rounding). Valid until the next batched solve."""
        if self._last_solve is None:
            raise RuntimeError("last_product: no batched solve has run")
        rhs, residual = self._last_solve
        return rhs - residual

    def _solve_batched(self, rhs: np.ndarray, previous: np.ndarray, layout: Layout, shift: float,
                       stabilisation: float, guess: np.ndarray, tolerance: float,
                       guess_product: np.ndarray | None = None) -> np.ndarray:
        """All windows at once: Jacobi-preconditioned CG on each block of the block-diagonal
        matrix of the windows' systems (:func:`~femphase.fem.blocks.conjugate_gradient`),
        started from ``guess``, to the relative ``tolerance``. The system's
        blocks come from the full-domain system in one gather per layout, so that an
        iteration is one sparse product (the mass and stiffness blocks applied apart and
        summed were two products and five vector passes: 1.2–1.7 against 1.0–1.1 ms per
        iteration in a run of examples/straight_mesh.toml, decision record 0024)."""
        # the system in the right-hand side's precision: float32 in single-precision steps,
        # where a float64 matrix would promote every product to double
        dtype = np.dtype(rhs.dtype).type
        key = (shift, stabilisation)
        matrix = self.system(shift, stabilisation)[0]
        aligned, full_inverse = self._systems.setdefault(
            ("aligned", key, dtype),
            lambda: (self.domain.aligned(matrix).astype(dtype), (1.0 / matrix.diagonal()).astype(dtype)))
        system = self.domain.window_matrix(layout, ("system", key, dtype), aligned)
        # the Jacobi preconditioner D⁻¹, kept per layout: made at every solve it was a third of
        # the solve's start (0.1 of 0.3 ms on 10⁵ positions)
        inverse = self.domain.window_diagonal(layout, ("system inverse diagonal", key, dtype), full_inverse)
        if not self.lumped:
            rhs = rhs + shift * (self.domain.window_operator(layout, "mass", dtype) @ previous)
        solution, iterations, residual = conjugate_gradient(system, layout.offsets, inverse, rhs, guess, tolerance,
                                                            guess_product=guess_product)
        self.krylov_iterations += float(iterations @ np.diff(layout.offsets) / layout.offsets[-1])
        self._last_solve = (rhs, residual)
        return solution.astype(previous.dtype, copy=False)

    def _solver(self, key, window, shift: float, stabilisation: float) -> tuple:
        """(solver, consistent mass block or None) of the window key's system."""
        def build() -> tuple:
            lumped = self.lumped
            a = shift + self.mobility * stabilisation
            solver = self.domain.solver(window, lambda: window_block(self.system(shift, stabilisation)[0],
                                                                     self.domain.window_dofs(window)),
                                        a, self.mobility * self.energy.diffusivity, lumped, self.numerics.solver,
                                        self.numerics.tolerance)
            mass_block = None if lumped else window_block(self.system(shift, stabilisation)[1],
                                                          self.domain.window_dofs(window))
            return solver, mass_block
        return self._solvers.setdefault((key, shift, stabilisation), build)

    # -- one step -------------------------------------------------------------------------
    def step(self, state: State, steps: int = 1) -> None:
        """Advance ``state`` by ``steps`` steps of dt in place; raises BlowUpError naming the
        step that failed, with ``state`` as it was after the last step that did not (as it
        was before the call where the scheme merges steps).

        A scheme that :attr:`~femphase.timestepping.base.TimeScheme.merges_steps` takes them as one
        run, synchronised at the end only (the adaptive scheme's half-steps, window refits
        and set-up shared across step boundaries): fewer calls, less work, and results that
        depend on where calls end at the level of the splitting error. Others step one by
        one."""
        if not (isinstance(steps, (int, np.integer)) and steps >= 1):
            raise ValueError(f"steps must be a whole number >= 1, not {steps!r}")
        per_call = steps if self.scheme.merges_steps else 1
        for _ in range(steps // per_call):
            layout, phi = state.flat()
            if self.single_precision:  # the call's working copy; the state stays double
                phi = phi.astype(np.float32)
            layout, phi = self.refit(layout, phi, state.time)
            phi, layout = self._advance(phi, layout, state, per_call)
            end = state.time
            for _ in range(per_call):  # the same clock as step by step, to the last bit
                end += self.dt
            check_fields(phi, self.numerics.blowup_margin, state.step + per_call, end)
            state.windows, state.fields = list(layout.windows), layout.scatter(phi.astype(np.float64, copy=False))
            state.time, state.step = end, state.step + per_call

    def _advance(self, phi: np.ndarray, layout: Layout, state: State, steps: int) -> tuple[np.ndarray, Layout]:
        """The scheme's advance; a scheme of the user's own module that raises or returns other
        than (φ, layout) stops the run naming it (ExtensionError)."""
        scheme, origin = self.scheme, self._scheme_origin
        with blamed(origin, lambda exc: ExtensionError(f"the time scheme {scheme.name!r} ({origin})", state.step,
                                                       state.time, f"its advance raised {type(exc).__name__}: {exc}")):
            result = scheme.advance(phi, layout, state, steps) if scheme.merges_steps else scheme.advance(phi, layout,
                                                                                                         state)
        if origin is not None:
            new_phi, new_layout = result if isinstance(result, tuple) and len(result) == 2 else (None, None)
            if not (isinstance(new_phi, np.ndarray) and isinstance(new_layout, Layout)
                    and new_phi.shape == (int(new_layout.offsets[-1]),)):
                got = (f"φ of shape {new_phi.shape} for a layout of {int(new_layout.offsets[-1])} positions"
                       if isinstance(new_phi, np.ndarray) and isinstance(new_layout, Layout)
                       else type(result).__name__)
                raise ExtensionError(f"the time scheme {scheme.name!r} ({origin})", state.step, state.time,
                                     f"its advance must return (φ, layout), φ one value per position of the layout; "
                                     f"it returned {got}")
        return result

    @property
    def roomless(self) -> bool:
        """Whether the windows take no room for a step's motion at a call's refit: windows
        solved all at once under a scheme that refits between its substeps
        (:attr:`~femphase.timestepping.base.TimeScheme.refits_substeps`). They have no
        solvers to keep and each substep starts from a refit; the room, taken at calls and
        given back at the substeps' refits, made 112 layouts where 66 came without it
        (examples/straight_mesh.toml, 800 time units of flow). Such a scheme asks for room
        before each advection instead (:meth:`refit` with ``span``)."""
        return self.batched and self.scheme.refits_substeps

    def refit(self, layout: Layout, phi: np.ndarray, time: float | None = None,
              span: float | None = None) -> tuple[Layout, np.ndarray]:
        """(layout, φ) after refitting the windows that no longer fit their fields, leaving
        room for the motion from ``time`` on:

        * ``time`` alone (a call's refit): room for a step's motion (dt), so that a particle
          stays inside its window over the step and a window's solvers last; none where
          :attr:`roomless`;
        * ``time`` and ``span`` (a scheme's refit before an advection over ``span`` time
          units): room for that motion once the flow can carry a particle farther than the
          policy's ``room`` within it (below that the margin takes the motion), where the
          advection keeps the windows in place (meshes; the structured channel's moves them
          with the flow: none there). A steady flow's room lies ahead of each particle's
          mean motion; a flow that changes in time may turn within the span, so its room is
          a margin widened on every side by the farthest it can carry a particle (largest
          speed × span);
        * neither: no room.

        Without room before each advection, a fast flow's advection carried particles out of
        their windows and their fields were cut away: at max_velocity 10 on
        examples/straight_mesh.toml three of ten particles vanished within the first
        substep of flow; in an oscillating shear of rate 10 and frequency 0.5, where one
        instant's velocity may be near zero, a particle at the wall kept 111 of its 195; with
        an LU per box ("direct") at max_velocity 10 and dt = 1, areas of 184 against 192 and
        φ down to −0.18."""
        policy, motion = self.policy, None
        keeps_windows = self.advection is not None and not self.advection.moves_windows
        if time is not None and span is None and not self.roomless:
            motion = lambda: self._motion(layout, phi, time, self.dt)  # noqa: E731
        elif time is not None and span is not None and keeps_windows:
            reach = self._largest_speed(time, span) * span
            if reach > self.policy.room and self.flow.steady:
                motion = lambda: self._motion(layout, phi, time, span)  # noqa: E731
            elif reach > self.policy.room:
                policy = replace(self.policy, margin=self.policy.margin + reach)
        return self.domain.refit(layout, phi, policy, motion)

    def _largest_speed(self, time: float, span: float) -> float:
        """The flow's largest nodal speed over ``span`` time units from ``time``: a steady
        flow's (kept), a changing flow's at the span's start, middle and end."""
        if self.flow.steady:
            if self._speed is None:
                self._speed = float(np.max(np.hypot(*nodal_velocity(self.domain, self.flow))))
            return self._speed
        return max(float(np.max(np.hypot(*nodal_velocity(self.domain, self.flow, time + f * span))))
                   for f in (0.0, 0.5, 1.0))

    def _motion(self, layout: Layout, phi: np.ndarray, time: float, span: float) -> np.ndarray:
        """(N, 2): each particle's displacement over ``span`` time units from ``time``, its
        φ²-weighted mean velocity × span (particle order)."""
        out = np.zeros((len(layout.windows), 2))
        if self.advection is None:
            return out
        weight = layout.mass * phi**2
        total = np.maximum(layout.reduce(np.add, weight), 1e-300)
        velocity = np.take(self.advection.velocity(time), layout.node_index, axis=1)
        for axis in range(2):
            out[layout.order, axis] = span * layout.reduce(np.add, weight * velocity[axis]) / total
        return out


def _built_scheme(name: str, stepper: "Stepper") -> tuple:
    """The scheme ``name`` for ``stepper``, and where it is defined if in the user's own
    module (:meth:`~femphase.registry.Registry.origin`), else None: one of the user's that
    cannot be built is refused naming it (SceneError, ``numerics.scheme``)."""
    cls = scheme_class(name)
    origin = SCHEMES.origin(name)
    with blamed(origin, lambda exc: SceneError("numerics.scheme", name, f"a scheme built as {origin}(stepper): it "
                                               f"raised {type(exc).__name__}: {exc}")):
        return cls(stepper), origin
