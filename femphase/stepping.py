"""The stepper: advances a State by steps of fixed dt on any Domain, with any time scheme.

One step:

1. refit the windows that no longer fit their fields (:meth:`femphase.domain.Domain.refit`);
2. the time scheme (:mod:`femphase.schemes`, chosen by ``numerics.scheme``) advances the
   gathered fields, using what the stepper offers: the advection of the domain in the flow
   (:attr:`Stepper.advection`), the explicit part g of δF/δφ
   (:meth:`Stepper.explicit_derivative`), window-by-window solves of
   (c G + J0 S M_L + J0 D K) φ = rhs (:meth:`Stepper.solve`), and the source term;
3. a check that φ is finite and near [0, 1] (else :class:`~femphase.errors.BlowUpError`
   naming the step, with the state untouched).

Every window solves the principal submatrix of the full-domain system on its dofs (see
:mod:`femphase.windows`); solvers are built once per window key and system, and all windows
of a key are solved in one multi-right-hand-side call; the solvers kept are bounded in
memory (:attr:`Stepper.SOLVER_CACHE_BYTES`, least recently used dropped first).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

from .domain import Domain, window_block
from .energy import FreeEnergy, WindowedFields
from .errors import BlowUpError, SceneError
from .flows import Flow, no_flow
from .model import ModelParameters
from .registry import Registry
from .solvers import SOLVER_METHODS
from .state import State
from .windows import Layout

MASS_TYPES = ("lumped", "consistent")
FD_ADVECTION = ("upwind3", "upwind1")
PRECISIONS = ("mixed", "double")

#: Time schemes by name (``numerics.scheme``); filled by :mod:`femphase.schemes` and :mod:`femphase.fd`.
SCHEMES: Registry[type] = Registry("Time schemes", "numerics.scheme")


@dataclass(frozen=True)
class Numerics:
    """Discretisation choices (scene table ``[numerics]``).

    scheme          the time scheme, a name in :data:`SCHEMES`: "adaptive" (default):
                    error-controlled second-order substeps inside each step of the phase, whose
                    dt is then the largest substep and the spacing of frames and checkpoints;
                    "sav2": second order at fixed dt; "euler": first order (linearly implicit
                    Euler with Lie splitting; the default before issue 12); "fd-heun": the
                    finite-difference reference, structured channel only
    mass            "lumped" (default) or "consistent" mass matrix in the time derivative
    stabilisation   "auto" (the smallest energy-stable S for each dt) or a number ≥ 0
    solver          "auto", "direct" (cached LU), "amg" (pyamg-preconditioned CG) or "tensor"
                    (exact tensor-product solve; structured channel, one diagonal direction,
                    lumped mass). "auto": tensor where it applies, else LU up to
                    DIRECT_MAX_DOFS, else AMG
    tolerance       relative residual of the AMG-Krylov solves
    tolerance_t     "adaptive" scheme only: the local error allowed per substep (max-norm of φ,
                    dimensionless). The default, 0.1, keeps the lattice's period within 0.3 %
                    and r(t) within 2 % of a time-converged run (0.15 % and 1.1 %;
                    benchmarks/README.md, "Time schemes"); 3e-2 until session 10, whose
                    substep sizes between the powers of two let 0.1 take larger substeps
    repulsion_split "sav2" and "adaptive" under flow only: True (default) splits the repulsion
                    off the explicit midpoint step (Strang) and integrates it as the pointwise
                    decay it is, in exponential form (:meth:`femphase.schemes.RelaxedSAV2.relax`);
                    False: the explicit midpoint step of all terms (femphase before session 8,
                    with tolerance_t 1e-2 its default then)
    area_implicit   "sav2" and "adaptive" only: True treats the area term's stiff rank-one mode
                    (each particle's area relaxing back at J0·8μ/(πR²) ≈ 0.4 per time unit)
                    linearly implicitly in the predictor (one more solve per substep;
                    :meth:`femphase.schemes.RelaxedSAV2.rank_one_predictor`); False: explicit
    windows         False: every field on the whole domain (full-mesh mode)
    threshold       φ above which a node belongs to a particle (window fitting)
    margin          lattice units kept between a particle and its window's edge
    diagonals       "right", "left" or "alternating" (structured channel's triangulation)
    fd_advection    the finite-difference reference's advection differences ("fd-heun"
                    only): "upwind3" (default, third order) or "upwind1" (first order)
    blowup_margin   a step fails when φ leaves [−blowup_margin, 1 + blowup_margin]. Discs
                    started at R/2 overshoot physically to φ ≈ 1.4 while the area constraint
                    inflates them (2.1 with μ × 10), so the default, 2, flags only runaways
    merged_steps    most steps of the phase's dt one stepper call takes between frames, T1
                    looks and phase ends (the default 8; 1: every step its own call). The
                    adaptive scheme runs a call's steps as one run of substeps, synchronised
                    at its end only (:class:`femphase.schemes.AdaptiveSAV2`): 0.94× the CPU per
                    time unit on the lattice with calls of 2 steps, 0.87× with 8 (same run,
                    benchmarks/README.md, "Session 12"); results then depend on where calls
                    end, at the level of the splitting error. Other schemes step one by one;
                    trackers' ``after_step`` runs after every call
    precision       "mixed" (default): under flow on the structured channel, each stepper
                    call computes in single precision (float32) on a working copy of the
                    fields: forces, tensor solves, row-shift FFTs, error estimates; the state
                    between calls (at frames, T1 looks, every merged_steps steps), checkpoints,
                    observables and energies are double. Rounding ~1e-6 relative, against the
                    default scheme's time error of ~1e-2 (benchmarks/README.md, "Session 14",
                    measures the CPU saved and the errors, unchanged). Phases without flow
                    compute in double (their steps must not raise F, checked to 1e-12), and
                    so do meshes and the finite-difference reference. "double": everything in
                    double, for convergence studies whose errors reach ~1e-5
                    (verification/mms.py sets it)
    strict          False (default): a run that leaves the accuracy envelope measured in
                    benchmarks/stability.py warns (:class:`femphase.guards.AccuracyWarning`,
                    naming the scene key to change); True: it stops with
                    :class:`femphase.guards.AccuracyError` at that step (docs/outputs.md)
    """

    scheme: str = "adaptive"
    mass: str = "lumped"
    stabilisation: float | str = "auto"
    solver: str = "auto"
    tolerance: float = 1e-10
    tolerance_t: float = 0.1
    repulsion_split: bool = True
    area_implicit: bool = False
    windows: bool = True
    threshold: float = 0.01
    margin: float = 4.0
    diagonals: str = "right"
    blowup_margin: float = 2.0
    fd_advection: str = "upwind3"
    merged_steps: int = 8
    precision: str = "mixed"
    strict: bool = False

    def __post_init__(self) -> None:
        from .mesh import DIAGONAL_PATTERNS

        _load_schemes()
        SCHEMES.get(self.scheme)
        for key, value, valid in (("mass", self.mass, MASS_TYPES), ("solver", self.solver, SOLVER_METHODS),
                                  ("fd_advection", self.fd_advection, FD_ADVECTION),
                                  ("diagonals", self.diagonals, DIAGONAL_PATTERNS),
                                  ("precision", self.precision, PRECISIONS)):
            if value not in valid:
                raise SceneError(f"numerics.{key}", value, f"one of {valid}")
        if self.stabilisation != "auto" and not (
            isinstance(self.stabilisation, (int, float)) and not isinstance(self.stabilisation, bool)
            and self.stabilisation >= 0
        ):
            raise SceneError("numerics.stabilisation", self.stabilisation, '"auto" or a number ≥ 0')
        for key in ("windows", "strict", "repulsion_split", "area_implicit"):
            if not isinstance(getattr(self, key), bool):
                raise SceneError(f"numerics.{key}", getattr(self, key), "true or false")
        if not (isinstance(self.merged_steps, int) and not isinstance(self.merged_steps, bool)
                and self.merged_steps >= 1):
            raise SceneError("numerics.merged_steps", self.merged_steps, "a whole number ≥ 1")
        for key, low, high in (("threshold", 0.0, 0.5), ("margin", 0.0, np.inf), ("tolerance", 0.0, np.inf),
                               ("tolerance_t", 0.0, 1.0), ("blowup_margin", 0.0, np.inf)):
            value = getattr(self, key)
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and low < value < high
            if not ok:
                raise SceneError(f"numerics.{key}", value, f"a number in ({low:g}, {high:g})")


def _load_schemes() -> None:
    from . import fd, schemes  # noqa: F401  (register the time schemes)


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


def cached_bytes(solver, mass_block: sp.csr_matrix | None) -> int:
    """Bytes a solver cache entry holds: the solver's ``nbytes`` and, with the consistent
    mass, the window's mass block (its three CSR arrays)."""
    if mass_block is None:
        return int(solver.nbytes)
    return int(solver.nbytes + mass_block.data.nbytes + mass_block.indices.nbytes + mass_block.indptr.nbytes)


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
        self._systems: dict = {}
        self._solvers: OrderedDict = OrderedDict()  # least recently used first
        self._cached_bytes = 0
        _load_schemes()
        self.scheme = SCHEMES.get(scheme or numerics.scheme)(self)
        #: whether steps compute in single precision (numerics.precision, under flow only)
        self.single_precision = (numerics.precision == "mixed" and not self.flow.is_still
                                 and domain.single_precision_steps and self.scheme.mixed_precision)

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
        key = (shift, stabilisation)
        if key not in self._systems:
            ops = self.domain.operators
            consistent = not self.lumped
            time_mass = ops.mass if consistent else sp.diags(ops.lumped_mass)
            matrix = (shift * time_mass + self.mobility * stabilisation * sp.diags(ops.lumped_mass)
                      + self.mobility * self.energy.diffusivity * ops.stiffness).tocsr()
            self._systems[key] = (matrix, sp.csr_matrix(time_mass) if consistent else None)
        return self._systems[key]

    def solve(self, nodal_rhs: np.ndarray, previous: np.ndarray, layout: Layout, shift: float,
              stabilisation: float) -> np.ndarray:
        """φ with (shift·G + J0 S M_L + J0 D K) φ = M_L nodal_rhs + shift·G previous, window by
        window (all vectors in layout order)."""
        lumped = self.lumped
        if lumped:  # M_L (nodal_rhs + shift·previous), in place
            rhs = previous * shift
            rhs += nodal_rhs
            rhs *= layout.mass_like(rhs)
        else:
            rhs = layout.mass * nodal_rhs
        out = np.empty_like(previous)
        for group, (key, members, start, stop, size) in enumerate(layout.groups):
            solver, mass_block = self._solver(key, layout.representative(group), shift, stabilisation)
            # (size, members) views in Fortran order, as SuperLU wants them: no copies
            current = previous[start:stop].reshape(members.size, size).T
            group_rhs = rhs[start:stop].reshape(members.size, size).T
            if not lumped:
                group_rhs = group_rhs + shift * (mass_block @ current)
            out[start:stop].reshape(members.size, size).T[...] = solver.solve(group_rhs, current)
        return out

    #: Bytes of solvers kept (their ``nbytes`` and their consistent mass blocks',
    #: :func:`cached_bytes`; the least recently used are dropped first).
    #: Windows come and go and the adaptive scheme changes its step size; on a mesh every
    #: box is its own system, whose LU costs ~2 MB resident per ~1000 dofs: keeping 4096
    #: solvers, as before session 9, took examples/obstacle_mesh.toml to 13 GB by step 5700.
    #: The structured channel's tensor solvers are ~10 kB each.
    SOLVER_CACHE_BYTES = 256 * 2**20

    def _solver(self, key, window, shift: float, stabilisation: float) -> tuple:
        cache_key = (key, shift, stabilisation)
        solvers = self._solvers
        if cache_key in solvers:
            solvers.move_to_end(cache_key)
        else:
            lumped = self.lumped
            a = shift + self.mobility * stabilisation
            solver = self.domain.solver(window, lambda: window_block(self.system(shift, stabilisation)[0],
                                                                     self.domain.window_dofs(window)),
                                        a, self.mobility * self.energy.diffusivity, lumped, self.numerics.solver,
                                        self.numerics.tolerance)
            mass_block = None if lumped else window_block(self.system(shift, stabilisation)[1],
                                                          self.domain.window_dofs(window))
            solvers[cache_key] = (solver, mass_block)
            self._cached_bytes += cached_bytes(solver, mass_block)
            while self._cached_bytes > self.SOLVER_CACHE_BYTES and len(solvers) > 1:
                _, dropped = solvers.popitem(last=False)
                self._cached_bytes -= cached_bytes(*dropped)
        return solvers[cache_key]

    # -- one step -------------------------------------------------------------------------
    def step(self, state: State, steps: int = 1) -> None:
        """Advance ``state`` by ``steps`` steps of dt in place; raises BlowUpError naming the
        step that failed, with ``state`` as it was after the last step that did not (as it
        was before the call where the scheme merges steps).

        A scheme that :attr:`~femphase.schemes.TimeScheme.merges_steps` takes them as one
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
            phi, layout = (self.scheme.advance(phi, layout, state, per_call) if self.scheme.merges_steps
                           else self.scheme.advance(phi, layout, state))
            end = state.time
            for _ in range(per_call):  # the same clock as step by step, to the last bit
                end += self.dt
            check_fields(phi, self.numerics.blowup_margin, state.step + per_call, end)
            state.windows, state.fields = list(layout.windows), layout.scatter(phi.astype(np.float64, copy=False))
            state.time, state.step = end, state.step + per_call

    def refit(self, layout: Layout, phi: np.ndarray, time: float | None = None) -> tuple[Layout, np.ndarray]:
        """(layout, φ) after refitting the windows that no longer fit their fields; with
        ``time``, windows leave room for the motion of a step from then (meshes)."""
        motion = None if time is None else (lambda: self._motion(layout, phi, time))
        return self.domain.refit(layout, phi, self.policy, motion)

    def _motion(self, layout: Layout, phi: np.ndarray, time: float) -> np.ndarray:
        """(N, 2): each particle's displacement over the coming step, its φ²-weighted mean
        velocity × dt (particle order)."""
        out = np.zeros((len(layout.windows), 2))
        if self.advection is None:
            return out
        weight = layout.mass * phi**2
        total = np.maximum(layout.reduce(np.add, weight), 1e-300)
        velocity = np.take(self.advection.velocity(time), layout.node_index, axis=1)
        for axis in range(2):
            out[layout.order, axis] = self.dt * layout.reduce(np.add, weight * velocity[axis]) / total
        return out
