"""Discretisation choices: the records and option names every layer reads.

This module is the bottom of femphase's layers (docs/architecture.md): it imports nothing of
femphase but its errors, so the domains, the time schemes and the scene can all depend on
:class:`Numerics` without depending on each other. Registries of names (time schemes, flows,
domains) live with what they register; the option tuples here are the fixed choices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from femphase.errors import SceneError

__all__ = ["DIAGONAL_PATTERNS", "ESTIMATES", "FD_ADVECTION", "MASS_TYPES", "MESH_ADVECTIONS", "PRECISIONS",
           "SOLVER_METHODS", "Numerics"]

#: Triangulations of the structured channel: every square cut along the same diagonal
#: ("right": lower left to upper right; "left") or the two alternating.
DIAGONAL_PATTERNS = ("right", "left", "alternating")
#: ``numerics.solver``: see :class:`Numerics`.
SOLVER_METHODS = ("auto", "direct", "amg", "tensor", "batched")
#: ``numerics.mass``: the mass matrix in the time derivative.
MASS_TYPES = ("lumped", "consistent")
#: ``numerics.fd_advection``: the finite-difference reference's advection differences.
FD_ADVECTION = ("upwind3", "upwind1")
#: ``numerics.precision``.
PRECISIONS = ("mixed", "double")
#: ``numerics.mesh_advection``: see :class:`Numerics`.
MESH_ADVECTIONS = ("auto", "galerkin", "runge-kutta", "semi-lagrangian")
#: ``numerics.mesh_windows``: see :class:`Numerics`.
MESH_WINDOWS = ("auto", "shapes", "boxes")
#: ``numerics.estimate``: see :class:`Numerics`.
ESTIMATES = ("embedded", "doubling")


@dataclass(frozen=True)
class Numerics:
    """Discretisation choices (scene table ``[numerics]``).

    =============== =========================================================================================
    scheme          the time scheme, a name in :data:`femphase.timestepping.SCHEMES`
                    (checked when a scene or a stepper uses it): "adaptive" (default):
                    error-controlled second-order substeps inside each step of the phase, whose
                    dt is then the largest substep and the spacing of frames and checkpoints;
                    "sav2": second order at fixed dt; "euler": first order (linearly implicit
                    Euler with Lie splitting); "fd-heun": the
                    finite-difference reference, structured channel only
    mass            "lumped" (default) or "consistent" mass matrix in the time derivative
    stabilisation   "auto" (the smallest energy-stable S for each dt) or a number ≥ 0
    solver          "auto", "direct" (cached LU per window key), "amg" (pyamg-preconditioned
                    CG per window key), "tensor" (exact tensor-product solve; structured
                    channel, one diagonal direction, lumped mass) or "batched" (Jacobi-
                    preconditioned Krylov on all windows at once, :mod:`femphase.fem.blocks`).
                    "auto": on meshes "batched"; on the structured channel tensor where it
                    applies, else LU up to DIRECT_MAX_DOFS, else AMG
    tolerance       relative residual of the Krylov solves ("amg": 2-norm; "batched":
                    max|D⁻¹r| against max|D⁻¹b|, D the diagonal; under the adaptive scheme
                    the batched solves use at least 1e-3 of the local error allowed per
                    substep, :meth:`Numerics.krylov_tolerance`)
    tolerance_t     "adaptive" scheme only: the local error allowed per substep (max-norm of φ,
                    dimensionless) in phases with flow; in phases without a tenth of it at the
                    default, falling as its power 3/4 about the default
                    (:meth:`Numerics.substep_tolerance`), so that errors there follow it in
                    proportion. The default, 0.1,
                    keeps the time error below the spatial error at h = 1: the lattice's
                    r(t) within 1.2 % (h-error 12 %), a relaxing disc's area within 0.06,
                    0.07, 0.11, 0.014 at t = 10, 20, 50, 100 (h = 1 → 0.5 differences 0.15,
                    0.41, 0.31, 0.086), two discs' separation after 20000 time units within
                    1.5e-3 (h-error ≥ 0.07) (benchmarks/README.md, "Tolerance
                    proportionality")
    estimate        "adaptive" scheme, phases with flow: the error estimate that drives the
                    substeps. "embedded" (default): the first-order companion step's
                    difference, free, which sees the splitting of advection and repulsion
                    decay only through the midpoint step (ceilings hold the stiff split parts);
                    ``tolerance_t`` bounds it per substep. "doubling": every substep of h is
                    also taken as two of h/2 (splitting included) and the halves are kept;
                    their local error, a third of the two results' largest difference, contains
                    every error the step makes, and ``tolerance_t`` bounds it per time unit
                    (error per unit step: local error ≤ tolerance_t × h), so that the global
                    error follows ``tolerance_t`` in proportion. Three relaxations per substep
                    instead of one, in double precision whatever ``precision``
                    (:meth:`single_precision_allowed`;
                    docs/decisions/0053-step-doubling-estimate.md). Without flow the step is
                    not split and the embedded estimate runs
    repulsion_split "sav2" and "adaptive" under flow only: True (default) splits the repulsion
                    off the explicit midpoint step (Strang) and integrates it as the pointwise
                    decay it is, in exponential form (:meth:`femphase.timestepping.sav2.RelaxedSAV2.relax`);
                    False: the explicit midpoint step of all terms
    area_implicit   "sav2" and "adaptive" only: True treats the area term's stiff rank-one mode
                    (each particle's area relaxing back at J0·8μ/(πR²) ≈ 0.4 per time unit)
                    linearly implicitly in the predictor (one more solve per substep;
                    :meth:`femphase.timestepping.sav2.RelaxedSAV2.rank_one_predictor`); False: explicit
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
                    at its end only (:class:`femphase.timestepping.adaptive.AdaptiveSAV2`): 0.94× the CPU per
                    time unit on the lattice with calls of 2 steps, 0.87× with 8 (same run;
                    docs/decisions/0008-merged-steps.md); results then depend on where calls
                    end, at the level of the splitting error. Other schemes step one by one;
                    trackers' ``after_step`` runs after every call
    precision       "mixed" (default): under flow on the structured channel and on meshes
                    with batched solves, each stepper call computes in single precision
                    (float32) on a working copy of the fields: forces, tensor solves,
                    row-shift FFTs, a mesh's CG solves and advection, error estimates; the state
                    between calls (at frames, T1 looks, every merged_steps steps), checkpoints,
                    observables and energies are double. Rounding ~1e-6 relative, against the
                    default scheme's time error of ~1e-2 (docs/decisions/0012-single-precision-flow-steps.md
                    gives the CPU saved and the errors, unchanged). Phases without flow
                    compute in double (their steps must not raise F, checked to 1e-12), and
                    so do meshes with per-box solvers ("direct", "amg": their LU and Padé
                    solves are double only), the finite-difference reference and the adaptive
                    scheme's flow steps at tolerance_t below 1e-4, where single precision's
                    rounding would set the error (:attr:`Numerics.SINGLE_PRECISION_TOLERANCE`).
                    "double": everything in double, for convergence studies whose errors
                    reach ~1e-5 (verification/mms.py sets it) and for time-converged
                    references at fixed dt: the rounding of many small steps adds up (the
                    lattice's r̄(t) by sav2 at dt = 0.25, 0.125, 0.0625 diverged at order
                    −1.9 in mixed precision, converged at 1.95 in double; benchmarks/tolerance.py)
    strict          False (default): a run that leaves the accuracy envelope measured in
                    benchmarks/stability.py warns (:class:`femphase.run.guards.AccuracyWarning`,
                    naming the scene key to change); True: it stops with
                    :class:`femphase.run.guards.AccuracyError` at that step (docs/outputs.md)
    mesh_advection  meshes only: "auto" (default): in a steady flow with the batched solves,
                    semi-Lagrangian for every advection of Courant number max|v| dt/h ≥ 2 (h
                    the median edge), Galerkin below (:mod:`femphase.domains.mesh.semi_lagrangian`;
                    docs/decisions/0043);
                    "galerkin": the Galerkin step at every Courant number (the explicit
                    Taylor–Galerkin step with the batched solves, Galerkin–Padé with
                    per-window solvers; docs/decisions/0058); "runge-kutta": the explicit
                    three-stage Runge–Kutta step at every Courant number (K + 1 products per
                    stage instead of per substep; kept for discretisation studies);
                    "semi-lagrangian": semi-Lagrangian at every Courant number (steady flows
                    only; below 2 its interpolation errors exceed the Galerkin step's,
                    docs/decisions/0042)
    mesh_windows    meshes only: what a window is. "shapes": the dofs within a reach of the
                    particle, along the mesh's edges (:mod:`femphase.domains.mesh.shapes`);
                    "boxes": the dofs in an axis-aligned box around it
                    (:mod:`femphase.domains.mesh.boxes`); "auto" (default): shapes with the
                    batched solves, else boxes (docs/decisions/0057-shaped-mesh-windows.md)
    cache_mib       mebibytes (2²⁰ bytes) that everything a run keeps for reuse may hold
                    together: window dofs, per-window blocks and solvers, the current
                    layout's block-diagonal matrices, advections per substep size (the
                    domain's one budget, :class:`femphase.caches.ByteBudget`; least recently
                    used dropped first). Default 256: examples/obstacle_mesh.toml (N = 95,
                    dt = 10) holds 37–39 MiB of it under flow (benchmarks/mesh_memory.py;
                    docs/decisions/0020-one-cache-budget.md)
    =============== =========================================================================================
    """

    scheme: str = "adaptive"
    mass: str = "lumped"
    stabilisation: float | str = "auto"
    solver: str = "auto"
    tolerance: float = 1e-10
    tolerance_t: float = 0.1
    estimate: str = "embedded"
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
    mesh_advection: str = "auto"
    mesh_windows: str = "auto"
    cache_mib: float = 256.0

    #: The batched Krylov solves' tolerance under the adaptive scheme, as a fraction of the
    #: local error the scheme allows per substep (:meth:`substep_tolerance`): their error then
    #: stays 10³ below it, and far below the time error. Measured on examples/straight_mesh.toml
    #: (relaxation 400, then 1200 time units of its Stokes flow at dt = 10, against solves to
    #: 1e-10; benchmarks/krylov_tolerance.py): at 1e-3 centroids moved by 7.3e-4, φ by 6.6e-4
    #: and areas by 6.5e-4 (relative), at 1e-4 by 3.4e-4, 5.3e-4 and 5.8e-4, at 1e-2 by 0.011,
    #: 9.0e-3 and 1.4e-3, where substeps of 2.5 instead of 3.33 move them by 0.18, 0.11 and
    #: 2.3e-2; CG iterations 4041 + 3217 at 1e-3 against 4874 + 3823 at 1e-4
    #: (docs/decisions/0029-mesh-solves-at-1e-3.md).
    KRYLOV_FRACTION = 1e-3
    #: The same for the solve of the second-order steps' predictor, the linearly implicit half
    #: step whose result φ̄ enters the step only through the explicit forces g(φ̄), times J0 dt,
    #: and the error estimate (:meth:`femphase.timestepping.sav2.RelaxedSAV2.relax`): at 1e-2 of
    #: the substep's tolerance its error is a hundredth of what the estimate may be. Measured on
    #: examples/straight_mesh.toml (relaxation 400, then 1200 time units of its Stokes flow
    #: at dt = 10, against solves to 1e-10; benchmarks/krylov_tolerance.py): centroids moved by
    #: 7.3e-4 (3.8e-4 with the predictor at 1e-5 of the substep's tolerance), where substeps
    #: of 2.5 instead of 3.33 move them by 0.18, for 36 % fewer CG iterations under flow
    #: (3217 against 5036) and 20 % fewer in the relaxation
    #: (docs/decisions/0023-loose-predictor-solves.md).
    PREDICTOR_KRYLOV_FRACTION = 1e-2

    #: ``tolerance_t``'s share in phases without flow (:meth:`substep_tolerance`). There the
    #: relaxation's fast early stretch (discs growing to their area) carries the time error,
    #: and at the whole tolerance it exceeds the spatial error at h = 1 (a disc relaxing from
    #: R/2: 0.83 in area at t = 20, against 0.41 between h = 1 and 0.5; at a tenth 0.10).
    #: Under flow the whole tolerance keeps the time error far below the spatial error (the
    #: lattice's r(t): 1.2 % against 12 %), and a tenth there costs 1.68× the CPU of the
    #: protocol's run (benchmarks/tolerance.py, docs/decisions/0017-tolerance-by-phase.md).
    STILL_FRACTION = 0.1
    #: Without flow the allowed local error follows ``tolerance_t`` to the power
    #: STILL_EXPONENT about STILL_ANCHOR (the default ``tolerance_t``, where it is
    #: STILL_FRACTION of it): STILL_FRACTION · A · (tolerance_t/A)^STILL_EXPONENT. The step
    #: without flow takes a second corrector pass (docs/decisions/0030-second-corrector-pass.md),
    #: and its observables converge at order p ≈ 2.5 (a relaxing disc's area) to 2.8 (two
    #: discs' separation) in the substep, while the estimate is a first-order step's local
    #: error, O(h²): at a tolerance in proportion their errors fell as tolerance^(p/2), slopes
    #: 1.15 and 1.31. The power 2/p ≈ 3/4 brings them to 0.84 and 1.04
    #: (docs/decisions/0044-still-tolerance-power.md); the default is unchanged.
    STILL_EXPONENT = 0.75
    STILL_ANCHOR = 0.1

    def substep_tolerance(self, still: bool) -> float:
        """The local error the adaptive scheme allows per substep (max-norm of φ): ``tolerance_t``
        in phases with flow; in phases without (``still``) STILL_FRACTION · A ·
        (``tolerance_t``/A)^STILL_EXPONENT, A = STILL_ANCHOR (a tenth of ``tolerance_t`` at the
        default 0.1; 1.8e-3 at 1e-2, 3.2e-4 at 1e-3, 1e-5 at 1e-5)."""
        if not still:
            return self.tolerance_t
        anchor = self.STILL_ANCHOR
        return self.STILL_FRACTION * anchor * (self.tolerance_t / anchor) ** self.STILL_EXPONENT

    #: The tightest ``tolerance_t`` at which "mixed" precision still computes flow steps in
    #: single precision under the adaptive scheme; below it they compute in double
    #: (:meth:`single_precision_allowed`). Their rounding otherwise sets a floor: the sheared
    #: lattice's r̄(t) error against a double-precision reference was 8.1e-5 of max r̄ at 1e-4
    #: (double: 7.7e-5) and 9.8e-5 at 1e-5 (double: 9.7e-6; docs/decisions/0018-nyquist-mode.md).
    SINGLE_PRECISION_TOLERANCE = 1e-4

    def single_precision_allowed(self, scheme: str) -> bool:
        """Whether flow steps of ``scheme`` (the one the stepper runs, which ``--method`` may
        set apart from ``self.scheme``) may compute in single precision: ``precision =
        "mixed"``, and for "adaptive" a ``tolerance_t`` of at least SINGLE_PRECISION_TOLERANCE
        and the embedded estimate. The step-doubling estimate divides the halves' difference
        by the substep, so float32 rounding (~1e-6 per substep) reads as an error growing as
        the substep shrinks, and the controller then refines to the smallest substeps."""
        return self.precision == "mixed" and (scheme != "adaptive"
                                               or (self.tolerance_t >= self.SINGLE_PRECISION_TOLERANCE
                                                   and self.estimate == "embedded"))

    def krylov_tolerance(self, still: bool) -> float:
        """Relative tolerance of the batched Krylov solves of the window systems:
        ``tolerance`` for schemes at fixed dt, and under the adaptive scheme the larger of
        ``tolerance`` and KRYLOV_FRACTION of the local error it allows per substep
        (:meth:`substep_tolerance`; at the default 1e-4 under flow, 1e-5 without), so the
        solves are as accurate as the step needs and no more."""
        return self._substep_share(self.KRYLOV_FRACTION, still)

    def predictor_krylov_tolerance(self, still: bool) -> float:
        """:meth:`krylov_tolerance` for the predictor's solve: under the adaptive scheme
        PREDICTOR_KRYLOV_FRACTION of the local error it allows per substep
        (:meth:`substep_tolerance`; at the default 1e-3 under flow, 1e-4 without), at
        fixed dt ``tolerance``."""
        return self._substep_share(self.PREDICTOR_KRYLOV_FRACTION, still)

    def _substep_share(self, fraction: float, still: bool) -> float:
        """Under the adaptive scheme the larger of ``tolerance`` and ``fraction`` of the local
        error allowed per substep; ``tolerance`` at fixed dt."""
        if self.scheme == "adaptive":
            return max(self.tolerance, fraction * self.substep_tolerance(still))
        return self.tolerance

    def __post_init__(self) -> None:
        if not isinstance(self.scheme, str):
            raise SceneError("numerics.scheme", self.scheme, "the name of a time scheme (a string)")
        for key, value, valid in (("mass", self.mass, MASS_TYPES), ("solver", self.solver, SOLVER_METHODS),
                                  ("fd_advection", self.fd_advection, FD_ADVECTION),
                                  ("diagonals", self.diagonals, DIAGONAL_PATTERNS),
                                  ("precision", self.precision, PRECISIONS),
                                  ("mesh_advection", self.mesh_advection, MESH_ADVECTIONS),
                                  ("mesh_windows", self.mesh_windows, MESH_WINDOWS),
                                  ("estimate", self.estimate, ESTIMATES)):
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
        for key, low, high in (("threshold", 0.0, 0.5), ("margin", 0.0, np.inf), ("tolerance", 0.0, 1.0),
                               ("tolerance_t", 0.0, 1.0), ("blowup_margin", 0.0, np.inf),
                               ("cache_mib", 0.0, np.inf)):
            value = getattr(self, key)
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and low < value < high
            if not ok:
                raise SceneError(f"numerics.{key}", value, f"a number in ({low:g}, {high:g})")
