"""How well each domain's shape-tensor rule reads the elongation of a known shape.

    python -m verification.shape_bias [--quick]

The grid and the mesh measure the elongation r = λ1/λ2 − 1 of the shape tensor
R = −∫∇φ∇φᵀ by different rules (:mod:`femphase.analysis.shape`): the structured channel by
nodal central differences, a meshed channel by the exact integral of the P1 gradients. Both
are O(h²) accurate, but their constants differ, and on an irregular mesh the error varies with
position. This check separates the measurement from the dynamics: it writes the same
analytic fields on every domain and compares the r each one reads.

Fields: ellipses of area πR² (R = 8) and aspect ratio a/b = 1 + e, e = 0, 0.1, 0.2, 0.4,
with the profile (1 + tanh(R(1 − ρ)/λ))/2, ρ = ((x'/a)² + (y'/b)²)^½ in the ellipse's axes,
at the same random centres (40, away from the walls) and orientations on every domain. The
reference r of each field is read on the structured channel at h = 0.125 (quick: 0.25);
the continuum value is within O(h²) of it. Domains: `examples/straight_mesh.toml`'s
unstructured mesh (h ≈ 1.08), the same scene on `meshes/straight_structured.vtu` (the
structured channel's triangulation, every diagonal along +45°, read by the meshes' P1
rule) and the structured channel at h = 1.25, 1 and 0.5.

Reported per domain and e: the mean and standard deviation over the particles of the
difference from the reference r; and, for e = 0.2 and 0.4, the mean difference at each of
eight orientations θ of the major axis (:data:`ORIENTATIONS`, the same random centres at
each): how the error depends on the direction of the elongation, which the paper's limit
cycle sweeps through ±π/4.
"""

from __future__ import annotations

import os

# one BLAS thread: the machine's two cores are shared with other long runs
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from femphase.analysis.shape import shape_observables  # noqa: E402
from femphase.errors import ResolutionWarning  # noqa: E402
from femphase.model.parameters import interface_profile  # noqa: E402
from femphase.scene import load_scene  # noqa: E402
from femphase.state import State  # noqa: E402
from verification.mms import command_line, save_figure, save_results  # noqa: E402

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
RADIUS, WIDTH = 8.0, 2.0
ASPECTS = (0.0, 0.1, 0.2, 0.4)  # e = a/b − 1
N_SHAPES, SEED = 40, 0
#: Orientations of the major axis from x (radians) for the table by direction, and its aspects.
ORIENTATIONS = tuple(k * np.pi / 8 for k in range(-3, 5))
ORIENTED_ASPECTS = (0.2, 0.4)
#: name → (scene file, assignments)
DOMAINS = {
    "mesh (h ≈ 1.08)": ("straight_mesh.toml", ()),
    "structured mesh (h = 1)": ("straight_mesh.toml", ('domain.mesh="../meshes/straight_structured.vtu"',)),
    "grid h = 1.25": ("random.toml", ("domain.h=1.25",)),
    "grid h = 1": ("random.toml", ()),
    "grid h = 0.5": ("random.toml", ("domain.h=0.5",)),
}


def example_scene(path: str, assignments: tuple[str, ...]):
    """The scene of examples/``path`` with ``assignments``, its resolution warning silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResolutionWarning)  # coarse h is the point here
        return load_scene(EXAMPLES / path, list(assignments))


def ellipses(scene, centres: np.ndarray, angles: np.ndarray, aspect: float) -> State:
    """Ellipses of area πR² and a/b = 1 + ``aspect`` at ``centres``, major axes at
    ``angles`` from x, each on the window of its circumscribed disc plus 3λ."""
    domain, policy = scene.domain, scene.window_policy()
    a, b = RADIUS * np.sqrt(1.0 + aspect), RADIUS / np.sqrt(1.0 + aspect)
    windows, fields = [], []
    for (cx, cy), angle in zip(centres, angles):
        window = domain.disc_window((cx, cy), a + 3.0 * WIDTH, policy)
        dx, dy = domain.offsets(window, (cx, cy))
        along = np.cos(angle) * dx + np.sin(angle) * dy
        across = -np.sin(angle) * dx + np.cos(angle) * dy
        windows.append(window)
        fields.append(interface_profile(RADIUS * (1.0 - np.hypot(along / a, across / b)), WIDTH))
    return State(domain, windows, fields, np.full(len(fields), RADIUS))


def run(quick: bool = False, output: Path | None = None) -> dict:
    start = time.perf_counter()
    rng = np.random.default_rng(SEED)
    n = 10 if quick else N_SHAPES
    centres = np.column_stack([rng.uniform(0.0, 70.0, n), rng.uniform(20.0, 220.0, n)])
    angles = rng.uniform(-0.5 * np.pi, 0.5 * np.pi, n)
    reference_h = 0.25 if quick else 0.125
    reference = example_scene("random.toml", (f"domain.h={reference_h}",))
    scenes = {name: example_scene(*spec) for name, spec in DOMAINS.items()}
    rows = []
    for aspect in ASPECTS:
        exact = shape_observables(ellipses(reference, centres, angles, aspect)).elongation
        row = {"aspect": aspect, "reference_mean": float(exact.mean())}
        for name, scene in scenes.items():
            error = shape_observables(ellipses(scene, centres, angles, aspect)).elongation - exact
            row[name] = {"mean": float(error.mean()), "sd": float(error.std(ddof=1))}
        rows.append(row)
    oriented = []
    for aspect in ORIENTED_ASPECTS:
        for angle in ORIENTATIONS:
            same = np.full(n, angle)
            exact = shape_observables(ellipses(reference, centres, same, aspect)).elongation
            row = {"aspect": aspect, "orientation": angle, "reference_mean": float(exact.mean())}
            for name, scene in scenes.items():
                error = shape_observables(ellipses(scene, centres, same, aspect)).elongation - exact
                row[name] = float(error.mean())
            oriented.append(row)
    results = {"quick": quick, "reference_h": reference_h, "n_shapes": n, "domains": list(DOMAINS),
               "rows": rows, "by_orientation": oriented}
    return save_results("shape_bias", results, plot, start, output)


def plot(results: dict, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(5.5, 4))
    reference = [row["reference_mean"] for row in results["rows"]]
    for name in results["domains"]:
        mean = np.array([row[name]["mean"] for row in results["rows"]])
        sd = np.array([row[name]["sd"] for row in results["rows"]])
        ax.errorbar(reference, mean, yerr=sd, marker="o", capsize=3, label=name)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel(f"r read at h = {results['reference_h']:g} (mean over the shapes)")
    ax.set_ylabel("r read − reference (mean ± s.d.)")
    ax.legend(fontsize=8)
    save_figure(fig, path)


if __name__ == "__main__":
    command_line("shape_bias", run, ("rows",))
