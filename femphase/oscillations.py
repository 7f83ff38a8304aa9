"""The collective shape oscillations of a run, read back from its directory.

The paper's observables of a sheared suspension, computed from a :class:`~femphase.io.reader.RunData`
(the tables of ``femphase run``): the period of the bulk-mean elongation r̄(t)
(:func:`measured_period`), the order parameters per frame (:func:`order_series`), and the
minimal one-variable model aligned with the run by its first T1 event and compared with r̄(t)
(:func:`ode_solution`, :func:`ode_comparison`). Figures (:mod:`femphase.plot`) and sweep
summaries (:mod:`femphase.aggregate`) use them. Times in time units, γ̇ as in the scene's
flow (a velocity scale, docs/model.md).

Aligning the ODE with the simulation.  The ODE starts at t = 0 from the hexagonal lattice
(φ = π/3) and has its first T1 at τ0 = π/(2kγ̇).  The simulation's first T1 after shear
onset is found with :func:`femphase.analysis.lattice.t1_event_times` on the centroids of
particles.csv; the ODE is shifted so that its τ0 falls on it, but never starts before shear
onset: where the first T1 comes sooner after onset than τ0 (a random packing's first
rearrangements, long before a lattice's), the ODE starts at onset, and the comparison says
which alignment it used.  Without a T1 (no lattice, too short a run) the ODE starts at
shear onset, or at the first frame of a run without flow.
The alignment is exact at the first T1 only: when the ODE's period π/(kγ̇) differs from the
simulation's, the phases drift apart, which is why the comparison also offers k matched to
the measured period.
"""

from __future__ import annotations

import numpy as np

from femphase.analysis.lattice import frame_order
from femphase.analysis.periods import PeriodEstimate, oscillation_period
from femphase.io.reader import RunData
from femphase.model.minimal import K_PAPER, MAX_HALF_PERIODS, MinimalModelParameters, solve_minimal_model

__all__ = ["K_PAPER", "measured_period", "ode_alignment", "ode_comparison", "ode_fits", "ode_solution",
           "order_series", "period_estimate"]

def ode_solution(run: RunData, rate: float, k: float = K_PAPER):
    """The minimal model at `rate` with ω = kγ̇, and the simulation time of its t = 0.

    Returns ``(solution, offset)``: the ODE's sample at ODE time s is the simulation's time
    s + offset (see the module docstring for the alignment by the first T1; a run without
    flow starts the ODE at its first frame).  ``(None, offset)`` when the run ends before
    the ODE would start.
    """
    offset, t_end = _ode_span(run, rate, k)
    if t_end <= 0:
        return None, offset
    samples = max(2001, int(40 * t_end * k * rate / np.pi))  # ≥ 40 samples per period
    solution = solve_minimal_model(rate, t_end, parameters=MinimalModelParameters(k=k), n_samples=samples)
    return solution, offset


def _ode_span(run: RunData, rate: float, k: float) -> tuple[float, float]:
    """(the simulation time of the ODE's t = 0, the ODE time the run's frames reach)."""
    offset = ode_alignment(run, rate, k)[0]
    return offset, float(run.time[-1]) - offset


def ode_alignment(run: RunData, rate: float, k: float) -> tuple[float, str]:
    """(the simulation time of the ODE's t = 0, what it was aligned by: "first T1", "shear
    onset" or "first frame"), as the module docstring says."""
    onset = run.shear_start if run.flow_phase is not None else float(run.time[0])
    if run.t1_times.size:
        by_t1 = float(run.t1_times[0]) - np.pi / (2 * k * rate)
        if run.flow_phase is None or by_t1 >= onset:
            return by_t1, "first T1"
    return onset, "shear onset" if run.flow_phase is not None else "first frame"


def ode_fits(run: RunData, rate: float, k: float = K_PAPER) -> bool:
    """Whether one solve of the minimal model at ``rate`` spans the run: at most
    :data:`~femphase.model.minimal.MAX_HALF_PERIODS` half periods π/(2kγ̇)."""
    return _ode_span(run, rate, k)[1] * 2 * k * rate / np.pi <= MAX_HALF_PERIODS


def period_estimate(run: RunData, t_from: float | None = None) -> PeriodEstimate | None:
    """Period of the bulk-mean r(t) after `t_from` (default: shear onset + a quarter of the
    shear phase) with its uncertainty, None when no period can be measured."""
    start = run.shear_start if t_from is None else t_from
    frames = run.time >= start - 1e-9
    mean_r = run.bulk_elongation(frames)
    try:
        return oscillation_period(run.time[frames], mean_r, discard_fraction=0.25 if t_from is None else 0.0)
    except ValueError:
        return None


def measured_period(run: RunData, t_from: float | None = None) -> float | None:
    """The period of :func:`period_estimate` (time units), None when none can be measured."""
    estimate = period_estimate(run, t_from)
    return None if estimate is None else estimate.period


def ode_comparison(run: RunData, rate: float, t_from: float | None = None) -> dict:
    """Bulk-mean r(t) of the simulation against the minimal model, after `t_from`.

    Two ODEs: the paper's k = 0.01 and k matched to the measured period of r̄ (k = π/(Tγ̇)),
    each aligned by the first T1 where that does not start it before shear onset
    (``aligned_by`` says which: module docstring).  For each: the RMS difference and the
    Pearson correlation of r̄ and r_ODE on the simulation's frames, and the mean and range of
    both.
    """
    start = run.shear_start if t_from is None else t_from
    frames = run.time >= start - 1e-9
    t = run.time[frames]
    mean_r = run.bulk_elongation(frames)
    period = measured_period(run, t_from)
    ks = {"paper": K_PAPER}
    if period is not None:
        ks["matched"] = np.pi / (period * rate)
    out = {"simulation": {"mean": float(mean_r.mean()), "min": float(mean_r.min()), "max": float(mean_r.max())},
           "first_t1": float(run.t1_times[0]) if run.t1_times.size else None}
    for name, k in ks.items():
        solution, offset = ode_solution(run, rate, k)
        if solution is None:
            continue
        r_ode = np.interp(t - offset, solution.time, solution.elongation)
        out[name] = {
            "k": float(k), "offset": float(offset), "aligned_by": ode_alignment(run, rate, k)[1],
            "rms_difference": float(np.sqrt(np.mean((mean_r - r_ode) ** 2))),
            "correlation": float(np.corrcoef(mean_r, r_ode)[0, 1]) if np.std(r_ode) > 0 else None,
            "mean": float(r_ode.mean()), "min": float(r_ode.min()), "max": float(r_ode.max()),
        }
    return out


def order_series(run: RunData) -> dict[str, np.ndarray]:
    """Ψ6, Ψ2^L and the lattice angle per frame: global.csv's columns when the run wrote them
    (output.observables = ["order"]), else computed from particles.csv with the observable
    :class:`femphase.analysis.observables.Order`; NaN for fewer than 3 particles."""
    if "Psi6" in run.globals and len(run.globals["Psi6"]) == len(run.time):
        return {name: run.globals[name] for name in ("Psi6", "Psi2", "lattice_angle")}
    rows = []
    for k in range(len(run.time)):
        order = frame_order(np.stack([run.x[k], run.y[k]], axis=1), run.orientation[k], run.length)
        rows.append([order["Psi6"], order["Psi2"], order["lattice_angle"]])
    rows = np.asarray(rows, dtype=float).reshape(-1, 3)
    return {"Psi6": rows[:, 0], "Psi2": rows[:, 1], "lattice_angle": rows[:, 2]}
