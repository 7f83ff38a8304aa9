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

import numpy as np

from verification.physics_common import (
    RESULTS, RUNS, cached, ensure_relaxation, ensure_run, example_scene, fmt, is_complete, wall_seconds,
)

#: The paper's three rates (Fig. 2b, 3) and three more spread over [0.05, 0.5].
RATES = (0.0778, 0.1083, 0.1487, 0.25, 0.3857, 0.5)
PAPER_RATES = (0.0778, 0.1487, 0.3857)
#: h = 0.5 costs ~5× h = 1 per step: only the fastest rates (shortest periods).
FINE_RATES = (0.25, 0.3857, 0.5)
TRANSIENT = 2.0  # geometric periods discarded
MEASURED = 4.5  # geometric periods measured after the transient
FRAMES_PER_PERIOD = 40
QUICK_RATES = (0.1487, 0.3857)
#: (h, rate, dt, method) runs that check the time step and the scheme: dt sets how far the
#: particles relax between T1s (the splitting and the stabilisation slow the relaxation at
#: dt = 1), so the shape of the cycle, not its kinematic period, may depend on it; "fd" runs
#: the shear phase with the paper's finite-difference scheme at its dt = 0.1 (from the same
#: FEM relaxation), to see whether the paper's discretisation moves the regimes; "fd-upwind1"
#: the same with first-order upwind advection (numerics.fd_advection)
SCHEME_CHECKS = ((1.0, 0.3857, 0.5, "fem"), (1.0, 0.3857, 0.1, "fem"), (1.0, 0.3857, 0.1, "fd"),
                 (1.0, 0.3857, 0.1, "fd-upwind1"))


def is_main(result: dict) -> bool:
    """A run of the main sweep (FEM, dt = 1), not one of the SCHEME_CHECKS."""
    return result["dt"] == 1.0 and result.get("method", "fem") == "fem"

LX, LY, PER_ROW, N = 70.0, 240.0, 5, 100
LANE_SPACING = LY / (N // PER_ROW)  # Δy = 12
IN_LANE_SPACING = LX / PER_ROW  # a = 14
K_PAPER = 0.01
K_GEOMETRIC = math.pi * LANE_SPACING / (IN_LANE_SPACING * LY)


def geometric_period(rate: float) -> float:
    """a Ly/(γ̇ Δy): adjacent lanes slide by one in-lane spacing a (time units)."""
    return IN_LANE_SPACING * LY / (rate * LANE_SPACING)


def _scene(h: float, rate: float | None, periods: float, dt: float = 1.0, method: str = "fem"):
    """The hexagonal example for one run; ``method`` "fd-upwind1" sets numerics.fd_advection."""
    assignments = [f"domain.h={h}", "output.fields=false"]
    advection = method.partition("-")[2]
    if advection:
        assignments.append(f'numerics.fd_advection="{advection}"')
    if rate is not None:
        period = geometric_period(rate)
        assignments += [
            f"phases.1.flow.rate={rate}", f"phases.1.dt={dt}",
            f"phases.1.duration={math.ceil(periods * period)}",
            f"phases.1.frame_interval={max(1, math.floor(period / FRAMES_PER_PERIOD))}",
        ]
    return example_scene("hexagonal", assignments)


def run_name(h: float, rate: float | None = None, dt: float = 1.0, method: str = "fem") -> str:
    name = f"periods_h{h:g}_" + ("relax" if rate is None else f"rate{rate:g}")
    name = name if dt == 1.0 else f"{name}_dt{dt:g}"
    return name if method == "fem" else f"{name}_{method}"


def plan(quick: bool, spacings: tuple[float, ...] | None) -> list[tuple[float, float, float, str]]:
    """The (h, rate, dt, method) runs: all rates on h = 2 and 1, the fastest ones on h = 0.5,
    all FEM with dt = 1; then the SCHEME_CHECKS."""
    if quick:
        return [(2.0, rate, 1.0, "fem") for rate in QUICK_RATES]
    runs = [(h, rate, 1.0, "fem") for h in (2.0, 1.0) for rate in RATES] + [(0.5, rate, 1.0, "fem") for rate in FINE_RATES]
    return [run for run in runs + list(SCHEME_CHECKS) if spacings is None or run[0] in spacings]


def simulate(h: float, rate: float, dt: float = 1.0, method: str = "fem") -> tuple:
    """Run (or reuse) one shear run (the FEM relaxation at dt = 1 is shared); returns
    (directory, scene)."""
    scene = _scene(h, rate, TRANSIENT + MEASURED, dt, method)
    relaxed = ensure_relaxation(scene, RUNS / run_name(h))
    directory = ensure_run(scene, RUNS / run_name(h, rate, dt, method), branch_from=relaxed,
                           method=method.partition("-")[0])
    return directory, scene


def _period(time, signal, discard: float) -> dict:
    """:func:`oscillation_period` as a dict; period None (and the reason) when none is found."""
    from femphase.analysis.periods import oscillation_period

    try:
        estimate = oscillation_period(time, signal, discard_fraction=discard)
    except ValueError as exc:
        return {"period": None, "uncertainty": None, "n_cycles": 0, "error": str(exc)}
    return {"period": estimate.period, "uncertainty": estimate.uncertainty, "n_cycles": estimate.n_cycles}


def lane_kinematics(run, rate: float, t_from: float) -> dict:
    """How fast the lanes actually slide past each other after `t_from`.

    Lanes are the rows of the initial lattice (particle j is in row j // PER_ROW).  Each
    particle's mean velocity along x is its unwrapped displacement over the window; per lane,
    the mean velocity and centroid height.  Over the interior lanes (the wall rows left out):
    the mean velocity difference Δv of adjacent lanes and their mean spacing, the kinematic
    period T_kin = a/Δv, and the lanes' velocities relative to the imposed flow at their height.
    """
    frames = run.time >= t_from - 1e-9
    t = run.time[frames]
    x = np.unwrap(run.x[frames] * 2 * np.pi / run.length, axis=0) * run.length / (2 * np.pi)
    velocity = (x[-1] - x[0]) / (t[-1] - t[0])
    lane = np.arange(run.n_particles) // PER_ROW
    rows = lane.max() + 1
    lane_v = np.array([velocity[lane == k].mean() for k in range(rows)])
    lane_y = np.array([run.y[frames][:, lane == k].mean() for k in range(rows)])
    interior = slice(1, rows - 1)
    dv = np.diff(lane_v)[1:-1]
    flow = rate * lane_y / run.width
    return {
        "lane_spacing": float(np.diff(lane_y)[1:-1].mean()),
        "velocity_difference": float(dv.mean()),
        "velocity_difference_spread": float(dv.std()),
        "kinematic_period": float(IN_LANE_SPACING / dv.mean()),
        "lane_velocity_over_flow_min": float((lane_v[interior] / flow[interior]).min()),
        "lane_velocity_over_flow_max": float((lane_v[interior] / flow[interior]).max()),
    }


def analyse(directory, h: float, rate: float, dt: float) -> dict:
    """Periods of r̄(t), of each particle's r(t) and of φ(t) of one run (see the module doc),
    the steady oscillation's range, and the comparison with the minimal model."""
    from femphase.io.reader import open_run
    from femphase.oscillations import ode_comparison

    run = open_run(directory).complete()
    shear = run.time >= run.shear_start - 1e-9
    t = run.time[shear]
    t_geo = geometric_period(rate)
    t_steady = t[0] + TRANSIENT * t_geo
    discard = TRANSIENT * t_geo / (t[-1] - t[0])
    r = run.elongation[shear][:, run.bulk_particles()]
    mean_r = r.mean(axis=1)
    per_particle = np.array([_period(t, r[:, j], discard)["period"] or np.nan for j in range(r.shape[1])])
    found = per_particle[np.isfinite(per_particle)]
    lattice = run.globals["lattice_angle"][shear]
    steady = t >= t_steady
    theta = run.orientation[shear][:, run.bulk_particles()][steady]
    return {
        "h": h,
        "rate": rate,
        "dt": dt,
        "geometric_period": t_geo,
        "shear_duration": float(t[-1] - t[0]),
        "frame_interval": float(np.median(np.diff(t))),
        "mean_elongation": _period(t, mean_r, discard),
        "per_particle": {
            "n_particles": int(r.shape[1]),
            "n_with_period": int(found.size),
            "median": float(np.median(found)) if found.size else None,
            "q16": float(np.quantile(found, 0.16)) if found.size else None,
            "q84": float(np.quantile(found, 0.84)) if found.size else None,
        },
        "lattice_angle": _period(t, lattice, discard),
        "t1_events": int(run.t1_times.size),
        "steady": {
            "mean_r": float(mean_r[steady].mean()),
            "mean_r_min": float(mean_r[steady].min()),
            "mean_r_max": float(mean_r[steady].max()),
            "particle_r_max": float(r[steady].max()),
            "lattice_angle_min": float(lattice[steady].min()),
            "lattice_angle_max": float(lattice[steady].max()),
            # share of bulk particle-frames with the elongation axis below the flow axis
            "fraction_theta_negative": float(np.mean(theta < 0)),
            # ... and with it closer to the y axis than to the flow (the ODE's |θ| > π/4 half)
            "fraction_theta_beyond_pi4": float(np.mean(np.abs(theta) > np.pi / 4)),
            "theta_min": float(theta.min()),
            "theta_max": float(theta.max()),
        },
        "lanes": lane_kinematics(run, rate, t_steady),
        "ode": ode_comparison(run, rate, t_from=t_steady),
        "wall_seconds": wall_seconds(directory),
        "steps": int(run.info.get("steps", 0)),
    }


def _best(per_h: dict) -> tuple[float | None, float | None, float | None]:
    """(period, uncertainty, finest h) of one rate: the finest grid's period, its uncertainty
    combined in quadrature with the change from the next coarser grid (the discretisation
    error is taken to be at most the last refinement's change)."""
    grids = sorted((h for h, e in per_h.items() if e["period"] is not None), reverse=True)
    if not grids:
        return None, None, None
    finest = per_h[grids[-1]]
    change = abs(finest["period"] - per_h[grids[-2]]["period"]) if len(grids) > 1 else 0.0
    return finest["period"], float(np.hypot(finest["uncertainty"], change)), grids[-1]


def _richardson(per_h: dict) -> dict | None:
    """Observed order and extrapolated period from the grids h, h/2, h/4 (None without three)."""
    grids = sorted((h for h, e in per_h.items() if e["period"] is not None), reverse=True)
    if len(grids) < 3:
        return None
    (h0, h1, h2) = grids[-3:]
    if not (h0 == 2 * h1 == 4 * h2):
        return None
    t0, t1, t2 = (per_h[h]["period"] for h in (h0, h1, h2))
    ratio = (t0 - t1) / (t1 - t2) if t1 != t2 else np.inf
    noise = np.hypot(per_h[h1]["uncertainty"], per_h[h2]["uncertainty"])
    if abs(t1 - t2) < noise:
        return {"order": None, "period": None, "note": "converged: the last change is within the uncertainties"}
    if ratio <= 1 or not np.isfinite(ratio):
        return {"order": None, "period": None, "note": "not monotone in h: no Richardson estimate"}
    order = float(np.log2(ratio))
    return {"order": order, "period": float(t2 + (t2 - t1) / (2**order - 1))}


def _fit_power_law(rates, periods, sigmas) -> dict:
    """Weighted least squares of log T = log C + s log γ̇; the slope's standard error from
    the scaled covariance (the residual scatter), and the unscaled one (the stated errors)."""
    x, y = np.log(rates), np.log(periods)
    w = 1.0 / (np.asarray(sigmas) / np.asarray(periods))
    if len(x) < 3:
        return {"slope": None, "n": len(x)}
    coef, cov = np.polyfit(x, y, 1, w=w, cov=True)
    _, cov_unscaled = np.polyfit(x, y, 1, w=w, cov="unscaled")
    return {"slope": float(coef[0]), "slope_se": float(np.sqrt(cov[0, 0])),
            "slope_se_unscaled": float(np.sqrt(cov_unscaled[0, 0])), "n": len(x)}


def _k_estimate(rates, periods, sigmas) -> dict:
    """k = π/(Tγ̇) per rate and their weighted mean (with its standard error)."""
    rates, periods, sigmas = map(np.asarray, (rates, periods, sigmas))
    k = np.pi / (periods * rates)
    sk = k * sigmas / periods
    w = 1 / sk**2
    mean = float(np.sum(w * k) / np.sum(w))
    # the larger of the propagated error and the scatter of the rates' k about the mean
    scatter = float(np.sqrt(np.sum(w * (k - mean) ** 2) / np.sum(w) / max(len(k) - 1, 1)))
    return {"k": mean, "k_se": max(float(np.sqrt(1 / np.sum(w))), scatter),
            "per_rate": [float(v) for v in k], "paper": K_PAPER, "geometric": K_GEOMETRIC}


def dt_checks(results: list[dict]) -> list[dict]:
    """Each SCHEME_CHECKS run beside the same (h, rate) of the main sweep: period and cycle
    shape."""
    rows = []
    for check in (r for r in results if not is_main(r)):
        for r in (r for r in results if is_main(r) and (r["h"], r["rate"]) == (check["h"], check["rate"])):
            rows.append({"h": check["h"], "rate": check["rate"], "runs": [
                {"dt": x["dt"], "method": x.get("method", "fem"), "period": x["mean_elongation"]["period"],
                 "uncertainty": x["mean_elongation"]["uncertainty"], **x["steady"]} for x in (r, check)]})
    return rows


def summarise(results: list[dict]) -> dict:
    """Per rate: the period on each grid, the best (finest) period, the h-trend and Richardson
    estimate; over the rates: slope of log T against log γ̇ and k, for r̄ and for φ (runs at
    dt = 1); the time-step checks beside."""
    checks = dt_checks(results)
    results = [r for r in results if is_main(r)]
    rates = sorted({r["rate"] for r in results})
    entries = []
    for rate in rates:
        runs = {r["h"]: r for r in results if r["rate"] == rate}
        entry = {"rate": rate, "geometric_period": geometric_period(rate), "by_h": {}}
        for signal in ("mean_elongation", "lattice_angle"):
            per_h = {h: runs[h][signal] for h in runs}
            period, sigma, finest = _best(per_h)
            entry[signal] = {"period": period, "uncertainty": sigma, "finest_h": finest,
                             "richardson": _richardson(per_h)}
        for h in sorted(runs, reverse=True):
            run_ = runs[h]
            entry["by_h"][f"{h:g}"] = {
                "period": run_["mean_elongation"]["period"],
                "uncertainty": run_["mean_elongation"]["uncertainty"],
                "n_cycles": run_["mean_elongation"]["n_cycles"],
                "lattice_period": run_["lattice_angle"]["period"],
                "lattice_uncertainty": run_["lattice_angle"]["uncertainty"],
                "per_particle_median": run_["per_particle"]["median"],
                "steady": run_["steady"],
                "kinematic_period": run_["lanes"]["kinematic_period"],
                "lane_spacing": run_["lanes"]["lane_spacing"],
                "ode_matched": {k: run_["ode"].get("matched", {}).get(k) for k in ("k", "correlation", "rms_difference", "min", "max")},
                "ode_paper": {k: run_["ode"]["paper"].get(k) for k in ("correlation", "rms_difference", "min", "max")},
                "t1_events": run_["t1_events"],
                "wall_seconds": run_["wall_seconds"],
            }
        by_h = entry["by_h"]
        entry["h_trend"] = {
            f"{a}->{b}": (by_h[b]["period"] - by_h[a]["period"]) / by_h[a]["period"]
            for a, b in (("2", "1"), ("1", "0.5"))
            if a in by_h and b in by_h and by_h[a]["period"] and by_h[b]["period"]
        }
        entry["period"] = entry["mean_elongation"]["period"]
        entry["uncertainty"] = entry["mean_elongation"]["uncertainty"]
        entries.append(entry)

    def fits(signal: str, h: str | None) -> dict:
        """Slope and k over the rates: best periods (h None) or those of grid h."""
        names = ("period", "uncertainty") if signal == "mean_elongation" else ("lattice_period", "lattice_uncertainty")
        chosen = []
        for e in entries:
            if h is None:
                period, sigma = e[signal]["period"], e[signal]["uncertainty"]
            elif h in e["by_h"]:
                period, sigma = (e["by_h"][h][name] for name in names)
            else:
                continue
            if period is not None:
                chosen.append((e["rate"], period, sigma))
        if len(chosen) < 2:
            return {"n": len(chosen)}
        r_, t_, s_ = zip(*chosen)
        return {**_fit_power_law(r_, t_, s_), **_k_estimate(r_, t_, s_), "rates": list(r_)}

    grids = sorted({f"{r['h']:g}" for r in results}, key=float, reverse=True)
    return {
        "periods": {
            "rates": entries,
            "slope": fits("mean_elongation", None),
            "lattice_slope": fits("lattice_angle", None),
            "by_h": {h: fits("mean_elongation", h) for h in grids},
            "lattice_by_h": {h: fits("lattice_angle", h) for h in grids},
            "dt_checks": checks,
            "k_paper": K_PAPER,
            "k_geometric": K_GEOMETRIC,
            "protocol": {
                "scene": "examples/hexagonal.toml (N = 100, 5 × 20 hexagonal, 70 × 240, relax 2000, dt = 1)",
                "shear": "u = γ̇ y/Ly",
                "duration_periods": TRANSIENT + MEASURED,
                "transient_periods": TRANSIENT,
                "frames_per_period": FRAMES_PER_PERIOD,
                "period_signal": "bulk-mean elongation (particles > 2R from the walls)",
            },
        },
    }
def figures(summary: dict, results: list[dict]) -> None:
    """physics_periods.png (T against γ̇), physics_periods_ode.png (r̄(t) against the ODE at
    the paper's rates, finest grid), physics_periods_cycles.png (limit cycles at 0.0778 and
    0.3857) and physics_periods_snapshot.png (γ̇ = 0.1487, h = 1, the end of the run)."""
    from femphase.plot.figures import pyplot
    from femphase.plot.run import draw_elongation, draw_limit_cycle, plot_snapshot
    from femphase.io.reader import open_run
    from femphase.io.rundir import CHECKPOINT

    plt = pyplot()
    periods = summary["periods"]
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    dense = np.geomspace(0.04, 0.6, 50)
    for k, h in enumerate(sorted({r["h"] for r in results}, reverse=True)):
        chosen = [r for r in results if r["h"] == h and r["mean_elongation"]["period"]]
        ax.errorbar([r["rate"] * (1 + 0.02 * (k - 1)) for r in chosen], [r["mean_elongation"]["period"] for r in chosen],
                    [r["mean_elongation"]["uncertainty"] for r in chosen], fmt="o", ms=4, label=f"r̄(t), h = {h:g}")
        chosen = [r for r in results if r["h"] == h and r["lattice_angle"]["period"]]
        ax.plot([r["rate"] * (1 + 0.02 * (k - 1)) for r in chosen], [r["lattice_angle"]["period"] for r in chosen],
                "x", ms=5, color=f"C{k}", label=f"φ(t), h = {h:g}")
    ax.plot(dense, np.pi / (K_PAPER * dense), "k--", lw=0.8, label="π/(0.01 γ̇) (paper)")
    ax.plot(dense, np.pi / (K_GEOMETRIC * dense), "k:", lw=0.8, label=f"a Ly/(Δy γ̇) (k = {K_GEOMETRIC:.4f})")
    fit = periods["slope"]
    if fit.get("slope") is not None:
        ax.set_title(f"slope {fit['slope']:.3f} ± {fit['slope_se']:.3f}, k = {fit['k']:.5f} ± {fit['k_se']:.1g}",
                     fontsize=9)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ticks = [0.05, 0.1, 0.2, 0.5]
    ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
    ax.set_xticks([], minor=True)
    ax.set_xlabel("shear rate γ̇ (wall velocity)")
    ax.set_ylabel("period T")
    ax.legend(fontsize=7)
    _save_result(fig, "physics_periods.png")

    finest = {}
    for r in results:
        if r["rate"] in PAPER_RATES and r["h"] <= finest.get(r["rate"], (np.inf,))[0]:
            finest[r["rate"]] = (r["h"], r)
    shown = [finest[rate] for rate in PAPER_RATES if rate in finest]
    if shown:
        fig, axes = plt.subplots(len(shown), 1, figsize=(9, 2.8 * len(shown)), squeeze=False)
        for ax, (h, r) in zip(axes[:, 0], shown):
            run = open_run(RUNS / run_name(h, r["rate"])).complete()
            t_from = run.time[-1] - 3 * r["geometric_period"]
            matched = r["ode"].get("matched", {}).get("k")
            draw_elongation(ax, run, r["rate"], matched or K_PAPER, t_from=t_from)
            ax.set_title(f"γ̇ = {r['rate']:g}, h = {h:g}: ODE with k matched to the measured period", fontsize=9)
        _save_result(fig, "physics_periods_ode.png")

    cycles = [finest[rate] for rate in (0.0778, 0.3857) if rate in finest]
    if cycles:
        fig, axes = plt.subplots(1, len(cycles), figsize=(4.6 * len(cycles), 4.6), squeeze=False)
        for ax, (h, r) in zip(axes[0], cycles):
            run = open_run(RUNS / run_name(h, r["rate"])).complete()
            matched = r["ode"].get("matched", {}).get("k")
            late = 2 * r["geometric_period"] / (run.time[-1] - run.time[0])
            draw_limit_cycle(ax, run, r["rate"], matched or K_PAPER, late_fraction=late)
            ax.set_title(f"γ̇ = {r['rate']:g}, h = {h:g}, last 2 periods", fontsize=9)
        _save_result(fig, "physics_periods_cycles.png")

    snapshot = RUNS / run_name(1.0, 0.1487)
    if (snapshot / CHECKPOINT).exists():
        plot_snapshot(open_run(snapshot).complete(), RESULTS / "physics_periods_snapshot.png")


def _save_result(fig, name: str) -> None:
    import matplotlib.pyplot as plt

    RESULTS.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(RESULTS / name, dpi=130)
    plt.close(fig)


def table(summary: dict) -> str:
    """Markdown table of the periods per rate and grid, then the fits."""
    periods = summary["periods"]
    grids = sorted({h for e in periods["rates"] for h in e["by_h"]}, key=float, reverse=True)
    lines = ["| γ̇ | T_geo | " + " | ".join(f"T(r̄), h={h}" for h in grids) + " | T(φ), finest h | T_kin, finest h | h-trend | Richardson | k = π/(Tγ̇) |",
             "|" + "---|" * (len(grids) + 7)]
    for e in periods["rates"]:
        cells = [fmt(e["by_h"][h]["period"], e["by_h"][h]["uncertainty"], 4) if h in e["by_h"] else "—" for h in grids]
        trend = ", ".join(f"{k}: {100 * v:+.1f}%" for k, v in e["h_trend"].items()) or "—"
        rich = e["mean_elongation"]["richardson"]
        rich_text = "—" if rich is None else (rich["note"].split(":")[0] if rich["period"] is None else
                                             f"{rich['period']:.4g} (p = {rich['order']:.2g})")
        k = np.pi / (e["period"] * e["rate"]) if e["period"] else None
        lines.append(f"| {e['rate']:g} | {e['geometric_period']:.0f} | " + " | ".join(cells)
                     + f" | {fmt(e['lattice_angle']['period'], e['lattice_angle']['uncertainty'], 4)} | "
                     + f"{fmt(e['by_h'][min(e['by_h'], key=float)]['kinematic_period'], None, 4)} | {trend} | "
                     + f"{rich_text} | {fmt(k, None, 4)} |")
    lines.append("")
    for name, fit in [("best periods, r̄", periods["slope"]), ("best periods, φ", periods["lattice_slope"])] + [
            (f"h = {h}, r̄", f) for h, f in periods["by_h"].items()]:
        if fit.get("slope") is not None:
            lines.append(f"- {name}: slope {fit['slope']:.4f} ± {fit['slope_se']:.4f} "
                         f"(unscaled ± {fit['slope_se_unscaled']:.4f}), k = {fit['k']:.5f} ± {fit['k_se']:.5f} "
                         f"over {fit['n']} rates")
    lines.append(f"- paper k = {K_PAPER}, geometric k = π Δy/(a Ly) = {K_GEOMETRIC:.5f}")
    for check in periods["dt_checks"]:
        for x in check["runs"]:
            lines.append(f"- scheme check, h = {check['h']:g}, γ̇ = {check['rate']:g}, {x['method'].upper()} "
                         f"dt = {x['dt']:g}: "
                         f"T = {fmt(x['period'], x['uncertainty'], 4)}, r̄ {x['mean_r_min']:.3f}–{x['mean_r_max']:.3f}, "
                         f"θ {np.degrees(x['theta_min']):.0f}°…{np.degrees(x['theta_max']):.0f}°, "
                         f"θ < 0 {100 * x['fraction_theta_negative']:.0f} % of the time")
    return "\n".join(lines)


def run(quick: bool = False, spacings: tuple[float, ...] | None = None, simulate_only: bool = False,
        analyse_only: bool = False, write: bool | None = None) -> dict:
    """Run every planned shear run (resumably), analyse them, write the results (default: not
    in quick).

    `simulate_only` skips the analysis; `analyse_only` runs nothing and analyses the runs that
    are complete (e.g. while others are still under way in another process)."""
    done = []
    for h, rate, dt, method in plan(quick, spacings):
        label = f"h = {h:g}, γ̇ = {rate:g}, dt = {dt:g}, {method}"
        if analyse_only:
            scene = _scene(h, rate, TRANSIENT + MEASURED, dt, method)
            directory = RUNS / run_name(h, rate, dt, method)
            if is_complete(directory, scene):
                done.append((h, rate, dt, method, directory, scene))
            else:
                print(f"{label}: not complete, left out", flush=True)
            continue
        print(f"{label}: geometric period {geometric_period(rate):.0f}", flush=True)
        done.append((h, rate, dt, method, *simulate(h, rate, dt, method)))
    if simulate_only:
        return {}
    results = []
    for h, rate, dt, method, directory, scene in done:
        key = {"h": h, "rate": rate, "dt": dt, "steps": sum(p.n_steps for p in scene.phases), "version": 4}
        if method != "fem":
            key["method"] = method
        results.append(cached(directory / "result.json",
                              lambda: {**analyse(directory, h, rate, dt), "method": method}, key))
    summary = summarise(results)
    if (not quick) if write is None else write:
        from femphase.io.files import write_json

        write_json(RESULTS / "periods.json", summary["periods"])
        write_json(RESULTS / "physics_periods.json", {**summary, "runs": results})
        figures(summary, [r for r in results if is_main(r)])
    print(table(summary))
    return summary


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="h = 2, two rates only (minutes)")
    parser.add_argument("--h", type=float, nargs="+", default=None, help="run only these grid spacings")
    parser.add_argument("--simulate-only", action="store_true", help="run the simulations, skip the analysis")
    parser.add_argument("--analyse-only", action="store_true", help="run nothing; analyse the complete runs")
    args = parser.parse_args()
    run(args.quick, tuple(args.h) if args.h else None, args.simulate_only, args.analyse_only)
