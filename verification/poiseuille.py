"""The supplement's Poiseuille result, and the structured against the unstructured channel.

    python verification/poiseuille.py            # runs what is not cached, then plots

1. Ψ6 and Ψ2^L against the maximum velocity U of the Poiseuille flow u = 4U y(Ly − y)/Ly²
   (the supplement's Fig. SM3), with the paper's N = 100, R = 8 suspension in the 70 × 240
   channel, from random discs of radius R/2. **Shortened protocol** (the paper: relax 2000,
   flow 10^5 time units, average over the last 50 of 250 frames, 3 samples): relax 300, flow
   1000 time units at dt = 1, frames every 25, average over the last 20 frames (the last 500
   time units), 2 samples. Run on the structured grid (fast); the unstructured channel with
   its Stokes flow adds the point at U = 0.3 (sample 1).
2. The same scene (sample 1, U = 0.3, the same protocol) on the structured grid at h = 1, on
   the unstructured straight channel ``meshes/straight_unstructured.vtu`` (one node per unit
   area, as the grid) driven by its own Stokes flow (max_velocity = U), and on the grid at
   h = 0.5. The suspension is chaotic: after a few T1 events two discretisations follow
   different trajectories, so the agreement is judged (a) on the frame series before that
   (relaxation and early flow) and (b) on the time-averaged order parameters, each against the
   discretisation error of the h = 1 grid, estimated by its difference to h = 0.5.

Writes verification/results/poiseuille.json (every series, averages, timings), caches each
run in verification/results/poiseuille_runs.json, and plots verification/results/poiseuille.png.
Timings are ms per step measured in this process (machine shared, so compare ratios).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from femphase.analysis.shape import shape_observables  # noqa: E402
from femphase.domains.grid.domain import GridDomain  # noqa: E402
from femphase.flows import flow_from_spec, poiseuille  # noqa: E402
from femphase.domains.grid.lattice import channel_grid  # noqa: E402
from femphase.domains.mesh.domain import MeshDomain  # noqa: E402
from femphase.model.parameters import ModelParameters  # noqa: E402
from femphase.analysis.observables import Order  # noqa: E402
from femphase.placement import random_centres  # noqa: E402
from femphase.state import discs_state  # noqa: E402
from femphase.config import Numerics  # noqa: E402
from femphase.timestepping.stepper import Stepper

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "verification" / "results"
MESH = REPO / "meshes" / "straight_unstructured.vtu"
LX, LY, N, R = 70.0, 240.0, 100, 8.0
DT, FRAME = 1.0, 25.0
RELAX, FLOW, AVERAGED = 300.0, 1000.0, 20
VELOCITIES = (0.01, 0.1, 0.3, 1.0)
SAMPLES = (1, 2)
COMPARED_VELOCITY = 0.3
PARAMS, NUMERICS = ModelParameters(), Numerics(scheme="euler")  # as the stored results


class Run:
    """Discs of radius R/2 at ``centres`` on a domain, stepped by the one stepper of both kinds."""

    def __init__(self, domain, centres: np.ndarray) -> None:
        self.domain = domain
        self.state = discs_state(domain, centres, np.full(N, R), np.full(N, R / 2), PARAMS.interface_width,
                                 domain.window_policy(NUMERICS))

    def flow(self, velocity: float):
        raise NotImplementedError

    def stepper(self, velocity: float | None) -> Stepper:
        return Stepper(self.domain, PARAMS, NUMERICS, DT, self.flow(velocity) if velocity else None, self.state.radii)

    def shape(self):
        return shape_observables(self.state)


class GridRun(Run):
    """The structured channel at spacing h, in the Poiseuille flow u = 4U y(Ly − y)/Ly²."""

    def __init__(self, h: float, centres: np.ndarray) -> None:
        super().__init__(GridDomain(channel_grid(LX, LY, h)), centres)

    def flow(self, velocity: float):
        return poiseuille(velocity, LY)


class MeshRun(Run):
    """The meshed straight channel, driven by its own Stokes flow (the unit solution cached
    next to the mesh as ``<mesh>.stokes.npz``, as for a scene)."""

    def __init__(self, centres: np.ndarray) -> None:
        super().__init__(MeshDomain.from_table({"kind": "mesh", "mesh": MESH.name}, MESH.parent, NUMERICS), centres)

    def flow(self, velocity: float):
        return flow_from_spec({"type": "stokes", "max_velocity": velocity}, self.domain)


def simulate(run, velocity: float) -> dict:
    """Relax, then flow; the frame series of Ψ6, Ψ2, mean elongation and area, and ms/step."""
    # the "order" observable of a run's frames (it reads only the simulation's domain)
    observer = Order(SimpleNamespace(domain=run.domain))
    series = {key: [] for key in ("time", "Psi6", "Psi2", "elongation", "area")}

    def frame():
        shape = run.shape()
        order = observer(run.state, {"x": shape.x, "y": shape.y, "orientation": shape.orientation})
        for key, value in (("time", run.state.time), ("Psi6", order["Psi6"]), ("Psi2", order["Psi2"]),
                           ("elongation", float(np.mean(shape.elongation))), ("area", float(np.mean(shape.area)))):
            series[key].append(float(value))

    frame()
    timings = []
    for velocity_now, duration in ((None, RELAX), (velocity, FLOW)):
        stepper = run.stepper(velocity_now)
        for k in range(round(duration / DT)):
            start = time.perf_counter()
            stepper.step(run.state)
            timings.append(time.perf_counter() - start)
            if (k + 1) % round(FRAME / DT) == 0:
                frame()
    series["ms_per_step_flow"] = 1e3 * float(np.median(timings[round(RELAX / DT):]))
    return series


def cached(cache: dict, key: str, compute) -> dict:
    if key not in cache:
        print(f"running {key} ...", flush=True)
        start = time.perf_counter()
        cache[key] = compute()
        cache[key]["wall_s"] = time.perf_counter() - start
        (RESULTS / "poiseuille_runs.json").write_text(json.dumps(cache))
    return cache[key]


def averages(series: dict) -> dict:
    return {key: (float(np.mean(series[key][-AVERAGED:])), float(np.std(series[key][-AVERAGED:])))
            for key in ("Psi6", "Psi2")}


def main() -> None:
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / "poiseuille_runs.json"
    cache = json.loads(path.read_text()) if path.exists() else {}
    centres = {seed: random_centres(N, LX, LY, R / 2, seed) for seed in SAMPLES}

    sweep = {}
    for velocity in VELOCITIES:
        for seed in SAMPLES:
            run = cached(cache, f"grid_h1_U{velocity}_s{seed}",
                         lambda: simulate(GridRun(1.0, centres[seed]), velocity))
            sweep.setdefault(str(velocity), []).append(averages(run))
    compared = {
        "grid_h1": cache[f"grid_h1_U{COMPARED_VELOCITY}_s1"],
        "grid_h0.5": cached(cache, "grid_h0.5_U0.3_s1", lambda: simulate(GridRun(0.5, centres[1]), COMPARED_VELOCITY)),
        "mesh": cached(cache, "mesh_U0.3_s1", lambda: simulate(MeshRun(centres[1]), COMPARED_VELOCITY)),
    }
    mesh_point = averages(compared["mesh"])
    reference = compared["grid_h1"]
    relax_frames = round(RELAX / FRAME) + 1
    early = slice(relax_frames, relax_frames + 4)  # the first 100 time units of flow
    agreement = {}
    for name in ("mesh", "grid_h0.5"):
        run = compared[name]
        agreement[name] = {}
        for key in ("Psi6", "Psi2", "elongation", "area"):
            diff = np.subtract(run[key], reference[key])
            agreement[name][key] = {
                "max_diff_relax": float(np.max(np.abs(diff[:relax_frames]))),
                "max_diff_early_flow": float(np.max(np.abs(diff[early]))),
                "diff_of_late_means": float(np.mean(diff[-AVERAGED:])),
                "late_frame_std_grid_h1": float(np.std(reference[key][-AVERAGED:])),
            }

    summary = {
        "protocol": {"relax": RELAX, "flow": FLOW, "dt": DT, "frame_interval": FRAME,
                     "averaged_frames": AVERAGED, "samples": list(SAMPLES), "N": N, "R": R,
                     "note": "shortened protocol; the paper: relax 2000, flow 1e5, last 50 of 250 frames, 3 samples"},
        "sweep_grid": {
            velocity: {key: {"mean": float(np.mean([s[key][0] for s in samples])),
                             "sample_std": float(np.std([s[key][0] for s in samples])),
                             "frame_std": float(np.mean([s[key][1] for s in samples]))}
                       for key in ("Psi6", "Psi2")}
            for velocity, samples in sweep.items()
        },
        "mesh_point": {"velocity": COMPARED_VELOCITY, **{k: {"mean": v[0], "frame_std": v[1]} for k, v in mesh_point.items()}},
        "comparison": {"velocity": COMPARED_VELOCITY, "agreement": agreement,
                       "ms_per_step_flow": {name: run["ms_per_step_flow"] for name, run in compared.items()}},
    }
    (RESULTS / "poiseuille.json").write_text(json.dumps(summary, indent=2) + "\n")
    plot(summary, compared)
    print(json.dumps({k: summary[k] for k in ("sweep_grid", "mesh_point", "comparison")}, indent=1))


def plot(summary: dict, compared: dict) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    velocities = [float(v) for v in summary["sweep_grid"]]
    for key, colour in (("Psi6", "C0"), ("Psi2", "C3")):
        mean = np.array([summary["sweep_grid"][v][key]["mean"] for v in summary["sweep_grid"]])
        spread = np.array([summary["sweep_grid"][v][key]["sample_std"] for v in summary["sweep_grid"]])
        label = {"Psi6": "Ψ6", "Psi2": "Ψ2^L"}[key]
        axes[0].plot(velocities, mean, "o-", color=colour, label=f"{label}, grid h = 1")
        axes[0].fill_between(velocities, mean - spread, mean + spread, color=colour, alpha=0.2)
        point = summary["mesh_point"]
        axes[0].errorbar([point["velocity"]], [point[key]["mean"]], [point[key]["frame_std"]], fmt="s",
                         color=colour, mfc="none", ms=9, label=f"{label}, unstructured mesh + Stokes")
    axes[0].set(xscale="log", xlabel="maximum velocity U", ylabel="order parameter",
                title="Poiseuille flow (shortened protocol)")
    axes[0].legend(fontsize=7)
    styles = {"grid_h1": ("k-", "grid h = 1"), "grid_h0.5": ("C2--", "grid h = 0.5"), "mesh": ("C1-", "unstructured mesh")}
    for ax, key in zip(axes[1:], ("Psi6", "elongation")):
        for name, run in compared.items():
            style, label = styles[name]
            ax.plot(run["time"], run[key], style, label=label, lw=1)
        ax.axvline(RELAX, color="gray", lw=0.5)
        ax.set(xlabel="time", ylabel={"Psi6": "Ψ6", "elongation": "mean elongation"}[key],
               title=f"same scene, U = {COMPARED_VELOCITY}")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / "poiseuille.png", dpi=120)


if __name__ == "__main__":
    import argparse

    # no options: an argument parser so that --help describes the run instead of starting it
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    main()
