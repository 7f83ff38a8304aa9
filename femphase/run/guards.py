"""Accuracy guards: a run warns when its steps leave the accuracy envelope measured in
``benchmarks/stability.py`` (``benchmarks/README.md``), naming the scene key to change and
the value that brings the run back.

Large steps are stable, not accurate: the "euler" scheme's stabilisation keeps every dt
energy-stable, and a run with meaningless results finishes as silently as a good one. The
guard (:class:`AccuracyGuard`, a :class:`~femphase.run.simulation.Tracker`) checks the following,
each warned (:class:`AccuracyWarning`) at most once per phase (``vanished`` once per run), or, with
``numerics.strict = true``, raised as :class:`AccuracyError` naming the step and time:

``saturation`` (before the first step of every phase; "euler" and its subclasses)
    One step moves φ by −J0 g dt_eff with dt_eff = dt/(1 + J0 S dt) (:mod:`femphase.timestepping.base`):
    the explicit forces relax ``slowdown`` = 1 + J0 S dt times slower than the clock while
    advection runs at full speed. With the lumped mass and S = "auto" the slowdown is
    dt/dt*, dt* = 2/(J0 L) the largest step with S = 0 (0.92 at the paper's parameters, 3.0
    for a single particle). Warned when the slowdown exceeds :data:`SLOWDOWN_LIMIT` = 1.1.
    Measured: the paper's default dt = 1 has 1.08 (relaxation 8 % slow; lattice r(t) error
    6.1 %, period error 0.38 %, on the work–precision front); an isolated particle sheared at
    γ̇ = 1 is up to 61 % off in elongation at dt = 4 (1.33; 47 % at γ̇ = 0.1487) against 3 %
    at dt = 1 (0.33) and 6 % at dt = 2 (0.67), and settles 5.9× too elongated at dt = 10
    (3.3); the slab's areas drift by 0.15 over the second half of a 200-time-unit run at
    dt = 10 (10.8) against 4e-6 at dt = 1. The consistent mass (c = 1/4) has slowdown
    3/4 + J0 L dt/2, 1.83 at dt = 1 (its lattice r(t) error: 54 %).
``explicit fraction`` (the CFL of the explicit terms, reported with the saturation)
    dt/dt*: the fraction of the unstabilised explicit limit a step uses ("euler": > 1 means
    the stabilisation is active, the same measure as the slowdown; "fd-heun":
    dt/:func:`femphase.timestepping.fd.explicit_stability_limit`, which the scheme enforces itself).
``advection`` (before every phase and at every frame, when the phase has a flow)
    Windows are refitted at the start of every step so that ``numerics.margin`` (4 lattice
    units) separates a particle (φ > ``numerics.threshold``) from its window's edge, and the
    window follows the particle's mean motion; a part of the particle that moves more than
    the margin relative to that mean within one step leaves the window (the structured
    channel's row shift then wraps it to the window's other side, a mesh box cuts it off).
    The measure is dt·max|v − v̄_i| over the occupied dofs of particle i (v̄_i its
    φ²-weighted mean velocity) divided by the margin; warned above
    :data:`ADVECTION_LIMIT` = 1 (the paper's lattice: 0.002).
``fine grid`` (before every phase with a flow; "adaptive")
    Below h = :data:`FINE_GRID_SPACING` = 0.5 a ``numerics.tolerance_t`` above
    :data:`FINE_GRID_TOLERANCE` = 0.01: the paper's lattice at h = 0.25 at the default
    tolerance 0.1 (dt = 10, substeps 3.33) does not reproduce the oscillation of h = 1 and
    0.5 (r̄ irregular, peaks 1.6–2.0 against 1.0), and with dt = 2.5 it oscillates out of
    phase with the converged run (mean r 0.27 at t = 3000 against 1.02); at 0.01 it follows
    the run at 0.003 to 1e-3 (0.53, 1.02, 0.34, 0.20 at t = 2500, 3000, 3500, 4000, as at
    h = 0.5).
``area`` (at every frame from t = :func:`relaxation_time` on)
    a_i = ∫φ_i²/(πR_i²) outside [:data:`AREA_RATIO_MIN`, :data:`AREA_RATIO_MAX`] =
    [0.6, 1.25]. Equilibrium areas are not πR²: the diffuse interface and the neighbours'
    pressure hold them at a ≈ 0.97 (isolated particle), 0.84–0.87 (the paper's density),
    0.77 (sheared at γ̇ = 10, velocity gradient 10/240, dt = 0.1, FD alike), 0.786 (the
    densest benchmark, random N = 100, at t = 300). Every benchmark run inside the other
    limits keeps a ≥ 0.69 (FD on the random N = 100 scene at t = 50, still relaxing); runs
    far outside the envelope fall below 0.6: 0.52 (slab, γ̇ = 1, dt = 100), 0.34 (κ × 10,
    dt = 10), 0.20 (γ̇ = 10, dt = 100), 0.29–0.47 (the paper's lattice at γ̇ = 100, at
    dt = 1 and 0.1 alike: the particles are smeared into lanes, r ≈ 30). 1.25 is the largest area for
    which the stabilisation's curvature bound holds (:data:`femphase.model.energy.AREA_RATIO_MAX`).
    The check starts at t = 40 τ_A, τ_A = πR²/(8 J0 μ) the area constraint's relaxation
    time (largest R; 100 time units at the paper's parameters): discs started at R/2 grow
    logistically at rate 1/τ_A, and every healthy benchmark scene has all areas above 0.6
    from t = 15 on (slab: t = 10). Without an area term (μ = 0) it is off. The message names
    the likely cause: a saturated step (``phases.K.dt``), a flow whose strain rate exceeds the strongest measured one,
    :data:`STRAIN_RATE_ENVELOPE` = 10/240 (the flow's velocity key, e.g.
    ``phases.K.flow.rate``), or else the area stiffness (``model.mu``).

``vanished`` (at every frame, with or without an area term)
    a_i < :data:`VANISHED_RATIO` = 0.01 (or below its start, for a particle started smaller):
    the particle's field has all but disappeared. A
    particle shrinks by its interface's curvature unless the area term holds it; without it
    (μ = 0) a disc of R = 3 vanishes within 300 time units (areas 1e-30 and below), and its
    centroid, elongation and orientation, computed from a field of rounding noise, wander
    (elongation 3.6 and 11 in particles.csv) until its φ reaches 1/2 nowhere
    (:data:`femphase.analysis.shape.PRESENT_LEVEL`), from where they are NaN
    (:func:`femphase.analysis.shape.present`). The warning
    names the particle, its area and the time from which its shape columns mean nothing, and
    the key that holds particles at their area (``model.mu``).

Not guarded (not measured): the Galerkin–Padé step's accuracy at large Courant numbers on
meshes (0.1 % lag at u dt/h = 1; the default explicit step subcycles at ω h ≤ 1 and has no
such limit), the first-order splitting error below dt*.

The measures are pure functions (:func:`step_measures`, :func:`area_ratios`,
:func:`advective_spread`, :func:`max_strain_rate`, :func:`relaxation_time`) usable on their
own.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from femphase.domains.advection import nodal_velocity
from femphase.errors import RunStopped
from femphase.flows import Flow
from femphase.model.energy import AREA_RATIO_MAX as CURVATURE_AREA_MAX
from femphase.model.energy import FreeEnergy
from femphase.run.simulation import METHODS, Frame, Simulation, Tracker
from femphase.scene import Phase, Scene
from femphase.state import State
from femphase.timestepping.base import MASS_BOUND, SCHEMES, auto_stabilisation, stability_step
from femphase.timestepping.euler import LinearlyImplicitEuler
from femphase.timestepping.fd import explicit_stability_limit

__all__ = ["ADVECTION_LIMIT", "AREA_RATIO_MAX", "AREA_RATIO_MIN", "FINE_GRID_SPACING", "FINE_GRID_TOLERANCE",
           "RELAXATION_TIMES", "SLOWDOWN_LIMIT", "VANISHED_RATIO",
           "STRAIN_RATE_ENVELOPE", "AccuracyError", "AccuracyGuard", "AccuracyWarning", "StepMeasures",
           "advective_spread", "area_ratios", "max_strain_rate", "relaxation_time", "step_measures"]


#: Largest accepted relaxation slowdown 1 + J0 S dt (dt/dt* for the lumped "auto").
SLOWDOWN_LIMIT = 1.1
#: Largest accepted advective displacement spread per step, in window margins.
ADVECTION_LIMIT = 1.0
#: Accepted particle areas ∫φ²/(πR²) after the relaxation.
AREA_RATIO_MIN = 0.6
AREA_RATIO_MAX = CURVATURE_AREA_MAX
#: Below this ∫φ²/(πR²) a particle has vanished (checked at every frame, whatever μ).
VANISHED_RATIO = 0.01
#: The area check starts after this many area relaxation times τ_A = πR²/(8 J0 μ).
RELAXATION_TIMES = 40.0
#: The strongest velocity gradient of the measured envelope (the slab sheared at γ̇ = 10 in
#: the paper's units, u = γ̇ y/240): areas ≥ 0.77, FEM at dt = 0.1 and 1 and FD agreeing.
STRAIN_RATE_ENVELOPE = 10.0 / 240.0
#: Below this spacing the adaptive scheme needs ``tolerance_t`` ≤ FINE_GRID_TOLERANCE under
#: flow: at the default 0.1 the lattice at h = 0.25 loses its oscillation, at 0.01 it agrees
#: with 0.003 (docs/design/time-schemes.md, "Measured limits").
FINE_GRID_SPACING = 0.5
FINE_GRID_TOLERANCE = 0.01
#: Flow keys that scale the velocity linearly, by flow type.
VELOCITY_KEYS = {"shear": "rate", "poiseuille": "rate", "oscillating_shear": "rate", "stokes": None}
STOKES_KEYS = ("max_velocity", "flux", "pressure_drop")
#: The scene key that sets each energy term's curvature bound (what makes dt* small).
TERM_KEYS = {"interface": "model.gamma", "area": "model.mu", "repulsion": "model.kappa"}


class AccuracyWarning(UserWarning):
    """A run left the accuracy envelope of ``benchmarks/stability.py``; the message names the
    scene key to change and the value that brings it back."""


class AccuracyError(RunStopped):
    """``numerics.strict``: a run left the accuracy envelope (the step and time are named)."""

    def __init__(self, step: int, time: float, reason: str) -> None:
        self.step, self.time, self.reason = step, time, reason
        super().__init__(f"the run left the accuracy envelope at step {step} (t = {time:g}): {reason} "
                         "(numerics.strict = true; set it false to continue with a warning)")


# -- measures ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class StepMeasures:
    """How one phase's step relates to the explicit terms' limits.

    ================= ========================================================================
    scheme            the time scheme's name
    dt                the step
    dt_star           the largest step with no stabilisation ("euler"; inf without curvature),
                      or the explicit stability limit ("fd-heun"); NaN for other schemes
    stabilisation     S ("euler"), else NaN
    slowdown          1 + J0 S dt: how much slower than dt the explicit forces relax (1: none)
    explicit_fraction dt/dt_star
    accurate_dt       the largest dt with slowdown ≤ ``limit`` (same settings), or inf
    ================= ========================================================================
    """

    scheme: str
    dt: float
    dt_star: float
    stabilisation: float
    slowdown: float
    explicit_fraction: float
    accurate_dt: float


def step_measures(scene: Scene, phase: Phase, radii: np.ndarray, *, scheme: str | None = None,
                  energy=None, limit: float = SLOWDOWN_LIMIT) -> StepMeasures:
    """The :class:`StepMeasures` of ``phase`` of ``scene`` for particles of target ``radii``
    (``scheme`` overrides ``numerics.scheme``, ``energy`` the paper's free energy)."""
    numerics, model = scene.numerics, scene.model
    name = scheme or numerics.scheme
    energy = energy or FreeEnergy.paper(model)
    radii = np.asarray(radii, dtype=float)
    smallest = float(radii.min()) if radii.size else model.radius
    pairs = radii.size > 1  # as the stepper: one particle has no repulsion curvature
    dt, j0 = float(phase.dt), model.mobility
    nan = float("nan")
    cls = SCHEMES.get(name)
    if issubclass(cls, LinearlyImplicitEuler):
        dt_star = stability_step(energy, j0, numerics.mass, smallest, pairs)
        curvature = energy.curvature_bound(smallest, pairs)
        if numerics.stabilisation == "auto":
            s = auto_stabilisation(energy, j0, numerics.mass, dt, smallest, pairs)
            # 1 + J0 S(dt) dt ≤ limit ⟺ dt ≤ 2(limit − 1 + c)/(J0 L) (or S = 0: dt ≤ dt*)
            accurate = max(dt_star, 2.0 * (limit - 1.0 + MASS_BOUND[numerics.mass]) / (j0 * curvature)) \
                if curvature > 0 else float("inf")
        else:
            s = float(numerics.stabilisation)
            accurate = (limit - 1.0) / (j0 * s) if s > 0 else float("inf")
        return StepMeasures(name, dt, dt_star, s, 1.0 + j0 * s * dt, dt / dt_star, accurate)
    if name == "fd-heun":
        flow = scene.flow(phase)
        speed = 0.0
        if not flow.is_still:
            velocity = _velocity(scene.domain, flow, 0.0)
            speed = float(np.abs(velocity[0]).max() + np.abs(velocity[1]).max())
        limit_dt = explicit_stability_limit(model, scene.domain.spacing, speed, smallest, energy)
        return StepMeasures(name, dt, limit_dt, nan, 1.0, dt / limit_dt, limit_dt)
    return StepMeasures(name, dt, nan, nan, 1.0, nan, float("inf"))


def area_ratios(state: State) -> np.ndarray:
    """a_i = ∫φ_i²/(πR_i²) (nodal quadrature, particle order)."""
    layout, phi = state.flat()
    area = np.empty(state.n_particles)
    area[layout.order] = layout.reduce(np.add, layout.mass * phi**2)
    return area / (np.pi * np.asarray(state.radii, dtype=float) ** 2)


def relaxation_time(scene: Scene, radii: np.ndarray | None = None) -> float:
    """RELAXATION_TIMES × τ_A, τ_A = πR²/(8 J0 μ) for the largest target radius: the time
    from which the area check applies (inf without an area term)."""
    model = scene.model
    if model.area_stiffness <= 0:
        return float("inf")
    return RELAXATION_TIMES / model.area_rate(float(np.max(scene.radii if radii is None else radii)))


def _velocity(domain, flow: Flow, time: float) -> np.ndarray:
    return nodal_velocity(domain, flow, time)


def advective_spread(state: State, velocity: np.ndarray, dt: float, threshold: float) -> np.ndarray:
    """(N,) ``dt · max |v − v̄_i|`` over the dofs of particle i where φ_i > ``threshold``, v̄_i
    its φ²-weighted mean velocity: how far a part of the particle moves relative to its
    window in one step (lattice units). ``velocity`` is (2, n_dofs)."""
    layout, phi = state.flat()
    v = np.take(np.asarray(velocity, dtype=float), layout.node_index, axis=1)
    weight = layout.mass * phi**2
    total = np.maximum(layout.reduce(np.add, weight), 1e-300)
    deviation = np.zeros_like(phi)
    for axis in range(2):
        mean = layout.reduce(np.add, weight * v[axis]) / total
        deviation += (v[axis] - np.repeat(mean, layout.sizes)) ** 2
    occupied = np.where(phi > threshold, np.sqrt(deviation), 0.0)
    out = np.zeros(state.n_particles)
    if occupied.size:
        out[layout.order] = dt * layout.reduce(np.maximum, occupied)
    return out


def max_strain_rate(domain, velocity: np.ndarray) -> float:
    """max over elements of ``|∇v|`` (Frobenius norm; G for the shear u = G y): the largest
    velocity gradient of the nodal velocity (2, n_dofs) on ``domain``."""
    gx, gy = domain.operators.gradient
    squares = sum((g @ np.asarray(component, dtype=float)) ** 2 for g in (gx, gy) for component in velocity)
    return float(np.sqrt(np.max(squares))) if np.size(squares) else 0.0


# -- the tracker -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Issue:
    """One guard finding: its kind ("saturation", "fine grid", "advection", "area", "vanished"), the phase index, the
    step and time it was found at, the scene key to change and the message."""

    kind: str
    phase: int
    step: int
    time: float
    key: str
    message: str


class AccuracyGuard(Tracker):
    """Warns (or, ``strict``, raises :class:`AccuracyError`) when a run leaves the accuracy
    envelope; see the module docstring for the checks and their tolerances. ``strict``
    defaults to the scene's ``numerics.strict``. Found issues are kept in :attr:`issues`."""

    needs: frozenset = frozenset()

    def __init__(self, strict: bool | None = None) -> None:
        self.strict = strict
        self.issues: list[Issue] = []

    # -- tracker interface
    def start(self, simulation: Simulation, state: State) -> None:
        self.simulation = simulation
        self.scene = simulation.scene
        if self.strict is None:
            self.strict = bool(self.scene.numerics.strict)
        self.scheme = METHODS.get(simulation.method) or self.scene.numerics.scheme
        self.relax_from = relaxation_time(self.scene, state.radii)
        # a particle started below VANISHED_RATIO (a tiny initial disc) has vanished only once it shrinks
        self._vanishes_below = np.minimum(area_ratios(state), VANISHED_RATIO) if state.n_particles else None
        self._warned: set[tuple[str, int]] = set()
        self._checked: set[int] = set()
        self._measures: dict[int, StepMeasures] = {}
        self._flows: dict[int, Flow] = {}
        self._stepped_phase: int | None = None

    def after_step(self, state: State) -> None:
        self._stepped_phase = state.phase  # the phase of this step (it is advanced after us)
        self._check_phase(state.phase, state)

    def frame(self, frame: Frame) -> None:
        state = frame.state
        ran = self._stepped_phase if self._stepped_phase is not None else min(state.phase, len(self.scene.phases) - 1)
        if state.step > 0 or self._stepped_phase is not None:
            self._check_advection(ran, state)
            ratio = self._area_ratio(state, frame.particle.get("area"))
            self._check_vanished(ran, state, ratio)
            if state.time >= self.relax_from - 1e-9:
                self._check_areas(ran, state, ratio)
        if state.phase < len(self.scene.phases):  # the phase about to run: check before its first step
            self._check_phase(state.phase, state)

    def finish(self, state: State, error: Exception | None) -> None: ...

    # -- checks
    def measures(self, index: int, radii: np.ndarray) -> StepMeasures:
        if index not in self._measures:
            self._measures[index] = step_measures(self.scene, self.scene.phases[index], radii,
                                                  scheme=self.scheme, energy=self.simulation.energy)
        return self._measures[index]

    def _flow(self, index: int) -> Flow:
        if index not in self._flows:
            self._flows[index] = self.scene.flow(self.scene.phases[index])
        return self._flows[index]

    def _check_phase(self, index: int, state: State) -> None:
        if index in self._checked:
            return
        self._checked.add(index)
        m = self.measures(index, state.radii)
        if m.slowdown > SLOWDOWN_LIMIT:
            self._report("saturation", index, state, f"phases.{index}.dt", self._saturation_message(index, m))
        self._check_fine_grid(index, state)
        self._check_advection(index, state)

    def _check_fine_grid(self, index: int, state: State) -> None:
        spacing, tolerance = self.scene.domain.resolution, self.scene.numerics.tolerance_t
        if (self.scheme == "adaptive" and spacing < FINE_GRID_SPACING - 1e-12 and tolerance > FINE_GRID_TOLERANCE
                and not self._flow(index).is_still):
            self._report("fine grid", index, state, "numerics.tolerance_t",
                         f"numerics.tolerance_t = {tolerance:g} at h = {spacing:g}: below h = {FINE_GRID_SPACING:g} "
                         f"the adaptive scheme's flow steps at that tolerance are not accurate (the lattice at "
                         f"h = 0.25 loses its oscillation at 0.1 and agrees with 0.003 at 0.01); set "
                         f"numerics.tolerance_t ≤ {FINE_GRID_TOLERANCE:g}")

    def _saturation_message(self, index: int, m: StepMeasures) -> str:
        numerics = self.scene.numerics
        if numerics.stabilisation == "auto":
            what = (f"phases.{index}.dt = {m.dt:g} is {m.explicit_fraction:.3g} × dt* = {m.dt_star:.3g} (the largest "
                    f"step without stabilisation, 2c/(J0 L)), so the stabilised relaxation runs "
                    f"{m.slowdown:.3g}× slower than the clock (dt/dt* for the lumped mass)")
            fix = f"set phases.{index}.dt ≤ {_round_down(m.accurate_dt)}"
            if numerics.mass == "consistent":
                fix += ' (or numerics.mass = "lumped", whose dt* is 4× larger)'
        else:
            what = (f"numerics.stabilisation = {m.stabilisation:g} with phases.{index}.dt = {m.dt:g} makes the "
                    f"relaxation run 1 + J0·S·dt = {m.slowdown:.3g}× slower than the clock")
            fix = (f"set phases.{index}.dt ≤ {_round_down(m.accurate_dt)} or numerics.stabilisation = \"auto\" "
                   f"(dt* = {m.dt_star:.3g})")
        fix += self._stiffest_term(self.scene.phases[index], m)
        return (f"phase {index} ({self.scene.phases[index].name!r}): {what}; results are stable but not accurate "
                f"beyond a slowdown of {SLOWDOWN_LIMIT:g} (benchmarks/README.md): {fix}")

    def _stiffest_term(self, phase: Phase, m: StepMeasures) -> str:
        """", or lower model.kappa (the repulsion term makes 99 % of L)" when one term's
        curvature bound dominates L (> 1/2), else ""."""
        radii = self.scene.radii
        smallest, pairs = (float(radii.min()), radii.size > 1) if radii.size else (self.scene.model.radius, True)
        bounds = {t.name: t.curvature_bound(smallest, pairs) for t in self.simulation.energy.terms}
        total = sum(bounds.values())
        name = max(bounds, key=bounds.get) if bounds else None
        key = TERM_KEYS.get(name)
        if total <= 0 or key is None or bounds[name] <= 0.5 * total:
            return ""
        return f", or make {key} smaller (the {name} term makes {100 * bounds[name] / total:.3g} % of L = {total:.3g})"


    def _check_advection(self, index: int, state: State) -> None:
        if ("advection", index) in self._warned:
            return
        flow = self._flow(index)
        if flow.is_still or state.n_particles == 0:
            return
        dt = self.scene.phases[index].dt
        velocity = _velocity(state.domain, flow, state.time + 0.5 * dt)
        spread = advective_spread(state, velocity, dt, self.scene.numerics.threshold)
        margin = self.scene.numerics.margin
        worst = int(np.argmax(spread))
        fraction = spread[worst] / margin
        if fraction > ADVECTION_LIMIT:
            self._report("advection", index, state, f"phases.{index}.dt", (
                f"phase {index} ({self.scene.phases[index].name!r}): in one step of dt = {dt:g} parts of particle "
                f"{worst} move {spread[worst]:.3g} lattice units relative to its mean motion, {fraction:.3g}× the "
                f"window margin numerics.margin = {margin:g}: the field leaves its window within a step; set "
                f"phases.{index}.dt ≤ {_round_down(dt * ADVECTION_LIMIT / fraction)} (or raise numerics.margin to "
                f"≥ {spread[worst] / ADVECTION_LIMIT:.3g})"))

    @staticmethod
    def _area_ratio(state: State, area: np.ndarray | None) -> np.ndarray:
        """a_i = ∫φ_i²/(πR_i²), from the frame's area column where it has one."""
        if area is None:
            return area_ratios(state)
        return np.asarray(area, dtype=float) / (np.pi * np.asarray(state.radii, dtype=float) ** 2)

    def _check_vanished(self, index: int, state: State, ratio: np.ndarray) -> None:
        if any(kind == "vanished" for kind, _ in self._warned) or not ratio.size:
            return
        gone = np.flatnonzero(ratio < self._vanishes_below)
        if not gone.size:
            return
        mu = self.scene.model.area_stiffness
        cause = ("without an area term (model.mu = 0) a particle shrinks by its interface's curvature until it "
                 "vanishes: set model.mu > 0 (the paper: 20) to hold particles at their area" if mu <= 0 else
                 f"the area term (model.mu = {mu:g}) did not hold it: raise model.mu or lower phases.{index}.dt")
        self._report("vanished", index, state, "model.mu", (
            f"phase {index} ({self.scene.phases[index].name!r}), t = {state.time:g}: particle {int(gone[0])} has "
            f"vanished, area ∫φ²/πR² = {ratio[gone[0]]:.3g} < {VANISHED_RATIO:g} ({gone.size} of {ratio.size} "
            f"particles); from here its x, y, elongation and orientation in particles.csv mean nothing (NaN once "
            f"its φ reaches 1/2 nowhere); {cause}"))

    def _check_areas(self, index: int, state: State, ratio: np.ndarray) -> None:
        if ("area", index) in self._warned or state.n_particles == 0:
            return
        low, high = int(np.argmin(ratio)), int(np.argmax(ratio))
        if ratio[low] >= AREA_RATIO_MIN and ratio[high] <= AREA_RATIO_MAX:
            return
        i = low if ratio[low] < AREA_RATIO_MIN else high
        what = (f"phase {index} ({self.scene.phases[index].name!r}), t = {state.time:g} ≥ {self.relax_from:.3g} "
                f"(after the relaxation): particle {i} has area ∫φ²/πR² = {ratio[i]:.3g}, outside the envelope "
                f"[{AREA_RATIO_MIN:g}, {AREA_RATIO_MAX:g}] (mean {np.mean(ratio):.3g}); ")
        key, fix = self._area_remedy(index, state, ratio[i])
        self._report("area", index, state, key, what + fix)

    def _area_remedy(self, index: int, state: State, ratio: float) -> tuple[str, str]:
        """The likely cause of an area outside the envelope: (scene key, advice)."""
        m = self.measures(index, state.radii)
        dt_key = f"phases.{index}.dt"
        if m.slowdown > SLOWDOWN_LIMIT:
            return dt_key, (f"the stabilised relaxation runs {m.slowdown:.3g}× slower than the clock: set {dt_key} ≤ "
                            f"{_round_down(m.accurate_dt)}")
        if ratio > AREA_RATIO_MAX:
            return dt_key, (f"areas above {AREA_RATIO_MAX:g} void the stabilisation's curvature bound: set {dt_key} ≤ "
                            f"{_round_down(min(m.dt, m.dt_star) * (3 * AREA_RATIO_MAX - 1) / (3 * ratio - 1))}")
        flow = self._flow(index)
        if not flow.is_still:
            rate = max_strain_rate(state.domain, _velocity(state.domain, flow, state.time))
            if rate > STRAIN_RATE_ENVELOPE:
                factor = STRAIN_RATE_ENVELOPE / rate
                spec = self.scene.phases[index].flow
                key = VELOCITY_KEYS.get(spec.get("type"))
                if spec.get("type") == "stokes":
                    key = next((k for k in STOKES_KEYS if k in spec), None)
                if key is not None and isinstance(spec.get(key), (int, float)):
                    target = f"phases.{index}.flow.{key} ≤ {_round_down(spec[key] * factor)}"
                else:
                    key, target = None, f"the flow's velocities × {factor:.3g}"
                return (f"phases.{index}.flow" + (f".{key}" if key else ""),
                        (f"the flow's largest velocity gradient {rate:.3g} exceeds the strongest measured one, "
                        f"{STRAIN_RATE_ENVELOPE:.3g} (γ̇ = 10 in the paper's channel): the flow deforms particles "
                        f"faster than the model restores them, at any dt (the step is within the saturation "
                        f"limit); use {target}"))
        mu = self.scene.model.area_stiffness
        return "model.mu", (f"the area constraint is too weak for this packing or flow: raise model.mu to ≥ "
                            f"{mu * (1 - ratio) / (1 - AREA_RATIO_MIN):.3g} (the area deficit scales as 1/μ)")

    def _report(self, kind: str, index: int, state: State, key: str, message: str) -> None:
        if (kind, index) in self._warned:
            return
        self._warned.add((kind, index))
        self.issues.append(Issue(kind, index, state.step, state.time, key, message))
        if self.strict:
            raise AccuracyError(state.step, state.time, message)
        warnings.warn(f"{message} [step {state.step}, t = {state.time:g}; numerics.strict = true makes this an "
                      f"error]", AccuracyWarning, stacklevel=3)


def _round_down(value: float) -> str:
    """``value`` rounded down to 2 significant digits, as text (a safe suggestion)."""
    if not np.isfinite(value) or value <= 0:
        return f"{value:.3g}"
    exponent = int(np.floor(np.log10(value))) - 1
    return f"{np.floor(value / 10.0**exponent) * 10.0**exponent:.3g}"
