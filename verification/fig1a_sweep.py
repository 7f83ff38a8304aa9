"""Fig. 1a from a sweep directory: the order parameters against the shear rate (or, for
the supplement's Poiseuille figure, against the centre-line velocity: the same axis key).

    femphase sweep verification/sweeps/fig1a_reduced.toml -o verification/runs/fig1a_reduced
    python -m verification.fig1a_sweep verification/runs/fig1a_reduced
    femphase sweep verification/sweeps/poiseuille_reduced.toml -o verification/runs/poiseuille_reduced
    python -m verification.fig1a_sweep verification/runs/poiseuille_reduced
    python -m verification.fig1a_sweep verification/runs/poiseuille_mesh_reduced --against poiseuille_reduced
    python -m verification.fig1a_sweep --stored poiseuille_mesh_fast --against poiseuille_fast_counted

Aggregates the sweep (``femphase aggregate``: Ψ6 and Ψ2^L averaged over the last fifth of
the shear frames of every run, the paper's last 50 of 250), draws ``femphase plot``'s sweep
figures into ``verification/results/<sweep name>/``, and writes
``verification/results/<sweep name>.json`` with, per rate: the samples done, the mean and
sample standard deviation (ddof = 1, the paper's shading) of Ψ6, Ψ2^L, the mean elongation
and the T1 rate; it prints the same as a markdown table for verification/README.md, and
with ``--against NAME`` a point-by-point comparison with another sweep's results.
Works on a sweep still under way (the runs not done are counted, not averaged), and on a
sweep over samples alone at one velocity set in its [set] (a one-row table, no figures). With
``--stored NAME`` instead of a directory it reads ``verification/results/NAME.json`` (a
sweep aggregated before, whose runs need not be on this machine) and writes nothing.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tomllib
from pathlib import Path

import numpy as np

from femphase.plot.sweep import plot_sweep, sample_curves
from femphase.aggregate import read_summary, write_aggregate

RESULTS = Path(__file__).resolve().parent / "results"
#: The swept axis that is not a sample axis: the rate (shear, Poiseuille) or, for a Stokes
#: flow on a mesh, its centre-line velocity ``phases.1.flow.max_velocity``
SAMPLE_AXES = ("particles.seed",)
COLUMNS = {"Psi6_mean": "Ψ6", "Psi2_mean": "Ψ2^L", "elongation_mean": "mean r", "t1_rate": "T1 rate (per particle per 1000 t)"}


def rate_table(rows: list[dict], rate_key: str = "phases.1.flow.rate") -> list[dict]:
    """Per value of ``rate_key``: samples done and mean ± s.d. of every column of :data:`COLUMNS`."""
    done = [row for row in rows if row["status"] == "done"]
    curves = {column: sample_curves(done, column, rate_key, [])[()] for column in COLUMNS}
    rates = sorted({row[rate_key] for row in rows})
    table = []
    for rate in rates:
        entry = {"rate": rate, "runs": sum(row[rate_key] == rate for row in rows),
                 "done": sum(row[rate_key] == rate for row in done)}
        for column, curve in curves.items():
            if rate in curve.x:
                k = curve.x.index(rate)
                entry[column] = {"mean": float(curve.mean[k]), "sd": float(curve.sd[k])}
        table.append(entry)
    return table


def markdown(table: list[dict]) -> str:
    def cell(entry: dict, column: str) -> str:
        if column not in entry:
            return "–"
        scale = 1000.0 if column == "t1_rate" else 1.0
        mean, sd = entry[column]["mean"] * scale, entry[column]["sd"] * scale
        return f"{mean:.3g} ± {sd:.2g}" if sd == sd else f"{mean:.3g}"

    lines = ["| γ̇ | samples done | " + " | ".join(COLUMNS.values()) + " |", "|" + "---|" * (2 + len(COLUMNS))]
    lines += [f"| {e['rate']:g} | {e['done']}/{e['runs']} | " + " | ".join(cell(e, c) for c in COLUMNS) + " |"
              for e in table]
    return "\n".join(lines)


def comparison(table: list[dict], other: list[dict]) -> str:
    """Point by point against another sweep's table (same rates): per column this sweep's
    mean, the other's, and their difference in units of the two samples' combined standard
    error √(sd₁²/n₁ + sd₂²/n₂)."""
    by_rate = {entry["rate"]: entry for entry in other}
    lines = ["| γ̇ | " + " | ".join(f"{name}: this, other, Δ/s.e." for name in COLUMNS.values()) + " |",
             "|" + "---|" * (1 + len(COLUMNS))]
    for entry in table:
        match = by_rate.get(entry["rate"])
        cells = []
        for column in COLUMNS:
            if match is None or column not in entry or column not in match:
                cells.append("–")
                continue
            scale = 1000.0 if column == "t1_rate" else 1.0
            a, b = entry[column], match[column]
            error = np.sqrt(a["sd"] ** 2 / max(entry["done"], 1) + b["sd"] ** 2 / max(match["done"], 1))
            ratio = (a["mean"] - b["mean"]) / error if error > 0 else float("nan")
            cells.append(f"{scale * a['mean']:.3g}, {scale * b['mean']:.3g}, {ratio:+.1f}")
        lines.append(f"| {entry['rate']:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def fixed_rate(directory: Path, sweep: dict) -> tuple[str, float]:
    """(key, value) of the flow velocity of a sweep over samples alone, the velocity set in
    its [set]: read from its first run's scene. SystemExit when the scene has none."""
    scene = tomllib.loads((directory / sweep["runs"][0]["directory"] / "scene.toml").read_text())
    flow = scene["phases"][1].get("flow", {}) if len(scene.get("phases", [])) > 1 else {}
    for key in ("rate", "max_velocity"):
        if key in flow:
            return f"phases.1.flow.{key}", float(flow[key])
    raise SystemExit(f"{directory}: the sweep's axes {list(sweep['axes'])} are samples only and its scene's "
                     f"phases.1.flow {flow!r} has no rate or max_velocity to tabulate against")


def stored(name: str) -> list[dict]:
    """The rate table of a sweep aggregated before, ``verification/results/NAME.json``."""
    path = RESULTS / f"{name}.json"
    if not path.is_file() or "rates" not in json.loads(path.read_text()):
        sweeps = sorted(p.stem for p in RESULTS.glob("*.json") if "rates" in json.loads(p.read_text()))
        raise SystemExit(f"no sweep results named {name!r} in {RESULTS}; stored sweeps: {', '.join(sweeps)}")
    return json.loads(path.read_text())["rates"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path, nargs="?", help="the sweep directory (femphase sweep -o DIR)")
    parser.add_argument("--stored", metavar="NAME", help="instead of a directory, a sweep's stored "
                        "results/NAME.json (prints its table, writes nothing)")
    parser.add_argument("--against", metavar="NAME", help="another sweep's results/NAME.json to compare with, "
                        "rate by rate (e.g. poiseuille_reduced)")
    args = parser.parse_args()
    if (args.directory is None) == (args.stored is None):
        parser.error("give one of a sweep directory and --stored NAME")
    if args.stored:
        table = stored(args.stored)
        print(markdown(table))
        if args.against:
            print(comparison(table, stored(args.against)))
        return
    name = args.directory.name
    out = RESULTS / f"{name}.json"
    if out.is_file() and "rates" not in json.loads(out.read_text()):
        # results/ holds other verifications' files: a sweep named like one must not replace it
        raise SystemExit(f"{out} holds another verification's results, not a sweep's; "
                         f"name the sweep directory differently (e.g. {name}_full)")
    sweep = json.loads((args.directory / "sweep.json").read_text())
    rate_key = next((key for key in sweep["axes"] if key not in SAMPLE_AXES), None)
    if rate_key is None:  # samples alone, at one velocity: no curve to draw
        rate_key, rate = fixed_rate(args.directory, sweep)
        write_aggregate(args.directory)
        rows = [{**row, rate_key: rate} for row in read_summary(args.directory / "summary.csv")]
        figures = {}
    else:
        figures = plot_sweep(args.directory, RESULTS / name)
        rows = read_summary(args.directory / "summary.csv")
    table = rate_table(rows, rate_key)
    out.write_text(json.dumps({"sweep": str(args.directory), "axes": sweep["axes"], "rates": table,
                               "figures": {k: str(v.relative_to(RESULTS.parent)) for k, v in figures.items()},
                               "command": f"python -m verification.fig1a_sweep {args.directory}"}, indent=1) + "\n")
    print(markdown(table))
    if args.against:
        print(comparison(table, stored(args.against)))
    print(f"wrote {', '.join(str(p) for p in (out, *figures.values()))}")
    shutil.copy(args.directory / "summary.csv", RESULTS / f"{name}_summary.csv")


if __name__ == "__main__":
    main()
