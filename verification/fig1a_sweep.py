"""Fig. 1a from a sweep directory: the order parameters against the shear rate (or, for
the supplement's Poiseuille figure, against the centre-line velocity: the same axis key).

    femphase sweep verification/sweeps/fig1a_reduced.toml -o verification/runs/fig1a_reduced
    python -m verification.fig1a_sweep verification/runs/fig1a_reduced
    femphase sweep verification/sweeps/poiseuille_reduced.toml -o verification/runs/poiseuille_reduced
    python -m verification.fig1a_sweep verification/runs/poiseuille_reduced
    python -m verification.fig1a_sweep verification/runs/poiseuille_mesh_reduced --against poiseuille_reduced

Aggregates the sweep (``femphase aggregate``: Ψ6 and Ψ2^L averaged over the last fifth of
the shear frames of every run, the paper's last 50 of 250), draws ``femphase plot``'s sweep
figures into ``verification/results/<sweep name>/``, and writes
``verification/results/<sweep name>.json`` with, per rate: the samples done, the mean and
sample standard deviation (ddof = 1, the paper's shading) of Ψ6, Ψ2^L, the mean elongation
and the T1 rate; it prints the same as a markdown table for verification/README.md, and
with ``--against NAME`` a point-by-point comparison with another sweep's results.
Works on a sweep still under way (the runs not done are counted, not averaged).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

from femphase.plot.sweep import plot_sweep, sample_curves
from femphase.aggregate import read_summary

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path, help="the sweep directory (femphase sweep -o DIR)")
    parser.add_argument("--against", metavar="NAME", help="another sweep's results/NAME.json to compare with, "
                        "rate by rate (e.g. poiseuille_reduced)")
    args = parser.parse_args()
    name = args.directory.name
    out = RESULTS / f"{name}.json"
    if out.is_file() and "rates" not in json.loads(out.read_text()):
        # results/ holds other verifications' files: a sweep named like one must not replace it
        raise SystemExit(f"{out} holds another verification's results, not a sweep's; "
                         f"name the sweep directory differently (e.g. {name}_full)")
    figures = plot_sweep(args.directory, RESULTS / name)
    sweep = json.loads((args.directory / "sweep.json").read_text())
    rate_key = next(key for key in sweep["axes"] if key not in SAMPLE_AXES)
    table = rate_table(read_summary(args.directory / "summary.csv"), rate_key)
    out.write_text(json.dumps({"sweep": str(args.directory), "axes": sweep["axes"], "rates": table,
                               "figures": {k: str(v.relative_to(RESULTS.parent)) for k, v in figures.items()},
                               "command": f"python -m verification.fig1a_sweep {args.directory}"}, indent=1) + "\n")
    print(markdown(table))
    if args.against:
        print(comparison(table, json.loads((RESULTS / f"{args.against}.json").read_text())["rates"]))
    print(f"wrote {out} and {', '.join(str(p) for p in figures.values())}")
    shutil.copy(args.directory / "summary.csv", RESULTS / f"{name}_summary.csv")


if __name__ == "__main__":
    main()
