"""The same particles in Poiseuille flow on the structured channel and on an unstructured mesh.

    python verification/mesh_vs_grid.py            # h = 2, 1, 0.5, 0.25 and the advections
    python verification/mesh_vs_grid.py --quick    # h = 1, 0.5
    python verification/mesh_vs_grid.py --tolerance-t 0.001   # the same at that tolerance (no advection study)

A lone particle and a pair (R = 8, relaxed from discs of R, no relaxation phase) in the
Poiseuille flow u = 4U y(Ly − y)/Ly², U = 0.5, of a 48 × 64 channel for 2000 time units,
at the default scheme and dt = 10: on the structured channel (``domain.h = h``, the exact
parabola) and on a Delaunay mesh of the same channel with edge length for spacing h
(:func:`femphase.domains.mesh.generation.delaunay_channel`) in its own P2 Stokes flow of
centre-line velocity U (which represents the parabola exactly). Observables at t = 2000:
the lone particle's lateral position y and elongation r (migration and deformation), the
pair's centroid separation d. (h = 2 = λ runs with a ResolutionWarning.) Each path's
h-error is estimated by its change from h to h/2;
the two paths agree when |mesh − grid| at h is within those h-errors, and converge
together when that difference falls as h halves.

Which part of the mesh's difference at h = 1 is its advection's: the lone particle on the
mesh at h = 1 with the default explicit advection (Taylor–Galerkin) and the Runge–Kutta
step, each with its lumped inverse corrected twice and made exact (16 corrections), and with
the Galerkin–Padé step, each at dt = 10 and 2.5 (not with --quick).

Writes verification/results/mesh_vs_grid.json and .png and rewrites the
``mesh_vs_grid`` block of verification/README.md; with ``--tolerance-t T``,
mesh_vs_grid_tolerance_T.json and .png only (no advection study, no README block).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from femphase.domains.mesh import advection  # noqa: E402
from femphase.domains.mesh.domain import write_domain  # noqa: E402
from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing  # noqa: E402
from femphase.io.reader import open_run  # noqa: E402
from femphase.run.runner import run_scene  # noqa: E402
from femphase.scene import scene_from_dict  # noqa: E402
from verification.readme import write_block  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "verification" / "results"
LX, LY, U, DURATION, DT = 48.0, 64.0, 0.5, 2000.0, 10.0
CASES = {"single": [[24.0, 22.0]], "pair": [[16.0, 24.0], [32.0, 38.0]]}


def scene(case: str, kind: str, h: float, mesh_file: Path | None, dt: float = DT, numerics: dict | None = None) -> dict:
    domain = ({"Lx": LX, "Ly": LY, "h": h} if kind == "grid"
              else {"kind": "mesh", "mesh": str(mesh_file), "h": h})
    flow = ({"type": "poiseuille", "rate": U} if kind == "grid" else {"type": "stokes", "max_velocity": U})
    return {"name": f"{case} {kind} h={h:g}", "domain": domain,
            "particles": {"layout": "list", "centres": CASES[case]},
            "output": {"fields": False}, "numerics": numerics or {},
            "phases": [{"name": "flow", "duration": DURATION, "dt": dt, "frame_interval": 100.0, "flow": flow}]}


def observables(directory: Path, case: str) -> dict:
    run = open_run(directory)
    x, y, r = run.x[-1], run.y[-1], run.elongation[-1]
    if case == "single":
        return {"y": float(y[0]), "elongation": float(r[0])}
    dx = (x[1] - x[0] + LX / 2) % LX - LX / 2
    return {"separation": float(np.hypot(dx, y[1] - y[0]))}


def channel_mesh(h: float):
    """A Delaunay mesh of the channel with the edge length of spacing h."""
    wall = lambda height: (lambda x: 0 * x + height)  # noqa: E731
    return delaunay_channel(LX, edge_for_spacing(h), wall(0.0), wall(LY), seed=1)


def run_case(case: str, kind: str, h: float, scratch: Path, dt: float = DT, numerics: dict | None = None) -> dict:
    mesh_file = None
    if kind == "mesh":
        mesh_file = scratch / f"channel_{h:g}.vtu"
        if not mesh_file.exists():
            write_domain(mesh_file, *channel_mesh(h))
    directory = scratch / f"{case}_{kind}_{h:g}"
    started = time.process_time()
    run_scene(scene_from_dict(scene(case, kind, h, mesh_file, dt, numerics), scratch), directory, progress=False,
              overwrite=True)
    return {"case": case, "kind": kind, "h": h, "cpu_s": time.process_time() - started, **observables(directory, case)}


#: The mesh's advection at h = 1 (the lone particle): the two explicit steps, each with its
#: lumped inverse corrected twice and made exact, and the Galerkin–Padé step, each at dt = 10 and 2.5
ADVECTIONS = {"Taylor–Galerkin, K = 2 (default)": (None, {}), "Taylor–Galerkin, K = 16 (B⁻¹ exact)": (16, {}),
              "Runge–Kutta, K = 2": (None, {"mesh_advection": "runge-kutta"}),
              "Runge–Kutta, K = 16 (M⁻¹ exact)": (16, {"mesh_advection": "runge-kutta"}),
              "Galerkin–Padé": (None, {"solver": "direct"})}


def advection_study(scratch: Path) -> list[dict]:
    """The lone particle on the mesh at h = 1 under each of :data:`ADVECTIONS` at dt = 10 and
    2.5: which part of the mesh's difference from the grid is its advection's."""
    rows = []
    for name, (corrections, numerics) in ADVECTIONS.items():
        default = advection.MASS_CORRECTIONS
        try:
            if corrections is not None:
                advection.MASS_CORRECTIONS = corrections
            for dt in (DT, DT / 4):
                rows.append({"advection": name, "dt": dt, **run_case("single", "mesh", 1.0, scratch, dt, numerics)})
                print(json.dumps(rows[-1]), flush=True)
        finally:
            advection.MASS_CORRECTIONS = default
    return rows


def summarise(runs: list[dict], spacings: list[float]) -> list[dict]:
    """Per case, observable and h: grid, mesh, |mesh − grid| and each path's change to h/2."""
    rows = []
    for case in CASES:
        keys = ["y", "elongation"] if case == "single" else ["separation"]
        value = {(r["kind"], r["h"]): r for r in runs if r["case"] == case}
        for key in keys:
            for k, h in enumerate(spacings):
                grid, mesh = value[("grid", h)][key], value[("mesh", h)][key]
                finer = spacings[k + 1] if k + 1 < len(spacings) else None
                rows.append({"case": case, "observable": key, "h": h, "grid": grid, "mesh": mesh,
                             "difference": abs(mesh - grid),
                             "grid_change": None if finer is None else abs(value[("grid", finer)][key] - grid),
                             "mesh_change": None if finer is None else abs(value[("mesh", finer)][key] - mesh)})
    return rows


def markdown(rows: list[dict], command: str) -> str:
    def cell(v):
        return "—" if v is None else f"{v:.4g}"
    lines = [f"`{command}`", "",
             "| case | observable | h | grid | mesh | \\|mesh − grid\\| | grid: change to h/2 | mesh: change to h/2 |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['case']} | {r['observable']} | {r['h']:g} | {cell(r['grid'])} | {cell(r['mesh'])} | "
              f"{cell(r['difference'])} | {cell(r['grid_change'])} | {cell(r['mesh_change'])} |" for r in rows]
    return "\n".join(lines)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = sorted({(r["case"], r["observable"]) for r in rows})
    fig, axes = plt.subplots(1, len(pairs), figsize=(4 * len(pairs), 3.2))
    for ax, (case, key) in zip(np.atleast_1d(axes), pairs):
        mine = [r for r in rows if r["case"] == case and r["observable"] == key]
        h = [r["h"] for r in mine]
        ax.plot(h, [r["grid"] for r in mine], "o-", label="structured channel")
        ax.plot(h, [r["mesh"] for r in mine], "s--", label="unstructured mesh")
        ax.set_xscale("log", base=2)
        ax.set_xlabel("h")
        ax.set_title(f"{case}: {key} at t = {DURATION:g}")
    np.atleast_1d(axes)[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="h = 1 and 0.5 only")
    parser.add_argument("--output", type=Path, default=RESULTS)
    parser.add_argument("--tolerance-t", type=float, default=None,
                        help="numerics.tolerance_t of every run (default: the scene's default, 0.1); the README "
                             "block is written only at the default")
    args = parser.parse_args()
    numerics = {} if args.tolerance_t is None else {"tolerance_t": args.tolerance_t}
    spacings = [1.0, 0.5] if args.quick else [2.0, 1.0, 0.5, 0.25]
    runs = []
    with tempfile.TemporaryDirectory() as scratch:
        for h in spacings:
            for case in CASES:
                for kind in ("grid", "mesh"):
                    runs.append(run_case(case, kind, h, Path(scratch), numerics=numerics))
                    print(json.dumps(runs[-1]), flush=True)
        advections = [] if args.quick or numerics else advection_study(Path(scratch))
    rows = summarise(runs, spacings)
    command = ("python verification/mesh_vs_grid.py" + (" --quick" if args.quick else "")
               + (f" --tolerance-t {args.tolerance_t:g}" if numerics else ""))
    args.output.mkdir(parents=True, exist_ok=True)
    stem = "mesh_vs_grid" + (f"_tolerance_{args.tolerance_t:g}" if numerics else "")
    (args.output / f"{stem}.json").write_text(json.dumps(
        {"command": command, "runs": runs, "rows": rows, "advections": advections}, indent=1))
    plot(rows, args.output / f"{stem}.png")
    block = markdown(rows, command)
    if advections:
        block += ("\n\nThe lone particle on the mesh at h = 1 by advection and dt:\n\n| advection | dt | y | r |\n"
                  "|---|---|---|---|\n" + "\n".join(f"| {r['advection']} | {r['dt']:g} | {r['y']:.3f} | "
                                                    f"{r['elongation']:.3f} |" for r in advections))
    print(block)
    if args.output == RESULTS and not numerics:
        write_block("mesh_vs_grid", block + "\n\n![mesh against grid](results/mesh_vs_grid.png)",
                    "The structured channel and an unstructured mesh in Poiseuille flow")


if __name__ == "__main__":
    main()
