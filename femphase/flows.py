"""Imposed velocity fields v(x, y, t) (lattice units per time unit), by name.

Conventions (see docs/model.md): γ̇ ("rate") is a velocity scale, not a rate in lattice
units. Linear shear is u = γ̇ y/Ly with the bottom wall at rest and the top wall moving at
γ̇; ``scale = "shear_rate"`` gives the plain u = γ̇ y (γ̇ is then ∂u/∂y). Poiseuille is
u = 4 γ̇ y (Ly − y)/Ly², so γ̇ is the centre-line velocity. y is measured from the lower
wall of the domain. A flow that changes in time sees the run's time t, from the start of
its first phase, not the time since its own phase began.

A flow whose velocity is (u(y, t), 0) is a *row flow*: on the structured channel its
advection is an exact shift of every row of nodes (:mod:`femphase.domains.grid.advection`). A scene
names a flow by ``type``; :data:`FLOWS` maps the name to a builder ``(spec, domain) → Flow``,
so a new flow is one registered function (``docs/architecture.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Protocol

import numpy as np

from femphase.errors import FlowError, SceneError
from femphase.registry import Registry, import_module

__all__ = ["FLOWS", "SHEAR_SCALES", "Flow", "FlowDomain", "check_keys", "flow_from_spec", "largest_speed",
           "linear_shear", "no_flow", "number", "poiseuille", "python_flow", "row_flow", "separable_row_flow",
           "time_mean", "velocity_at"]


SHEAR_SCALES = ("wall_velocity", "shear_rate")

Velocity = Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Flow:
    """A velocity field v(x, y, t) → (u, v).

    ============= =======================================================================================
    row_velocity  u(y, t) for flows (u(y, t), 0), else None
    steady        v does not depend on t (advection operators are then built once)
    stokes        the :class:`femphase.domains.mesh.stokes.StokesFlow` behind a ``stokes`` flow, whose P2
                  field the meshed domain's advection integrates exactly
    speed_bound   for a flow that changes in time, max|u| + max|v| over all times where the flow knows it
                  (lattice units per time unit), else None: an explicit scheme checks its step against it
                  before the run, not only at the step that would break it
    amplitude     for a flow v(x, y, t) = f(t) w(x, y) of fixed direction field (an oscillating shear): f,
                  dimensionless, else None
    profile       with ``amplitude``: the steady flow w. Operators linear in v are then w's, built once and
                  scaled by f's mean over each step (:func:`time_mean`), instead of built anew at every step
    ============= =======================================================================================
    """

    name: str
    velocity: Velocity | None
    row_velocity: Callable[[np.ndarray, float], np.ndarray] | None = None
    steady: bool = True
    stokes: object = None
    speed_bound: float | None = None
    amplitude: Callable[[float], float] | None = None
    profile: "Flow | None" = None

    def __post_init__(self) -> None:
        if (self.amplitude is None) != (self.profile is None) or (self.profile is not None and not self.profile.steady):
            raise ValueError("a flow of fixed direction field needs both its amplitude f(t) and its steady profile "
                             "w(x, y)")

    def mean_amplitude(self, time: float, span: float) -> float:
        """f's mean over [time, time + span] (:func:`time_mean`), for a flow with an
        ``amplitude``: the factor by which the step's mean velocity is the ``profile``."""
        if self.amplitude is None:
            raise ValueError(f"the flow {self.name!r} has no amplitude: its direction field changes in time")
        amplitude = self.amplitude
        return float(time_mean(lambda t: np.array([amplitude(t)], dtype=float), time, span)[0])

    @property
    def is_still(self) -> bool:
        return self.velocity is None


#: The three-point Gauss–Legendre rule on [0, 1] (nodes, weights): exact for polynomials of
#: degree ≤ 5 in t.
GAUSS_NODES = 0.5 + 0.5 * np.sqrt(0.6) * np.array([-1.0, 0.0, 1.0])
GAUSS_WEIGHTS = np.array([5.0, 8.0, 5.0]) / 18.0


#: Relative agreement of :func:`time_mean`'s rule on n and 2n pieces at which it stops, and
#: the most pieces it takes.
TIME_MEAN_TOLERANCE, TIME_MEAN_PIECES = 1e-6, 64


def _gauss_mean(velocity: Callable[[float], np.ndarray], time: float, span: float, pieces: int) -> np.ndarray:
    width = span / pieces
    return sum(weight / pieces * np.asarray(velocity(time + (k + node) * width), dtype=float)
               for k in range(pieces) for node, weight in zip(GAUSS_NODES, GAUSS_WEIGHTS))


def time_mean(velocity: Callable[[float], np.ndarray], time: float, span: float) -> np.ndarray:
    """(1/span) ∫ velocity(s) ds over [time, time + span]: what an advection step of ``span``
    in a flow that changes in time moves by. For a flow whose direction field is fixed,
    v(x, t) = f(t) w(x) (an oscillating shear), the advection over the step is then the
    mean velocity's to the rule's accuracy, where the velocity at the step's midpoint, also
    second order, errs by the factor sin(ωs/2)/(ωs/2) of a flow of frequency ω (−17 % at
    ω·span = 2.1, a substep of 3.33 in a flow of period 10). By :data:`GAUSS_WEIGHTS` on
    1, 2, 4 … pieces until two agree to :data:`TIME_MEAN_TOLERANCE` of the mean's largest
    value (at most :data:`TIME_MEAN_PIECES`): one piece errs by 4.9e-5 at ω·span = 2.1 but
    by 1.6 % of the amplitude over a whole period, and a substep may be a whole dt."""
    coarse = _gauss_mean(velocity, time, span, 1)
    pieces = 2
    while True:
        fine = _gauss_mean(velocity, time, span, pieces)
        scale = max(float(np.max(np.abs(fine), initial=0.0)), 1e-300)
        change = float(np.max(np.abs(fine - coarse), initial=0.0))
        if pieces >= TIME_MEAN_PIECES or change <= TIME_MEAN_TOLERANCE * scale:
            return fine
        coarse, pieces = fine, 2 * pieces


class FlowDomain(Protocol):
    """What a flow builder reads of the domain it is built for (lengths in lattice units):
    every :class:`femphase.domains.base.Domain` has it."""

    coordinates: np.ndarray   # (2, n_dofs): x and y of every dof
    n_dofs: int

    @property
    def y_range(self) -> tuple[float, float]:
        """Lowest and highest y of the domain (the walls' extremes)."""

    @property
    def period(self) -> float:
        """The period in x."""

    def wall_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """(points, unit normals), each (2, n), along the walls."""


FLOWS: Registry[Callable[[dict, FlowDomain], Flow]] = Registry("Flows", "flow.type")


def no_flow() -> Flow:
    return Flow("none", None)


def row_flow(name: str, u: Callable[[np.ndarray, float], np.ndarray], steady: bool = True,
             speed_bound: float | None = None) -> Flow:
    """The flow (u(y, t), 0); ``u`` may return a number for a uniform flow."""
    def row(y, t):
        y = np.asarray(y, dtype=float)
        return np.broadcast_to(np.asarray(u(y, t), dtype=float), y.shape).copy()

    def velocity(x, y, t):
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        return row(y, t), np.zeros_like(x)
    return Flow(name, velocity, row, steady, speed_bound=speed_bound)


def separable_row_flow(name: str, amplitude: Callable[[float], float], profile: Callable[[np.ndarray], np.ndarray],
                       speed_bound: float | None = None) -> Flow:
    """The row flow u(y, t) = amplitude(t) · profile(y), which changes in time along a fixed
    direction field (its operators scale with the amplitude, :attr:`Flow.profile`)."""
    flow = row_flow(name, lambda y, t: amplitude(t) * profile(y), steady=False, speed_bound=speed_bound)
    return replace(flow, amplitude=amplitude, profile=row_flow(f"{name} profile", lambda y, t: profile(y)))


def linear_shear(rate: float, width: float, scale: str = "wall_velocity", y0: float = 0.0) -> Flow:
    """u = γ̇ (y − y0)/Ly (scale="wall_velocity", default) or u = γ̇ (y − y0) (scale="shear_rate")."""
    if scale not in SHEAR_SCALES:
        raise SceneError("flow.scale", scale, f"one of {SHEAR_SCALES}")
    gradient = rate / width if scale == "wall_velocity" else rate
    return row_flow("shear", lambda y, t: gradient * (y - y0))


def poiseuille(rate: float, width: float, y0: float = 0.0) -> Flow:
    """u = 4 γ̇ (y − y0)(Ly − y + y0)/Ly²: γ̇ is the centre-line velocity; the walls are at rest."""
    return row_flow("poiseuille", lambda y, t: 4.0 * rate * (y - y0) * (width - y + y0) / width**2)


def python_flow(function: Callable, row: bool = False, steady: bool = True, name: str | None = None) -> Flow:
    """Any callable. With row=True, ``function(y)`` is u(y) (``function(y, t)`` when not
    steady) and v = 0; otherwise ``function(x, y)`` (or ``function(x, y, t)``) returns
    (u, v) for arrays x, y of the same shape. A call that raises or gives NaN or inf stops
    the run with a :class:`~femphase.errors.FlowError` naming ``name`` (default: the
    callable's qualified name) and the time."""
    name = name or getattr(function, "__qualname__", repr(function))
    checked = _checked(function if not steady else lambda *arguments: function(*arguments[:-1]), name, row)
    if row:
        return row_flow("python", checked, steady)
    return Flow("python", checked, steady=steady)


def _checked(function: Callable, name: str, row: bool) -> Callable:
    """``function`` (of the time t last), stopping the run with a FlowError naming ``name``
    and the time where it raises or gives NaN or inf: the user's code, whose faults are
    not femphase's. ``row``: it returns u alone, else (u, v)."""
    def checked(*arguments):
        time = arguments[-1]
        try:
            with np.errstate(all="ignore"):
                values = function(*arguments)
        except Exception as exc:  # the user's code may raise anything
            raise FlowError(name, time, f"it raised {type(exc).__name__}: {exc}") from exc
        try:
            finite = all(np.isfinite(np.asarray(w, dtype=float)).all() for w in ((values,) if row else values))
        except (TypeError, ValueError) as exc:
            raise FlowError(name, time, f"it returned {type(values).__name__}, not "
                            + ("u" if row else "(u, v)") + f" as arrays of numbers ({exc})") from exc
        if not finite:
            raise FlowError(name, time, "it returned NaN or inf")
        return values
    return checked


def check_keys(spec: dict, allowed: set[str]) -> None:
    """SceneError naming the first key of a flow table that its type does not take."""
    for key in spec:
        if key not in allowed:
            kind = spec.get("type", "none")
            untyped = "" if "type" in spec else f" (flow.type is not given, so there is no flow; types: {FLOWS.names()})"
            raise SceneError(f"flow.{key}", spec[key], f"a {kind} flow takes only {sorted(allowed)}{untyped}")


def number(spec: dict, key: str, meaning: str, default: float | None = None, positive: bool = False) -> float:
    """The finite number spec[key] (or ``default``); SceneError naming the key otherwise."""
    value = spec.get(key, default)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
    if not ok or (positive and value <= 0):
        raise SceneError(f"flow.{key}", value, f"a finite number{' > 0' if positive else ''} ({meaning})")
    return float(value)


def _walls(domain: FlowDomain) -> tuple[float, float]:
    low, high = domain.y_range
    return low, high - low


@FLOWS.register("none")
def _none(spec: dict, domain: FlowDomain) -> Flow:
    """No flow: relaxation only."""
    check_keys(spec, {"type"})
    return no_flow()


@FLOWS.register("shear")
def _shear(spec: dict, domain: FlowDomain) -> Flow:
    """Linear shear u = γ̇ y/Ly, bottom wall at rest (keys: `rate` = γ̇, a velocity; `scale` =
    "wall_velocity" (default) or "shear_rate" for the plain u = γ̇ y)."""
    check_keys(spec, {"type", "rate", "scale"})
    y0, width = _walls(domain)
    return linear_shear(number(spec, "rate", "the velocity scale γ̇"), width, spec.get("scale", "wall_velocity"), y0)


@FLOWS.register("poiseuille")
def _poiseuille(spec: dict, domain: FlowDomain) -> Flow:
    """Poiseuille flow u = 4γ̇ y(Ly − y)/Ly² (key: `rate` = γ̇, the centre-line velocity)."""
    check_keys(spec, {"type", "rate"})
    y0, width = _walls(domain)
    return poiseuille(number(spec, "rate", "the centre-line velocity γ̇"), width, y0)


@FLOWS.register("oscillating_shear")
def _oscillating_shear(spec: dict, domain: FlowDomain) -> Flow:
    """Oscillatory linear shear u = γ̇ sin(ωt + φ0) y/Ly, t the run's time, not the phase's
    (keys: `rate` = γ̇, `frequency` = ω in radians per time unit, `phase` = φ0 in radians,
    default 0; after phases of total duration T, φ0 = −ωT starts it from rest). On a mesh it
    costs what a steady shear does: its advection operators are built once and scaled by the
    oscillation's mean over each step."""
    check_keys(spec, {"type", "rate", "frequency", "phase"})
    y0, width = _walls(domain)
    rate = number(spec, "rate", "the velocity amplitude γ̇")
    omega = number(spec, "frequency", "ω, radians per time unit")
    phase = number(spec, "phase", "radians", default=0.0)
    return separable_row_flow("oscillating_shear", lambda t: np.sin(omega * t + phase),
                              lambda y: rate * (y - y0) / width, speed_bound=abs(rate))


@FLOWS.register("python")
def _python(spec: dict, domain: FlowDomain) -> Flow:
    """Any importable callable (keys: `function` = "module:name"; `row_flow` = true for u(y);
    `steady` = false to pass the time t, the run's, as the last argument)."""
    check_keys(spec, {"type", "function", "row_flow", "steady"})
    for key in ("row_flow", "steady"):
        if key in spec and not isinstance(spec[key], bool):
            raise SceneError(f"flow.{key}", spec[key], "true or false")
    target = spec.get("function")
    module, _, attribute = target.partition(":") if isinstance(target, str) else ("", "", "")
    if not module or not attribute:
        raise SceneError("flow.function", target, "a string 'module:function' naming an importable callable, "
                         "e.g. 'mypackage.flows:vortex'")
    try:
        function = getattr(import_module(module), attribute)
    except (Exception, SystemExit) as exc:  # importing runs the module: it may raise anything
        raise SceneError("flow.function", target, f"an importable 'module:function' ({type(exc).__name__}: "
                         f"{exc}; the module is looked up on PYTHONPATH, then in the working directory)") from None
    if not callable(function):
        raise SceneError("flow.function", target, f"a callable; {target} is a {type(function).__name__}")
    flow = python_flow(function, spec.get("row_flow", False), spec.get("steady", True), target)
    _try_flow(flow, spec, domain)
    return flow


def _try_flow(flow: Flow, spec: dict, domain: FlowDomain) -> None:
    """Evaluate a python flow at a few dofs at t = 0 (when the scene is checked, not at the
    first step): SceneError naming flow.function when it fails or returns no (u, v)."""
    row, steady = spec.get("row_flow", False), spec.get("steady", True)
    signature = ("u(y)" if steady else "u(y, t)") if row else ("(u, v)(x, y)" if steady else "(u, v)(x, y, t)")
    x, y = np.asarray(domain.coordinates)[:, :: max(1, domain.n_dofs // 7)][:, :8]
    try:
        with np.errstate(all="ignore"):
            u, v = flow.velocity(x, y, 0.0)
            u, v = (np.broadcast_to(np.asarray(w, dtype=float), x.shape) for w in (u, v))
    except FlowError as exc:  # it raised, or gave NaN or inf (python_flow's check)
        raise SceneError("flow.function", spec.get("function"), f"a callable computing a finite {signature} for "
                         f"arrays ({exc.reason})") from None
    except Exception as exc:  # no (u, v) of the points' shape
        raise SceneError("flow.function", spec.get("function"), f"a callable computing {signature} for arrays "
                         f"(calling it failed: {type(exc).__name__}: {exc})") from None


#: Normal velocity at the walls, or jump across the period, relative to the flow's largest
#: speed, below which a flow counts as tangential there, or periodic (rounding)
FLOW_DEFECT = 1e-6


def velocity_at(flow: Flow, x: np.ndarray, y: np.ndarray, t: float) -> np.ndarray:
    """Velocity of ``flow`` at the points (x, y) at time t, shape ``(2,) + x.shape`` (lattice units per
    time unit), u and v broadcast to the points' shape."""
    return np.stack([np.broadcast_to(np.asarray(w, dtype=float), x.shape) for w in flow.velocity(x, y, t)])


def _velocity(flow: Flow, x: np.ndarray, y: np.ndarray, t: float) -> np.ndarray:
    """:func:`velocity_at`, silent about the overflows a flow checked before a run may give."""
    with np.errstate(all="ignore"):
        return velocity_at(flow, x, y, t)


def flow_defects(flow: Flow, domain: FlowDomain) -> dict[str, tuple[float, float, np.ndarray]]:
    """What makes ``flow`` unfit for the domain, by more than :data:`FLOW_DEFECT` of its
    largest speed, at t = 0 (also t = 1 for a time-dependent flow, which may vanish at
    t = 0): "walls", the largest |v·n| on the walls, and "period", the largest |v(x + Lx, y)
    − v(x, y)| at the dofs; each as (that value, the largest speed, the point (x, y)).
    Empty for a flow tangential to the walls and periodic in x, or no flow."""
    if flow.is_still:
        return {}
    points, normals = domain.wall_normals()
    x, y = np.asarray(domain.coordinates)
    defects = {}
    for t in _sampled_times(flow):
        at_dofs = _velocity(flow, x, y, t)
        speed = float(np.max(np.hypot(*at_dofs)))
        found = {"walls": (np.abs(np.sum(_velocity(flow, *points, t) * normals, axis=0)), points),
                 "period": (np.max(np.abs(_velocity(flow, x + domain.period, y, t) - at_dofs), axis=0),
                            np.stack([x, y]))}
        for name, (excess, where) in found.items():
            k = int(np.argmax(excess))
            if excess[k] > FLOW_DEFECT * speed and (name not in defects or excess[k] > defects[name][0]):
                defects[name] = (float(excess[k]), speed, where[:, k])
    return defects


def largest_speed(flow: Flow, domain: FlowDomain) -> float:
    """The largest speed over the dofs at t = 0 (and t = 1 for a time-dependent flow),
    lattice units per time unit; 0 for no flow."""
    if flow.is_still:
        return 0.0
    x, y = np.asarray(domain.coordinates)
    return max(float(np.max(np.hypot(*_velocity(flow, x, y, t)))) for t in _sampled_times(flow))


def _sampled_times(flow: Flow) -> tuple[float, ...]:
    """Where a flow is sampled before a run: a time-dependent one may vanish at t = 0."""
    return (0.0, 1.0) if not flow.steady else (0.0,)


def flow_from_spec(spec: dict, domain: FlowDomain) -> Flow:
    """The flow a scene's ``flow`` table describes, e.g. {type = "shear", rate = 0.1487}."""
    if not isinstance(spec, dict):
        raise SceneError("flow", spec, 'a table such as {type = "shear", rate = 0.1}')
    name = spec.get("type", "none")
    builder, origin = FLOWS.get(name), FLOWS.origin(name) if name in FLOWS else None
    if origin is None:  # femphase's own: a fault is a bug
        return builder(spec, domain)
    try:
        flow = builder(spec, domain)
    except SceneError:
        raise
    except Exception as exc:  # the user's builder may raise anything
        raise SceneError("flow.type", name, f"a flow type whose builder builds its flow: {origin} raised "
                         f"{type(exc).__name__}: {exc}") from None
    if not isinstance(flow, Flow):
        raise SceneError("flow.type", name, f"a flow type whose builder returns a femphase.flows.Flow: {origin} "
                         f"returned {type(flow).__name__}")
    # its velocities are the user's code too: a NaN or a raise is named, not taken for a blow-up of φ
    def checked(flow: Flow) -> Flow:
        return replace(flow, velocity=None if flow.velocity is None else _checked(flow.velocity, origin, False),
                       row_velocity=None if flow.row_velocity is None else _checked(flow.row_velocity, origin, True))
    return replace(checked(flow), profile=None if flow.profile is None else checked(flow.profile))
