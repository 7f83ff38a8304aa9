"""The period law's h-trend and the equilibrium's h → 0 limit, through `femphase converge`.

    python verification/converge_studies.py [--runs DIR] [--workers N]     # ~0.5 CPU-hours, resumable

Two convergence studies, each exactly what the command line runs:

* ``period``: ``femphase converge examples/hexagonal.toml --h 2,1,0.5,0.25 --set
  numerics.tolerance_t=0.01 --observable period,mean_elongation`` — the paper's N = 100
  lattice sheared at γ̇ = 0.1487 (20000 time units after 2000 of relaxation, the adaptive
  scheme at dt = 10); the period of r̄(t) and its mean, with the observed order and the
  Richardson limit, and T·γ̇ at every h. The tolerance is the one the accuracy guard asks
  for below h = 0.5 (the default 0.1 does not reproduce the oscillation at h = 0.25), set
  at every level so that the levels differ in h only;
* ``equilibrium``: ``femphase converge verification/scenes/equilibrium_disc.toml --h
  1,0.5,0.25,0.125 --observable area`` — one disc relaxed to equilibrium; its area's limit
  against the one of ``verification/equilibrium.py``.

The study directories go to ``--runs`` (default verification/runs/converge_*; rerunning
continues them; ``--workers`` runs in parallel); their convergence.csv and .png are copied to verification/results/, and
the ``converge_studies`` block of verification/README.md is rewritten.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from dataclasses import asdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from femphase.converge import run_convergence  # noqa: E402
from verification.readme import write_block  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "verification" / "results"
RATE = 0.1487
STUDIES = {
    "period": (REPO / "examples" / "hexagonal.toml", [2.0, 1.0, 0.5, 0.25], ["period", "mean_elongation"],
               ["numerics.tolerance_t=0.01"]),
    "equilibrium": (REPO / "verification" / "scenes" / "equilibrium_disc.toml", [1.0, 0.5, 0.25, 0.125], ["area"],
                    []),
}


def _uncertainty(value: float) -> str:
    """" ± u" for a value measured with its own uncertainty (a period), else ""."""
    return f" ± {value:.2g}" if value > 0 else ""


def block(results: dict) -> str:
    lines = []
    for name, result in results.items():
        scene, spacings, observables, assignments = STUDIES[name]
        options = "".join(f" --set {assignment}" for assignment in assignments)
        lines.append(f"`femphase converge {scene.relative_to(REPO)} --h {','.join(f'{h:g}' for h in spacings)}"
                     f"{options} --observable {','.join(observables)}`\n")
        lines.append("| observable | " + " | ".join(f"h = {level['s']:g}" for level in result["levels"])
                     + " | observed order | order used | Richardson limit ± error bar |")
        lines.append("|---|" + "---|" * (len(result["levels"]) + 3))
        for observable, estimate in result["estimates"].items():
            values = " | ".join(f"{level[observable]:.6g}" + _uncertainty(level["uncertainty"][observable])
                                for level in result["levels"])
            lines.append(f"| {observable} | {values} | {estimate.order:.2f} | {estimate.order_used:g} | "
                         f"{estimate.limit:.6g} ± {estimate.error_bar:.2g} |")
            if observable == "period":
                scaled = " | ".join(f"{RATE * level['period']:.2f}"
                                    + _uncertainty(RATE * level["uncertainty"]["period"]) for level in result["levels"])
                lines.append(f"| T·γ̇ | {scaled} | {estimate.order:.2f} | {estimate.order_used:g} | "
                             f"{RATE * estimate.limit:.2f} ± {RATE * estimate.error_bar:.2g} |")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=Path, default=REPO / "verification" / "runs", help="where the studies run")
    parser.add_argument("--only", choices=sorted(STUDIES), nargs="+", default=sorted(STUDIES))
    parser.add_argument("--workers", type=int, default=None, help="parallel runs (default: the sweep's)")
    args = parser.parse_args()
    results = {}
    for name in args.only:
        scene, spacings, observables, assignments = STUDIES[name]
        directory = args.runs / f"converge_{name}"
        results[name] = run_convergence(scene, directory, "h", spacings, observables, assignments,
                                        workers=args.workers, log=print)
        for suffix in ("csv", "png"):
            shutil.copyfile(directory / f"convergence.{suffix}", RESULTS / f"converge_{name}.{suffix}")
    text = block(results)
    print(text)
    (RESULTS / "converge_studies.json").write_text(json.dumps(
        {name: {"levels": r["levels"], "estimates": {k: asdict(e) for k, e in r["estimates"].items()}}
         for name, r in results.items()}, indent=1))
    write_block("converge_studies", text, "Convergence studies through `femphase converge`")


if __name__ == "__main__":
    main()
