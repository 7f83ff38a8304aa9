"""The paper's minimal one-variable model of the collective shape oscillations.

Hadjifrangiskou, Valani & Pinto reduce the dense sheared suspension to three functions of
time: the lattice angle φ(t) (fitted to the simulations), the orientation θ(t) of each
particle's elongation axis (driven by φ) and the elongation r = AR − 1 (AR the aspect ratio)::

    φ(t) = (π/12) cos²(ωt) + π/4,                       ω = k γ̇
    dθ/dt = −3 |dφ/dt| = −(πω/4) |sin 2ωt|,              θ(0) = π/2,  θ(τ_n⁺) = −π/4
    dr/dt = γ̇ (r + 1) sin 2θ + A (π/3 − φ)(r + 1) − ε r³ + K / r

The T1 neighbour exchanges happen where the lattice is square (φ = π/4), at the times
τ_n = (2n + 1) π / (2ω); there θ is reset to −π/4 (the supplement's "piecewise solution").

Conventions:

* time is in the solver's time units; angles are in radians;
* θ is the orientation of the elongation axis measured from the x axis (the flow direction),
  anticlockwise positive; it is nematic (θ + π ≡ θ) and reported in (−π/2, π/2];
* the solver (LSODA, each half period apart) integrates the paper's A, ε, K, k and r(0) at γ̇
  from 1e-5 to 1e4 and t_end up to 1.6e10; where the time scales lie further apart or r
  overflows, it stops with :class:`MinimalModelError` naming the interval and parameters;
* γ̇ ("rate") is the paper's shear-rate parameter. In femphase it is a velocity scale (the
  wall moves at γ̇ lattice units per time unit); the ODE only uses the number γ̇.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from femphase.errors import FemphaseError, SceneError

__all__ = ["K_PAPER", "DEFAULT_INITIAL_ELONGATION", "DEFAULT_PERIODS", "MAX_EVALUATIONS", "MAX_HALF_PERIODS",
           "RESET_ORIENTATION", "angular_frequency", "elongation_rate", "lattice_angle", "MinimalModelError",
           "MinimalModelParameters", "MinimalModelSolution", "orientation", "ParameterError", "period",
           "solve_minimal_model", "t1_times", "wrap_orientation", "write_solution"]

#: The most half periods π/(2ω) one solve integrates (each apart, about 10 ms): 10⁴, about
#: 2 minutes; t_end = 1e9 at γ̇ = 0.1 would have been 636 620, about 2 hours.
MAX_HALF_PERIODS = 10_000

#: A sample of the equally spaced grid closer than this fraction of a half period to a T1
#: time gives way to the T1 time (:func:`solve_minimal_model`): ode.csv writes times to 12
#: significant digits, which would print the two alike (a grid point 5e-13 from τ1 did at
#: γ̇ = 0.1487), and t_end ≤ :data:`MAX_HALF_PERIODS` half periods keeps 12 digits finer
#: than this.
T1_SAMPLE_GAP = 1e-4

#: The most right-hand-side evaluations one half period may take. The paper's parameters
#: take 600–1900 (γ̇ from 1e-5 to 1e4); where the model's time scales lie too far apart for
#: LSODA in double precision (γ̇ = 1e300, ε = 1e12, r(0) = 1e-300, t ~ 1e11) it would
#: otherwise stall for minutes to hours instead of failing. At this budget it stops in ~2 s.
MAX_EVALUATIONS = 100_000

#: Near-circular start, like the phase-field runs that start from discs; r = 0 itself is
#: excluded by the K/r term. The transient decays within a few time units (relaxation rate
#: 3εr² + K/r² ~ 1), far shorter than the period π/ω ~ 10³, so it does not shape the cycle.
DEFAULT_INITIAL_ELONGATION = 0.1

DEFAULT_PERIODS = 5

RESET_ORIENTATION = -np.pi / 4


#: The paper's ω = kγ̇: its fitted k.
K_PAPER = 0.01


@dataclass(frozen=True)
class MinimalModelParameters:
    """Constants of the elongation equation, with the paper's values as defaults.

    A        lattice drive: rate of elongation per radian of π/3 − φ (1 / time)
    epsilon  ε, free-energy cost of elongation, the −ε r³ term (1 / time)
    K        K/r keeps r away from 0; small enough not to affect the results (1 / time)
    k        ω = k γ̇ sets the T1 frequency (fitted, 0.01; with γ̇ a wall speed, 1 / length)
    """

    A: float = 2.0
    epsilon: float = 2.3
    K: float = 0.01
    k: float = K_PAPER

    def __post_init__(self) -> None:
        for name in ("A", "epsilon", "K"):
            value = getattr(self, name)
            _require(name, value, value >= 0, "must be a finite number ≥ 0")
        _require("k", self.k, self.k > 0, "must be a finite number > 0")


class MinimalModelError(FemphaseError, RuntimeError):
    """The minimal model could not be integrated at valid but extreme parameters (its time
    scales too far apart for the solver, or r overflowing): the message names the time
    interval, the parameters and what is known to work."""


class ParameterError(ValueError):
    """A parameter of the model or its solver out of range: ``name`` (the Python argument's
    name), ``value`` and what is ``valid``, so that a caller can name it in its own terms
    (``femphase ode`` names its option)."""

    def __init__(self, name: str, value: object, valid: str) -> None:
        self.name, self.value, self.valid = name, value, valid
        super().__init__(f"{name} = {value!r} is invalid: {valid}")

    def as_option(self) -> SceneError:
        """The same error for a command whose option ``--name`` (underscores as hyphens) is
        this parameter."""
        return SceneError(f"--{self.name.replace('_', '-')}", self.value, self.valid)


class _Stalled(Exception):
    """Raised from the right-hand side past :data:`MAX_EVALUATIONS` to stop the solver."""


def _require(name: str, value: float, condition: bool, valid: str) -> None:
    if not (np.isfinite(value) and condition):
        raise ParameterError(name, value, valid)


def angular_frequency(rate: float, k: float = K_PAPER) -> float:
    """ω = k γ̇ (radians per time unit)."""
    _require("rate", rate, rate > 0, "the shear rate γ̇ must be a finite number > 0")
    _require("k", k, k > 0, "must be a finite number > 0")
    return k * rate


def period(rate: float, k: float = K_PAPER) -> float:
    """π/ω, the period of φ, of sin 2θ and of the periodic r(t) (time units)."""
    return np.pi / angular_frequency(rate, k)


def lattice_angle(t: np.ndarray, rate: float, k: float = K_PAPER) -> np.ndarray:
    """φ(t) = (π/12) cos²(ωt) + π/4 (radians): π/3 (hexagonal) at t = 0, π/4 (square) at T1s."""
    omega = angular_frequency(rate, k)
    return np.pi / 12 * np.cos(omega * np.asarray(t, dtype=float)) ** 2 + np.pi / 4


def _half_period(rate: float, k: float) -> float:
    return np.pi / (2 * angular_frequency(rate, k))


def _half_periods_elapsed(t: np.ndarray, half_period: float) -> np.ndarray:
    """floor(t / half_period), exact at the marks half_period * j.

    The quotient alone rounds to j − 1 at some marks, which would put a T1 time on the wrong
    side of its own reset; the comparisons below use the same product as the marks.
    """
    j = np.floor(t / half_period)
    j += half_period * (j + 1) <= t
    j -= half_period * j > t
    return j


def _half_period_marks(rate: float, t_end: float, k: float) -> np.ndarray:
    """The times j π/(2ω) ≤ t_end, j = 0, 1, …: even j are the times φ = π/3, odd j the T1s.

    The solver, :func:`t1_times` and :func:`orientation` all use these products, so a T1
    time in the output grid is bit-for-bit the time at which θ is reset.
    """
    half_period = _half_period(rate, k)
    return half_period * np.arange(_half_periods_elapsed(t_end, half_period) + 1)


def t1_times(rate: float, t_end: float, k: float = K_PAPER) -> np.ndarray:
    """The T1 times τ_n = (2n + 1) π/(2ω) in [0, t_end], where φ = π/4 (time units)."""
    return _half_period_marks(rate, t_end, k)[1::2]


def wrap_orientation(theta: np.ndarray) -> np.ndarray:
    """The nematic angle θ mod π, in (−π/2, π/2]."""
    return np.pi / 2 - np.mod(np.pi / 2 - np.asarray(theta, dtype=float), np.pi)


def orientation(t: np.ndarray, rate: float, k: float = K_PAPER) -> np.ndarray:
    """θ(t) in closed form, wrapped to (−π/2, π/2] (radians, from the x axis).

    Between T1s θ = −π/4 − (πω/4) ``∫_{τ_n}^t |sin 2ωs| ds``, and the integral is analytic: each
    half period π/(2ω) turns θ by π/4, and the part s of a half period by (π/4) sin²(ωs).
    The first stretch [0, τ_0), which starts from θ(0) = π/2, is the second half of such a
    cycle (θ passes −π/2 ≡ π/2 halfway between T1s), so the formula holds for all t ≥ 0.
    At t = τ_n the value is the reset one, −π/4 (right-continuous).
    """
    omega = angular_frequency(rate, k)
    half_period = _half_period(rate, k)
    t = np.asarray(t, dtype=float)
    j = _half_periods_elapsed(t, half_period)
    # even j: the second half of a cycle, one half period after the last T1 already done
    half_periods_since_t1 = np.mod(j + 1, 2)
    into_half_period = np.sin(omega * (t - j * half_period)) ** 2
    return wrap_orientation(
        RESET_ORIENTATION - np.pi / 4 * (half_periods_since_t1 + into_half_period)
    )


def elongation_rate(
    elongation: np.ndarray,
    orientation: np.ndarray,
    lattice_angle: np.ndarray,
    rate: float,
    parameters: MinimalModelParameters,
) -> np.ndarray:
    """dr/dt = γ̇ (r + 1) sin 2θ + A (π/3 − φ)(r + 1) − ε r³ + K/r (1 / time)."""
    r = elongation
    drive = rate * np.sin(2 * orientation) + parameters.A * (np.pi / 3 - lattice_angle)
    return drive * (r + 1) - parameters.epsilon * r**3 + parameters.K / r


@dataclass
class MinimalModelSolution:
    """r, θ and φ sampled at `time` (time units; θ in (−π/2, π/2], φ in radians).

    The samples include every T1 time, where θ holds its reset value −π/4.
    """

    time: np.ndarray
    elongation: np.ndarray
    orientation: np.ndarray
    lattice_angle: np.ndarray
    rate: float
    parameters: MinimalModelParameters

    @property
    def period(self) -> float:
        """π/ω (time units)."""
        return period(self.rate, self.parameters.k)


def solve_minimal_model(
    rate: float,
    t_end: float,
    *,
    parameters: MinimalModelParameters = MinimalModelParameters(),
    initial_elongation: float = DEFAULT_INITIAL_ELONGATION,
    n_samples: int = 2001,
) -> MinimalModelSolution:
    """Integrate θ and r together from t = 0 to t_end (time units).

    r(0) = `initial_elongation` (must be > 0, see :data:`DEFAULT_INITIAL_ELONGATION`),
    θ(0) = π/2. The output holds `n_samples` equally spaced times plus the T1 times, less
    any equally spaced time within :data:`T1_SAMPLE_GAP` half periods of a T1 time; at a T1
    time the state is the one after θ's reset.

    The integration restarts at every multiple of π/(2ω): at the T1 times (odd multiples) to
    reset θ to −π/4, at the others because ``|sin 2ωt|`` has a kink there that would otherwise
    cost the step-size control accuracy.
    """
    # scipy.integrate loads here, not with the module: the command line reads this module's
    # defaults for `femphase ode --help` and every other command, and would pay ~0.4 s for it
    from scipy.integrate import solve_ivp

    omega = angular_frequency(rate, parameters.k)
    _require("t_end", t_end, t_end > 0, "must be a finite time > 0")
    _require(
        "initial_elongation", initial_elongation, initial_elongation > 0,
        "must be a finite elongation r = AR − 1 > 0",
    )
    if n_samples < 2:
        raise ValueError(f"n_samples = {n_samples!r} is invalid: must be an integer ≥ 2")
    half_period = _half_period(rate, parameters.k)
    # each half period is integrated apart (about 10 ms): beyond this, minutes to hours
    _require("t_end", t_end, t_end / half_period <= MAX_HALF_PERIODS,
             f"at most {MAX_HALF_PERIODS} half periods π/(2ω) = {half_period:.4g} (ω = kγ̇), i.e. t_end ≤ "
             f"{MAX_HALF_PERIODS * half_period:.4g}; this one spans {t_end / half_period:.0f} half periods")

    starts = _half_period_marks(rate, t_end, parameters.k)
    ends = np.append(starts[1:], t_end)
    grid, marks = np.linspace(0.0, t_end, n_samples), starts[1::2]
    if marks.size:
        nearest = np.clip(np.searchsorted(marks, grid), 1, marks.size) - 1
        gap = np.minimum(np.abs(grid - marks[nearest]), np.abs(grid - marks[np.minimum(nearest + 1, marks.size - 1)]))
        grid = grid[gap >= T1_SAMPLE_GAP * half_period]
    time = np.union1d(grid, marks)
    segment_of_sample = np.searchsorted(starts, time, side="right") - 1

    evaluations = 0

    def rhs(t: float, y: np.ndarray) -> list[float]:
        nonlocal evaluations
        evaluations += 1
        if evaluations > MAX_EVALUATIONS:
            raise _Stalled
        r, theta = y
        return [
            elongation_rate(r, theta, lattice_angle(t, rate, parameters.k), rate, parameters),
            -np.pi * omega / 4 * abs(np.sin(2 * omega * t)),
        ]

    def failed(start: float, end: float, reason: str) -> MinimalModelError:
        return MinimalModelError(
            f"the minimal model could not be integrated on t ∈ [{start:.6g}, {end:.6g}] at γ̇ = {rate:g}, "
            f"A = {parameters.A:g}, ε = {parameters.epsilon:g}, K = {parameters.K:g}, k = {parameters.k:g}, "
            f"r(0) = {initial_elongation:g}: {reason}. Its time scales (relaxation 1/(3εr² + K/r²), half period "
            f"π/(2ω) = {half_period:.4g}) lie too far apart here, or r overflows, for the solver in double "
            "precision; the paper's A, ε, K, k and r(0) integrate at γ̇ from 1e-5 to 1e4 and t_end up to 1.6e10"
        )

    state = np.array([initial_elongation, np.pi / 2])
    samples = np.empty((2, time.size))
    for j, (start, end) in enumerate(zip(starts, ends)):
        if j % 2 == 1:
            state[1] = RESET_ORIENTATION
        evaluations = 0
        # r relaxes on a time ~1 while the forcing varies on π/ω ~ 10³: the problem is stiff,
        # and LSODA switches to BDF where an explicit Runge–Kutta method would crawl.
        try:
            with np.errstate(over="ignore", invalid="ignore"):  # r overflowing is reported below
                segment = solve_ivp(
                    rhs, (start, end), state, method="LSODA", dense_output=True, rtol=1e-9, atol=1e-12
                )
        except _Stalled:
            raise failed(start, end, f"more than {MAX_EVALUATIONS} evaluations in one half period") from None
        except ValueError as exc:  # steps below the spacing of t's doubles: scipy's dense output refuses them
            raise failed(start, end, f"the solver's steps fell below the resolution of t ({exc})") from None
        if not segment.success:
            raise failed(start, end, f"LSODA: {segment.message.rstrip('.')}")
        in_segment = segment_of_sample == j
        if in_segment.any():  # a long run's segments outnumber its samples: most hold none
            samples[:, in_segment] = segment.sol(time[in_segment])
        state = segment.y[:, -1].copy()
        # each segment, the last included: a run within its first half period was never checked
        if not (np.isfinite(state).all() and np.isfinite(samples[:, in_segment]).all()):
            raise failed(start, end, f"r reached {state[0]:g}")

    return MinimalModelSolution(
        time=time,
        elongation=samples[0],
        orientation=wrap_orientation(samples[1]),
        lattice_angle=lattice_angle(time, rate, parameters.k),
        rate=rate,
        parameters=parameters,
    )


def write_solution(solution: MinimalModelSolution, directory: Path) -> None:
    """Write ode.csv (time, elongation, orientation, lattice_angle) and ode.json (the run)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    columns = ("time", "elongation", "orientation", "lattice_angle")
    np.savetxt(
        directory / "ode.csv",
        np.column_stack([getattr(solution, name) for name in columns]),
        delimiter=",",
        header=",".join(columns),
        comments="",
        fmt="%.12g",
    )
    metadata = {
        "rate": solution.rate,
        "parameters": asdict(solution.parameters),
        "period": solution.period,
        "t_end": float(solution.time[-1]),
        "initial_elongation": float(solution.elongation[0]),
    }
    (directory / "ode.json").write_text(json.dumps(metadata, indent=2) + "\n")
