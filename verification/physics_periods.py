"""Period of the collective shape oscillations against the shear rate (the paper's Fig. 2b, 3).

    python -m verification.physics_periods [--quick] [--h 2 1 0.5]

The paper's Fig. 2 scene (examples/hexagonal.toml: N = 100 on a 5 × 20 hexagonal lattice in
the 70 × 240 channel, relaxed 2000 time units without flow) is sheared at six rates γ̇ in
[0.05, 0.5], among them the paper's 0.0778, 0.1487 and 0.3857, on the grids h = 2 and 1
(all rates) and h = 0.5 (the three fastest rates: the cost per period is ∝ 1/(γ̇ h³)).

Each shear run lasts ``TRANSIENT + MEASURED`` geometric periods T_geo = a Ly/(γ̇ Δy) (the
time for adjacent lanes, Δy = Ly/20 apart, to slide past each other by one in-lane
spacing a = Lx/5), sampled with ≥ 40 frames per period.  The first TRANSIENT periods are
discarded; the period is measured on the rest by
:func:`femphase.analysis.periods.oscillation_period`:

* of r̄(t), the elongation averaged over the bulk particles (the two wall rows, whose
  particles are stretched across the wall layer, are left out): the primary estimate;
* per bulk particle (median and spread of the particles' periods): a check that the mean
  does not hide particles oscillating at another period;
* of the lattice angle φ(t) (global.csv).

Then, over the rates: the slope of log T against log γ̇ (weighted least squares, with its
standard error) and k = π/(T γ̇) (the paper: T = π/(kγ̇), k = 0.01), compared with the
geometric k_geo = π Δy/(a Ly).  Over the grids: the h-trend of each period and, where three
grids exist, a Richardson extrapolation.  Results: ``verification/results/periods.json``
and ``physics_periods.json``, figures ``physics_periods*.png``.
"""

from __future__ import annotations

import argparse
import math
import time as wallclock

import numpy as np

from verification.physics_common import (
    RESULTS, RUNS, cached, ensure_relaxation, ensure_run, example_scene, fmt, particle_series, wall_seconds,
)

#: The paper's three rates (Fig. 2b, 3) and three more spread over [0.05, 0.5].
RATES = (0.0778, 0.1083, 0.1487, 0.25, 0.3857, 0.5)
PAPER_RATES = (0.0778, 0.1487, 0.3857)
SPACINGS = (2.0, 1.0, 0.5)
#: h = 0.5 costs ~5× h = 1 per step: only the fastest rates (shortest periods).
FINE_RATES = (0.25, 0.3857, 0.5)
TRANSIENT = 2.0  # geometric periods discarded
MEASURED = 4.5  # geometric periods measured after the transient
FRAMES_PER_PERIOD = 40
QUICK_RATES = (0.1487, 0.3857)

LX, LY, PER_ROW, N = 70.0, 240.0, 5, 100
LANE_SPACING = LY / (N // PER_ROW)  # Δy = 12
IN_LANE_SPACING = LX / PER_ROW  # a = 14
K_PAPER = 0.01
K_GEOMETRIC = math.pi * LANE_SPACING / (IN_LANE_SPACING * LY)


def geometric_period(rate: float) -> float:
    """a Ly/(γ̇ Δy): adjacent lanes slide by one in-lane spacing a (time units)."""
    return IN_LANE_SPACING * LY / (rate * LANE_SPACING)


def _scene(h: float, rate: float | None, periods: float):
    assignments = [f"domain.h={h}", "output.fields=false"]
    if rate is not None:
        period = geometric_period(rate)
        assignments += [
            f"phases.1.flow.rate={rate}",
            f"phases.1.duration={math.ceil(periods * period)}",
            f"phases.1.frame_interval={max(1, math.floor(period / FRAMES_PER_PERIOD))}",
        ]
    return example_scene("hexagonal", assignments)


def run_name(h: float, rate: float | None = None) -> str:
    return f"periods_h{h:g}_" + ("relax" if rate is None else f"rate{rate:g}")


def plan(quick: bool, spacings: tuple[float, ...] | None) -> list[tuple[float, float]]:
    """The (h, rate) runs: all rates on h = 2 and 1, the fastest ones on h = 0.5."""
    if quick:
        return [(2.0, rate) for rate in QUICK_RATES]
    runs = [(h, rate) for h in (2.0, 1.0) for rate in RATES] + [(0.5, rate) for rate in FINE_RATES]
    return [(h, rate) for h, rate in runs if spacings is None or h in spacings]


def simulate(h: float, rate: float, quick: bool = False) -> tuple:
    """Run (or reuse) one shear run; returns (directory, scene)."""
    periods = TRANSIENT + MEASURED
    scene = _scene(h, rate, periods)
    relaxed = ensure_relaxation(scene, RUNS / run_name(h))
    started = wallclock.perf_counter()
    directory = ensure_run(scene, RUNS / run_name(h, rate), branch_from=relaxed)
    _log_session(directory, wallclock.perf_counter() - started)
    return directory, scene


def _log_session(directory, seconds: float) -> None:
    """Accumulate the wall time spent on a run over sessions (run.json keeps the last only)."""
    import json

    path = directory / "sessions.json"
    sessions = json.loads(path.read_text()) if path.exists() else []
    if seconds > 1.0:
        sessions.append({"wall_s": seconds, "run_json_wall_s": wall_seconds(directory)})
        path.write_text(json.dumps(sessions, indent=1))


def analyse(directory, h: float, rate: float) -> dict:
    """Periods of r̄(t), of each particle's r(t) and of φ(t) of one run (see the module doc)."""
    from femphase.analysis.periods import oscillation_period
    from femphase.io import read_csv
    from femphase.plot import load_run, ode_comparison, t1_times

    run = load_run(directory)
    series = particle_series(directory)
    shear = series.time >= run.shear_start - 1e-9
    t = series.time[shear]
    t_geo = geometric_period(rate)
    discard = TRANSIENT * t_geo / (t[-1] - t[0])
    bulk = run.bulk_particles()
    r = series.elongation[shear][:, bulk]
    mean_r = r.mean(axis=1)

    def period_of(signal) -> dict:
        try:
            estimate = oscillation_period(t, signal, discard_fraction=discard)
        except ValueError as exc:
            return {"period": None, "uncertainty": None, "n_cycles": 0, "error": str(exc)}
        return {"period": estimate.period, "uncertainty": estimate.uncertainty, "n_cycles": estimate.n_cycles}

    per_particle = [period_of(r[:, j])["period"] for j in range(r.shape[1])]
    found = np.array([p for p in per_particle if p is not None])
    glob = read_csv(directory / "global.csv")
    in_shear = glob["time"] >= run.shear_start - 1e-9
    steady = t >= t[0] + TRANSIENT * t_geo
    lattice = period_of_series(glob["time"][in_shear], glob["lattice_angle"][in_shear], discard)
    result = {
        "h": h,
        "rate": rate,
        "geometric_period": t_geo,
        "shear_duration": float(t[-1] - t[0]),
        "frame_interval": float(np.median(np.diff(t))),
        "mean_elongation": period_of(mean_r),
        "per_particle": {
            "n_particles": int(r.shape[1]),
            "n_with_period": int(found.size),
            "median": float(np.median(found)) if found.size else None,
            "q16": float(np.quantile(found, 0.16)) if found.size else None,
            "q84": float(np.quantile(found, 0.84)) if found.size else None,
        },
        "lattice_angle": lattice,
        "t1_events": int(len(t1_times(run))),
        "steady_elongation": {
            "mean": float(mean_r[steady].mean()),
            "min": float(mean_r[steady].min()),
            "max": float(mean_r[steady].max()),
            "particle_max": float(r[steady].max()),
        },
        "steady_lattice_angle": {
            "min": float(np.min(glob["lattice_angle"][in_shear][-steady.sum():])),
            "max": float(np.max(glob["lattice_angle"][in_shear][-steady.sum():])),
        },
        "ode": ode_comparison(run, rate, t_from=t[0] + TRANSIENT * t_geo),
        "wall_seconds": _wall_total(directory),
        "steps": int(run.info.get("steps", 0)),
    }
    return result


def period_of_series(time, signal, discard: float) -> dict:
    from femphase.analysis.periods import oscillation_period

    try:
        estimate = oscillation_period(time, signal, discard_fraction=discard)
    except ValueError as exc:
        return {"period": None, "uncertainty": None, "n_cycles": 0, "error": str(exc)}
    return {"period": estimate.period, "uncertainty": estimate.uncertainty, "n_cycles": estimate.n_cycles}


def _wall_total(directory) -> float:
    import json

    path = directory / "sessions.json"
    return float(sum(s["wall_s"] for s in json.loads(path.read_text()))) if path.exists() else float("nan")


def run(quick: bool = False, spacings: tuple[float, ...] | None = None, simulate_only: bool = False) -> dict:
    """Run every planned shear run (resumably), analyse them, write the results."""
    done = []
    for h, rate in plan(quick, spacings):
        print(f"h = {h:g}, γ̇ = {rate:g}: geometric period {geometric_period(rate):.0f}", flush=True)
        done.append((h, rate, *simulate(h, rate, quick)))
    if simulate_only:
        return {}
    results = []
    for h, rate, directory, scene in done:
        key = {"h": h, "rate": rate, "steps": sum(p.n_steps for p in scene.phases), "version": 1}
        results.append(cached(directory / "result.json", lambda: analyse(directory, h, rate), key))
    summary = summarise(results)
    if not quick:
        from femphase.io import write_json

        write_json(RESULTS / "periods.json", summary["periods"])
        write_json(RESULTS / "physics_periods.json", summary)
        figures(summary, results)
    print(table(summary))
    return summary


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="h = 2, two rates only (minutes)")
    parser.add_argument("--h", type=float, nargs="+", default=None, help="run only these grid spacings")
    parser.add_argument("--simulate-only", action="store_true", help="run the simulations, skip the analysis")
    args = parser.parse_args()
    run(args.quick, tuple(args.h) if args.h else None, args.simulate_only)
