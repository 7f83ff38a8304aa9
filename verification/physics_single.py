"""An isolated particle in shear elongates and settles without oscillating (the supplement).

    python -m verification.physics_single [--quick]

examples/single.toml: one particle (R = 8, from a disc of R/2) at the centre of the 70 × 240
channel, relaxed 300 time units, then sheared at γ̇ = 1 (u = γ̇ y/Ly) for SHEAR_DURATION
time units, on the grids h ∈ {2, 1, 0.5} with dt = 1, and on h = 1 with dt ∈ {0.5, 0.25}
(the steady elongation is the balance of advection and relaxation, so it carries the
splitting error of the time step).

Quantified on r(t) of the shear phase:

* the final elongation r and orientation θ;
* the settling time: when r last enters ±1 % of its final value;
* the relative change of r over the last half of the shear, (r_end − r_mid)/r_end;
* the late signal's peak-to-peak over its mean (last half): 0 for a settled particle;
* :func:`femphase.analysis.periods.oscillation_period` on the last half.  The late signal
  still wobbles periodically at a relative amplitude of 10⁻⁵–10⁻⁴ on h = 2 and 1 (the
  particle's centre crossing grid cells: u = 0.5 at mid-channel, one cell per 2h time units,
  aliased by the frame interval of 10); below its amplitude floor (10⁻³ of the signal) it
  reports no oscillation.  A particle counts as settled when the late peak-to-peak is below
  SETTLED_AMPLITUDE of the mean.

Results: ``verification/results/physics_single.json`` and ``physics_single.png``.
"""

from __future__ import annotations

import argparse

import numpy as np

from verification.physics_common import RESULTS, RUNS, cached, ensure_run, example_scene, wall_seconds

#: (h, dt) of the runs: the grids at dt = 1, then the time steps at h = 1
RUNS_PLAN = ((2.0, 1.0), (1.0, 1.0), (0.5, 1.0), (1.0, 0.5), (1.0, 0.25))
RATE = 1.0
SHEAR_DURATION = 6000.0
FRAME_INTERVAL = 10.0
QUICK = {"plan": ((1.0, 1.0),), "shear_duration": 1000.0}
#: the settling time is when r last enters ±SETTLED of its final value
SETTLED = 0.01
#: settled: peak-to-peak of r over the last half below this fraction of its mean
SETTLED_AMPLITUDE = 1e-3


def settling(time: np.ndarray, r: np.ndarray) -> dict:
    """Measures of a settled r(t) (time from shear onset); see the module docstring."""
    from femphase.analysis.periods import oscillation_period

    final = r[-1]
    outside = np.flatnonzero(np.abs(r - final) > SETTLED * abs(final))
    settle = time[outside[-1] + 1] - time[0] if outside.size and outside[-1] + 1 < len(time) else (
        0.0 if not outside.size else None)
    half = time >= time[0] + 0.5 * (time[-1] - time[0])
    late = r[half]
    try:
        estimate = oscillation_period(time[half], late, discard_fraction=0.0)
        oscillation = {"found": True, "period": estimate.period, "n_cycles": estimate.n_cycles}
    except ValueError as exc:
        oscillation = {"found": False, "reason": str(exc)}
    return {
        "final_r": float(final),
        "settling_time": None if settle is None else float(settle),
        "relative_change_last_half": float((late[-1] - late[0]) / late[-1]),
        "late_peak_to_peak_over_mean": float(np.ptp(late) / late.mean()),
        "max_r": float(r.max()),
        "oscillation": oscillation,
    }


def analyse(directory, h: float, dt: float) -> dict:
    from femphase.io.reader import open_run

    run = open_run(directory).complete()
    shear = run.time >= run.shear_start - 1e-9
    t, r, theta = run.time[shear], run.elongation[shear, 0], run.orientation[shear, 0]
    return {
        "h": h,
        "dt": dt,
        "rate": RATE,
        **settling(t, r),
        "final_theta": float(theta[-1]),
        "final_theta_degrees": float(np.degrees(theta[-1])),
        "late_theta_peak_to_peak": float(np.ptp(theta[t >= t[0] + 0.5 * (t[-1] - t[0])])),
        "wall_seconds": wall_seconds(directory),
    }


def figure(results: list[dict]) -> None:
    from femphase.plot.figures import pyplot
    from femphase.io.reader import open_run

    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    for result in results:
        run = open_run(result["directory"]).complete()
        label = f"h = {result['h']:g}, dt = {result['dt']:g}"
        axes[0].plot(run.time, run.elongation[:, 0], label=label)
        axes[1].plot(run.time, np.degrees(run.orientation[:, 0]), label=label)
    for ax in axes:
        ax.axvline(run.shear_start, color="k", ls=":", lw=0.8)
    axes[0].set_ylabel("elongation r")
    axes[1].set_ylabel("orientation θ (°)")
    axes[1].set_xlabel("time")
    axes[0].set_title(f"single particle, γ̇ = {RATE:g} (u = γ̇ y/Ly), shear from t = {run.shear_start:g}", fontsize=9)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    RESULTS.mkdir(parents=True, exist_ok=True)
    fig.savefig(RESULTS / "physics_single.png", dpi=130)
    plt.close(fig)


def table(results: list[dict]) -> str:
    lines = ["| h | dt | final r | max r | final θ (°) | settling time | rel. change, last half | peak-to-peak/mean, last half | periodic component (oscillation_period) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        settle = "—" if r["settling_time"] is None else f"{r['settling_time']:.0f}"
        osc = r["oscillation"]
        found = f"period {osc['period']:.3g} (noise, amplitude above)" if osc["found"] else "none"
        lines.append(f"| {r['h']:g} | {r['dt']:g} | {r['final_r']:.4f} | {r['max_r']:.3f} | {r['final_theta_degrees']:.2f} | {settle} | "
                     f"{r['relative_change_last_half']:.1e} | {r['late_peak_to_peak_over_mean']:.1e} | {found} |")
    return "\n".join(lines)


def run(quick: bool = False, write: bool | None = None) -> dict:
    """Run (resumably) and analyse the single-particle runs; write the results (default: not
    in quick)."""
    plan = QUICK["plan"] if quick else RUNS_PLAN
    duration = QUICK["shear_duration"] if quick else SHEAR_DURATION
    results = []
    for h, dt in plan:
        scene = example_scene("single", [
            f"domain.h={h}", "output.fields=false", f"phases.0.dt={dt}", f"phases.1.dt={dt}",
            f"phases.1.flow.rate={RATE}", f"phases.1.duration={duration}", f"phases.1.frame_interval={FRAME_INTERVAL}",
        ])
        directory = ensure_run(scene, RUNS / f"single_h{h:g}_dt{dt:g}_T{duration:g}")
        key = {"h": h, "dt": dt, "rate": RATE, "shear": duration, "version": 3}
        result = cached(directory / "result.json", lambda: analyse(directory, h, dt), key)
        results.append({**result, "directory": str(directory)})
    summary = {
        "runs": results,
        "all_settled": all(r["late_peak_to_peak_over_mean"] < SETTLED_AMPLITUDE for r in results),
        "settled_criterion": f"peak-to-peak of r over the last half < {SETTLED_AMPLITUDE:g} × its mean",
        "protocol": {"scene": "examples/single.toml", "rate": RATE, "shear_duration": duration,
                     "frame_interval": FRAME_INTERVAL, "runs_h_dt": [list(x) for x in plan]},
    }
    if (not quick) if write is None else write:
        from femphase.io.files import write_json

        write_json(RESULTS / "physics_single.json", {**summary, "runs": [
            {k: v for k, v in r.items() if k != "directory"} for r in results]})
        figure(results)
    print(table(results))
    return summary


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="h = 1, dt = 1 only, 1000 of shear")
    run(parser.parse_args().quick)
