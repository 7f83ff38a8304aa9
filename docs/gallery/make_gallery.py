"""Regenerate the gallery: docs/gallery/index.md and its figures, docs/gallery/figures/*.png.

    python docs/gallery/make_gallery.py            # every example below, ~4 minutes on 2 cores
    python docs/gallery/make_gallery.py single     # only the named examples (the page lists all)

Each example runs as ``python -m femphase.cli run SCENE -o DIR`` (the ``femphase run`` of
this checkout), with the ``--set`` overrides listed below where the scene's own protocol is
too long for a gallery, on one thread (OMP_NUM_THREADS, OPENBLAS_NUM_THREADS and
NUMBA_NUM_THREADS set to 1). ``femphase plot DIR`` then draws its figures, and the ones
listed are copied to docs/gallery/figures/ as palette PNGs (small enough to commit). The run
directories are kept under docs/_build/gallery-runs/ (not committed). The page is written
from the commands that ran, so what it quotes reproduces its figures. The figures are
committed: building the site runs no simulation.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
GALLERY = Path(__file__).resolve().parent
FIGURES = GALLERY / "figures"
RUNS = Path("docs/_build/gallery-runs")  # relative to ROOT, as the commands quote it
THREADS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
MAX_BYTES = 200_000

#: What `femphase plot` draws (docs: femphase/plot/run.py).
CAPTIONS = {
    "snapshot": "The last frame: Σφ_i in grey, each particle tinted, its elongation axis in red "
    "(length R·r).",
    "elongation": "Elongation r(t): the bulk mean, individual particles and the paper's minimal "
    "ODE model at the run's shear rate.",
    "limit_cycle": "The (r, 2θ) plane of three bulk particles over the last quarter of the run, "
    "with the ODE's cycle.",
    "order": "Bond order Ψ6, nematic order Ψ2^L, the lattice angle φ and the cumulative count "
    "of T1 events.",
}


@dataclass
class Example:
    name: str
    title: str
    what: str
    sets: list[str] = field(default_factory=list)
    figures: list[str] = field(default_factory=list)

    @property
    def scene(self) -> Path:
        return Path("examples") / f"{self.name}.toml"

    @property
    def run_dir(self) -> Path:
        return RUNS / self.name

    def commands(self) -> list[list[str]]:
        run = ["python", "-m", "femphase.cli", "run", str(self.scene), "-o", str(self.run_dir),
               "--overwrite", "-q"]
        for item in self.sets:
            run += ["--set", item]
        return [run, ["python", "-m", "femphase.cli", "plot", str(self.run_dir)]]


EXAMPLES = [
    Example(
        "single",
        "A single particle in shear",
        "One particle in the paper's 70 × 240 channel relaxes from a disc of radius R/2 to its "
        "target area, then is sheared at the paper's highest rate γ̇ = 1 (the top wall moving "
        "at γ̇). Alone, it elongates, tilts towards the flow and settles to a steady shape "
        "without oscillating (the red curve is the minimal ODE model of the dense lattice, "
        "drawn by `femphase plot` for every run). The scene's own protocol.",
        figures=["snapshot", "elongation"],
    ),
    Example(
        "hexagonal",
        "The sheared hexagonal lattice (the paper's Fig. 2 scene)",
        "N = 100 particles start on a hexagonal lattice, relax without flow for 2000 time "
        "units and are then sheared at γ̇ = 0.1487 for 20000. The lattice tilts with the flow "
        "and snaps back periodically: its angle φ swings between hexagonal (60°) and just "
        "past square (about 41°); at each square configuration rows of neighbours exchange in "
        "a burst of T1 events and the bond order Ψ6 drops, and the particles' elongation r "
        "oscillates at the same period. The minimal ODE model (red), aligned at the first T1 "
        "event, is drawn for comparison. The scene's own protocol (about ten periods; the "
        "paper shears for 10⁵ time units).",
        figures=["order", "elongation", "limit_cycle", "snapshot"],
    ),
    Example(
        "random",
        "Random initial conditions, shortened",
        "N = 100 discs of radius R/2 at random centroids relax for 2000 time units and are "
        "sheared at γ̇ = 0.1083. The gallery shears for 10000 time units with a frame every "
        "100 (the scene: 10⁵ time units, a frame every 400). Over this stretch the packing "
        "stays disordered: Ψ6 stays below 0.5, the lattice angle wanders around square and T1 "
        "events occur steadily rather than in bursts; whether order emerges later is what the "
        "scene's full protocol is for.",
        sets=["phases.1.duration=10000", "phases.1.frame_interval=100"],
        figures=["order", "elongation", "snapshot"],
    ),
    Example(
        "constriction_mesh",
        "A meshed channel with a constriction, shortened",
        "The meshed domain (`[domain] kind = \"mesh\"`): N = 80 random discs in a channel whose "
        "walls bulge inwards to a throat of width 144 (meshes/constriction.msh, an unstructured "
        "Delaunay mesh), driven by the Stokes flow of the same mesh (maximum velocity 0.1). "
        "The gallery relaxes for 200 time units and runs the flow for 200 (the scene: 2000 "
        "and 20000), enough to show how the particles pack against the curved walls. "
        "femphase warns on this mesh that its median edge (h ≈ 1.08) puts fewer than two nodes "
        "across the interface width λ = 2.",
        sets=["phases.0.duration=200", "phases.1.duration=200", "phases.0.frame_interval=100",
              "phases.1.frame_interval=100"],
        figures=["snapshot"],
    ),
]


def compact(source: Path, target: Path) -> None:
    """Copy a matplotlib PNG as a 256-colour palette PNG (a third of the size, the same look)."""
    with Image.open(source) as image:
        image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(target, optimize=True)
    size = target.stat().st_size
    if size > MAX_BYTES:
        raise SystemExit(f"{target} is {size} bytes (> {MAX_BYTES}): shrink the figure before committing it")


def run(example: Example) -> dict[str, float]:
    env = {**os.environ, **THREADS}
    seconds = {}
    for command, label in zip(example.commands(), ("run", "plot")):
        print("$", shlex.join(command), flush=True)
        start = time.perf_counter()
        subprocess.run([sys.executable, *command[1:]], cwd=ROOT, env=env, check=True)
        seconds[label] = time.perf_counter() - start
    FIGURES.mkdir(exist_ok=True)
    for figure in example.figures:
        compact(ROOT / example.run_dir / "figures" / f"{figure}.png", FIGURES / f"{example.name}-{figure}.png")
    return seconds


def section(example: Example, seconds: dict[str, float] | None) -> str:
    lines = [f"## {example.title}", "", example.what, "",
             f"Scene: [`{example.scene}`](../../{example.scene})"
             + (f", with `{'`, `'.join(example.sets)}` set on the command line." if example.sets else ".")]
    lines += ["", "```{literalinclude} " + f"../../{example.scene}", ":language: toml", "```", ""]
    for figure in example.figures:
        width = ":width: 40%\n" if figure == "snapshot" else ""
        lines += [f"```{{figure}} figures/{example.name}-{figure}.png", f"{width}:alt: {example.name}: {figure}",
                  "", CAPTIONS[figure], "```", ""]
    lines += ["Reproduce, from the repository's root (`python -m femphase.cli` is the `femphase` command",
              "of the checkout):",
              "", "```bash"]
    lines += [shlex.join(command) for command in example.commands()]
    lines += ["```", ""]
    if seconds:
        lines += [f"Wall time on one thread: run {seconds['run']:.0f} s, plot {seconds['plot']:.0f} s.", ""]
    return "\n".join(lines)


def page(timings: dict[str, dict[str, float]]) -> str:
    head = [
        "# Gallery",
        "",
        "The example scenes of `examples/`, run and plotted. Every figure on this page was made by",
        "",
        "```bash",
        "python docs/gallery/make_gallery.py",
        "```",
        "",
        "which runs each example with the command quoted under it (on one thread:",
        f"`{' '.join(f'{k}={v}' for k, v in THREADS.items())}`), then `femphase plot`, and",
        "rewrites this page; the long scenes run a shortened protocol, stated with each. The",
        "figures are committed, so building the documentation runs no simulation. What each figure",
        "shows, and the columns behind it: [outputs.md](../outputs.md); the scene keys:",
        "[scenes.md](../scenes.md).",
        "",
    ]
    return "\n".join(head) + "\n" + "\n".join(section(e, timings.get(e.name)) for e in EXAMPLES)


def previous_timings() -> dict[str, dict[str, float]]:
    """The wall times the current page states, kept for the examples not rerun."""
    import re

    timings = {}
    index = GALLERY / "index.md"
    if index.exists():
        for part in index.read_text().split("\n## ")[1:]:
            name = re.search(r"examples/(\w+)\.toml", part)
            time_line = re.search(r"run (\d+) s, plot (\d+) s", part)
            if name and time_line:
                timings[name.group(1)] = {"run": float(time_line.group(1)), "plot": float(time_line.group(2))}
    return timings


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="examples to rerun (default: all)")
    names = parser.parse_args().names or [e.name for e in EXAMPLES]
    unknown = set(names) - {e.name for e in EXAMPLES}
    if unknown:
        parser.error(f"unknown examples {sorted(unknown)}; known: {[e.name for e in EXAMPLES]}")
    start = time.perf_counter()
    timings = previous_timings()
    for example in EXAMPLES:
        if example.name in names:
            timings[example.name] = run(example)
    (GALLERY / "index.md").write_text(page(timings))
    print(f"gallery written in {time.perf_counter() - start:.0f} s: {GALLERY / 'index.md'}")
