"""Bond and nematic order against the shear rate from random initial conditions (Fig. 1a).

    python -m verification.physics_order [--quick] [--seeds 1 2]

The paper: N = 100 discs of radius R/2 at random centroids in the 70 × 240 channel, relaxed
2000 time units, sheared for 10^5 time units with 250 frames; Ψ6 and Ψ2^L averaged over the
last 50 frames and over 10 samples, against γ̇ (Fig. 1a: non-monotonic, a first peak near
the onset of T1s around γ̇ ~ 10⁻³, a dip where lanes with out-of-phase oscillations form
around 0.1, a renewed rise of Ψ2^L at γ̇ ~ 1).

Protocol (the paper's 10⁵ time units cost ~12–20 min per run here at h = 1, dt = 1): the
rates of the supplementary videos S1–S5, γ̇ ∈ {10⁻⁴, 0.0017, 0.0161, 0.1083, 1}, three
samples each (seeds 1, 2, 3; the relaxation is shared by the rates of one seed), with 250
frames per run. SHEAR_DURATIONS: the paper's 10⁵ time units at 0.0017 and 0.0161, where
the packing is still evolving after 2·10⁴ and the paper's low-rate peak sits; 2·10⁴ at 10⁻⁴
(the packing barely moves either way: a wall displacement of 2 or 10), 0.1083 and 1
(hundreds to thousands of T1s, steady averages). The last 50 frames are the last fifth of
each run.  examples/random.toml otherwise (h = 1, dt = 1).

Per run: the mean and standard deviation over the last 50 frames of Ψ6 and Ψ2^L as the
run wrote them (all particles), and recomputed over the bulk particles only (centroid
farther than 2R from the walls, :func:`femphase.analysis.lattice.global_order` with
``where``), plus the T1 rate, the mean elongation and the wall-to-wall strain reached.
Per rate: mean and standard deviation over the samples.  Results:
``verification/results/physics_order.json``, figures ``physics_order.png`` (order
parameters against γ̇) and ``physics_order_snapshots.png`` (the last frame at each rate,
seed 1, the paper's Fig. 1b).
"""

from __future__ import annotations

import argparse

import numpy as np

from verification.physics_common import (
    RESULTS, RUNS, cached, ensure_relaxation, ensure_run, example_scene, fmt, wall_seconds,
)

RATES = (1e-4, 0.0017, 0.0161, 0.1083, 1.0)
SEEDS = (1, 2, 3)
SHEAR_DURATIONS = {1e-4: 20000.0, 0.0017: 100000.0, 0.0161: 100000.0, 0.1083: 20000.0, 1.0: 20000.0}
N_FRAMES = 250
LAST_FRAMES = 50
PAPER_PROTOCOL = {"shear_duration": 1e5, "frames": 250, "last_frames": 50, "samples": 10, "dt": 0.1}
QUICK = {"rates": (0.0161, 1.0), "seeds": (1,), "shear_duration": 4000.0, "h": 2.0}


def _scene(seed: int, rate: float, shear_duration: float, h: float):
    return example_scene("random", [
        f"particles.seed={seed}", f"domain.h={h}", "output.fields=false",
        f"phases.1.flow.rate={rate}", f"phases.1.duration={shear_duration}",
        f"phases.1.frame_interval={shear_duration / N_FRAMES}",
    ])


def run_name(seed: int, rate: float | None, h: float, shear_duration: float) -> str:
    tag = f"order_h{h:g}_seed{seed}"
    return f"{tag}_relax" if rate is None else f"{tag}_rate{rate:g}_T{shear_duration:g}"


def analyse(directory, rate: float) -> dict:
    """Order parameters over the last frames of one run (see the module docstring)."""
    from femphase.analysis.lattice import bond_order, frame_average, global_order, nematic_order
    from femphase.analysis.lattice import periodic_delaunay_pairs
    from femphase.io.reader import open_run

    run = open_run(directory).complete()
    shear = np.flatnonzero(run.time >= run.shear_start - 1e-9)
    last = shear[-LAST_FRAMES:]
    margin = 2 * run.radius
    bulk6, bulk2 = [], []
    for k in last:
        centroids = np.stack([run.x[k], run.y[k]], axis=1)
        pairs = periodic_delaunay_pairs(centroids, run.length)
        inside = (run.y[k] > margin) & (run.y[k] < run.width - margin)
        bulk6.append(global_order(bond_order(centroids, run.length, pairs), where=inside))
        bulk2.append(global_order(nematic_order(run.orientation[k], pairs, run.n_particles), where=inside))
    duration = run.time[shear[-1]] - run.time[shear[0]]
    psi6, psi6_sd = frame_average(run.globals["Psi6"][last])
    psi2, psi2_sd = frame_average(run.globals["Psi2"][last])
    b6, b6_sd = frame_average(bulk6)
    b2, b2_sd = frame_average(bulk2)
    return {
        "rate": rate,
        "Psi6": psi6, "Psi6_sd": psi6_sd, "Psi2": psi2, "Psi2_sd": psi2_sd,
        "Psi6_bulk": b6, "Psi6_bulk_sd": b6_sd, "Psi2_bulk": b2, "Psi2_bulk_sd": b2_sd,
        "t1_events": int(run.t1_times.size),
        "t1_rate_last_frames": float(np.sum(run.t1_times >= run.time[last[0]]) / (run.time[last[-1]] - run.time[last[0]])),
        "mean_elongation_last_frames": float(run.elongation[last].mean()),
        "wall_displacement": float(rate * duration),
        "shear_duration": float(duration),
        "wall_seconds": wall_seconds(directory),
    }


def summarise(results: list[dict]) -> dict:
    """Per rate: mean and standard deviation over the samples of each run's frame average."""
    rows = []
    for rate in sorted({r["rate"] for r in results}):
        chosen = [r for r in results if r["rate"] == rate]
        row = {"rate": rate, "samples": len(chosen)}
        for name in ("Psi6", "Psi2", "Psi6_bulk", "Psi2_bulk", "mean_elongation_last_frames", "t1_rate_last_frames"):
            values = np.array([r[name] for r in chosen])
            row[name] = float(values.mean())
            row[f"{name}_sd_samples"] = float(values.std(ddof=1)) if len(values) > 1 else None
        row["wall_displacement"] = chosen[0]["wall_displacement"]
        row["shear_duration"] = chosen[0]["shear_duration"]
        rows.append(row)
    return {"rates": rows}


def figures(summary: dict, seeds: tuple[int, ...], h: float, durations: dict[float, float]) -> None:
    from femphase.plot.figures import pyplot
    from femphase.plot.run import draw_snapshot
    from femphase.io.reader import open_run
    from femphase.io.rundir import CHECKPOINT

    plt = pyplot()
    rows = summary["rates"]
    rates = np.array([r["rate"] for r in rows])
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, label, color in (("Psi6", "Ψ6", "C0"), ("Psi2", "Ψ2^L", "C1")):
        for suffix, style in (("", "-o"), ("_bulk", ":s")):
            mean = np.array([r[name + suffix] for r in rows])
            sd = np.array([r[f"{name}{suffix}_sd_samples"] or 0.0 for r in rows])
            ax.plot(rates, mean, style, color=color, ms=4, label=label + (" (bulk)" if suffix else " (all)"))
            if not suffix:
                ax.fill_between(rates, mean - sd, mean + sd, color=color, alpha=0.2)
    ax.set_xscale("log")
    ax.set_ylim(0, 1)
    ax.set_xlabel("shear rate γ̇ (wall velocity)")
    ax.set_ylabel("order parameter, last 50 of 250 frames")
    ax.set_title(f"{len(seeds)} samples, {min(durations.values()):g}–{max(durations.values()):g} time units "
                 f"of shear, h = {h:g} "
                 "(paper: 10 samples, 10^5)", fontsize=8)
    ax.legend(fontsize=7)
    fig.tight_layout()
    RESULTS.mkdir(parents=True, exist_ok=True)
    fig.savefig(RESULTS / "physics_order.png", dpi=130)
    plt.close(fig)

    directories = [RUNS / run_name(seeds[0], rate, h, durations[rate]) for rate in rates]
    directories = [d for d in directories if (d / CHECKPOINT).exists()]
    fig, axes = plt.subplots(1, len(directories), figsize=(2.0 * len(directories), 6.5), squeeze=False)
    for ax, directory, rate in zip(axes[0], directories, rates):
        draw_snapshot(ax, open_run(directory).complete())
        ax.set_title(f"γ̇ = {rate:g}", fontsize=8)
    fig.tight_layout()
    fig.savefig(RESULTS / "physics_order_snapshots.png", dpi=130)
    plt.close(fig)


def table(summary: dict) -> str:
    lines = ["| γ̇ | samples | shear duration | wall displacement | Ψ6 (all) | Ψ2^L (all) | Ψ6 (bulk) | Ψ2^L (bulk) "
             "| mean r | T1 rate |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in summary["rates"]:
        lines.append(
            f"| {r['rate']:g} | {r['samples']} | {r['shear_duration']:.3g} | {r['wall_displacement']:.3g} | "
            + " | ".join(fmt(r[n], r[f"{n}_sd_samples"], 3) for n in ("Psi6", "Psi2", "Psi6_bulk", "Psi2_bulk"))
            + f" | {r['mean_elongation_last_frames']:.3f} | {r['t1_rate_last_frames']:.3g} |")
    return "\n".join(lines)


def run(quick: bool = False, seeds: tuple[int, ...] | None = None, simulate_only: bool = False,
        rates: tuple[float, ...] | None = None, shear_duration: float | None = None) -> dict:
    """Run (resumably) and analyse the order-parameter runs; write the results (not in quick,
    and only for the default rates and durations, SHEAR_DURATIONS)."""
    write = not quick and rates is None and shear_duration is None
    rates = rates or (QUICK["rates"] if quick else RATES)
    seeds = seeds or (QUICK["seeds"] if quick else SEEDS)
    durations = {rate: shear_duration or (QUICK["shear_duration"] if quick else SHEAR_DURATIONS[rate])
                 for rate in rates}
    h = QUICK["h"] if quick else 1.0
    results = []
    for seed in seeds:
        for rate in rates:
            print(f"seed {seed}, γ̇ = {rate:g}", flush=True)
            scene = _scene(seed, rate, durations[rate], h)
            relaxed = ensure_relaxation(scene, RUNS / run_name(seed, None, h, durations[rate]))
            directory = ensure_run(scene, RUNS / run_name(seed, rate, h, durations[rate]), branch_from=relaxed)
            if not simulate_only:
                key = {"seed": seed, "rate": rate, "h": h, "shear": durations[rate], "version": 1}
                result = cached(directory / "result.json", lambda: analyse(directory, rate), key)
                results.append({**result, "seed": seed})
    if simulate_only:
        return {}
    summary = {
        **summarise(results),
        "runs": results,
        "protocol": {
            "scene": "examples/random.toml (N = 100 random discs of R/2, 70 × 240, relax 2000, dt = 1)",
            "h": h, "dt": 1.0, "rates": list(rates), "seeds": list(seeds),
            "shear_duration": {f"{rate:g}": duration for rate, duration in durations.items()},
            "frames": N_FRAMES, "last_frames": LAST_FRAMES, "paper": PAPER_PROTOCOL,
            "reduced": "3 samples instead of 10; the paper's 1e5 time units of shear at 0.0017 and 0.0161, "
                       "2e4 at the other rates (frames every 80 there, not 400: the averaging window is the "
                       "last 4000 time units instead of 2e4)",
        },
    }
    if write:
        from femphase.io.files import write_json

        write_json(RESULTS / "physics_order.json", summary)
        figures(summary, seeds, h, durations)
    print(table(summary))
    return summary


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="h = 2, one seed, two rates, 4000 of shear")
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="run only these seeds")
    parser.add_argument("--simulate-only", action="store_true", help="run the simulations, skip the analysis")
    parser.add_argument("--rates", type=float, nargs="+", default=None,
                        help="run only these rates (results are then printed, not written)")
    parser.add_argument("--shear-duration", type=float, default=None,
                        help="time units of shear at every rate (default: SHEAR_DURATIONS per rate; results "
                             "then printed, not written)")
    args = parser.parse_args()
    run(args.quick, tuple(args.seeds) if args.seeds else None, args.simulate_only,
        tuple(args.rates) if args.rates else None, args.shear_duration)
