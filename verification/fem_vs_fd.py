"""The finite-element solver against the paper's finite-difference scheme, as h shrinks.

Scenes (paper parameters λ = 2, γ = 0.06, κ = 0.5, μ = 20, J0 = 0.5, R = 8):

  relax    an isolated particle relaxing from a disc of radius R/2 (40 × 40 box)
  pair     two discs of radius R with centres 1.5 R apart, pushing each other apart (48 × 40)
  shear    an isolated disc of radius R in shear u = γ̇ y/Ly, γ̇ = 0.4 (48 × 40: ∂u/∂y = 0.01)
  lattice  the paper's N = 100 hexagonal lattice in 70 × 240, relaxed 300 time units
           without flow, then sheared at γ̇ = 0.1487 (u = γ̇ y/Ly) for 3600: the first T1
           peak of r(t) comes ~1100 after the onset, the next one a period (≈ 1880) later,
           so the window holds one full oscillation period and its onset transient.

Both methods run every scene at h ∈ {2, 1, 0.5} with the same time step
dt = 0.1 h² (0.4, 0.1, 0.025): the explicit FD scheme needs dt ∝ h² on fine grids anyway,
and the FEM stepper (Lie splitting + linearly implicit Euler) is first order in dt, so
dt ∝ h² keeps its time error ∝ h², like its spatial error. FEM runs with the lumped mass.
The lattice keeps dt ≥ 0.1 (0.4, 0.1, 0.1: dt = 0.025 at h = 0.5 would take hours here, and
the FD scheme is stable to dt = 0.17 there), so its FEM–FD difference tends to FEM's O(dt)
time error at dt = 0.1 rather than to zero. A finer FEM run (h = 0.25, dt = 0.1 h²;
lattice: h = 0.5, dt = 0.1, which is then also its FEM point at h = 0.5, for cost) is the
reference both methods are measured against.

Differences, each the largest over the frames (every 4 time units; lattice: every 50):

  field      (Σ_i Σ_k m_k (φ_ik − ψ_ik)²)^½ on the coarser grid (lumped-mass quadrature;
             the reference is injected at the coarse nodes, the grids are nested)
  area       max_i |ΔA_i| / (πR²)
  elongation max_i |Δr_i|
  centroid   max_i |Δx_i| (distance, minimum image in x)

The observed ``order`` of a scene is that of the field difference FEM–FD between the two
finest spacings, log(e₁/e₂)/log(h₁/h₂) (the convention of verification/README.md; a coarse
level outside the asymptotic range, like the lattice at h = λ, does not bend it);
``order_fit`` is the least-squares slope over all spacings, and ``orders`` lists the fitted
orders of every difference (None where a difference is round-off, e.g. the elongation of a
centred disc). The per-frame FEM–FD field and centroid differences are kept. The ``diagnostics`` show what the FEM–FD difference is made
of: for 'relax' and 'shear', its dependence on dt at h = 1 (dt = 0.1, 0.05, 0.025) and on
h at fixed dt = 0.025; for 'small_lattice' (8 particles at the lattice's spacing in
28 × 48, sheared at γ̇ = 0.3), both methods' centroid error against FEM at h = 0.5.

Writes verification/results/fem_vs_fd.json and fem_vs_fd.png. Run from the repository root:

    python verification/fem_vs_fd.py [--quick] [--jobs 2] [--cache DIR]

``--quick`` (smaller and shorter scenes, h ∈ {2, 1}, reference h = 0.5; well under a
minute) prints the summary and writes nothing unless ``--output DIR`` is given;
``run(quick)`` returns the same dictionary for a pytest check.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import time as wallclock
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

# the script lives outside the package; make `femphase` importable from a checkout
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from femphase.analysis.periods import first_period  # noqa: E402
from femphase.scene import scene_from_dict  # noqa: E402
from femphase.run.trackers import FrameRecorder  # noqa: E402
from femphase.run.simulation import Simulation
from femphase.domains.grid.windows import pad_window  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
RADIUS = 8.0
DT_PER_H2 = 0.1
#: the lattice's step never falls below this: FD at h = 0.5 is stable up to dt = 0.17, and
#: dt = 0.1 h² there would cost 156 000 steps of 100 windows (hours on this machine)
LATTICE_DT_FLOOR = 0.1


def time_step(name: str, h: float) -> float:
    """dt of both methods for scene ``name`` at spacing h: 0.1 h² (lattice: at least 0.1)."""
    dt = DT_PER_H2 * h * h
    return max(dt, LATTICE_DT_FLOOR) if name == "lattice" else dt
METRICS = ("field", "area", "elongation", "centroid")


def _phase(duration: float, dt: float, frame: float, flow: dict | None = None) -> dict:
    phase = {"name": "run", "duration": duration, "dt": dt, "frame_interval": frame}
    if flow is not None:
        phase["flow"] = flow
    return phase


def scene_dict(name: str, h: float, dt: float, quick: bool) -> dict:
    """The scene ``name`` at spacing h and step dt (see the module docstring)."""
    duration, frame = (20.0, 4.0) if quick else (100.0, 4.0)
    output = {"fields": False, "checkpoint": False}
    if name == "relax":
        size = (32.0, 32.0) if quick else (40.0, 40.0)
        return {"name": name, "domain": {"Lx": size[0], "Ly": size[1], "h": h}, "output": output,
                "particles": {"layout": "single"}, "phases": [_phase(duration, dt, frame)]}
    if name == "pair":
        return {"name": name, "domain": {"Lx": 48.0, "Ly": 40.0, "h": h}, "output": output,
                "particles": {"layout": "list", "centres": [[18.0, 20.0], [30.0, 20.0]], "initial_radius": RADIUS},
                "phases": [_phase(duration, dt, frame)]}
    if name == "shear":
        return {"name": name, "domain": {"Lx": 48.0, "Ly": 40.0, "h": h}, "output": output,
                "particles": {"layout": "single", "initial_radius": RADIUS},
                "phases": [_phase(duration, dt, frame, {"type": "shear", "rate": 0.4})]}
    if name == "small_lattice":  # 8 particles at the lattice's spacing, fast shear (diagnostic)
        return {"name": name, "domain": {"Lx": 28.0, "Ly": 48.0, "h": h}, "output": output,
                "particles": {"layout": "hexagonal", "N": 8, "per_row": 2},
                "phases": [_phase(100.0, dt, 50.0),
                           {**_phase(100.0, dt, 50.0, {"type": "shear", "rate": 0.3}), "name": "shear"}]}
    if name == "lattice":
        if quick:  # six particles in a small periodic box, 20 + 20 time units
            domain, particles, times = {"Lx": 36.0, "Ly": 48.0}, {"layout": "hexagonal", "N": 6, "per_row": 2}, (20.0, 20.0, 4.0)
        else:
            domain, particles, times = {"Lx": 70.0, "Ly": 240.0}, {"layout": "hexagonal", "N": 100}, (300.0, 3600.0, 50.0)
        relax, shear, frame = times
        return {"name": name, "domain": {**domain, "h": h}, "output": output, "particles": particles,
                "phases": [_phase(relax, dt, frame),
                           {**_phase(shear, dt, frame, {"type": "shear", "rate": 0.1487}), "name": "shear"}]}
    raise ValueError(f"unknown scene {name!r}")


def simulate(job: tuple, cache: Path | None = None) -> dict:
    """Run one scene with one method; returns the frames' states and observables. With a
    ``cache`` directory, a run done before is read back instead (pickle per job)."""
    path = cache / ("_".join(map(str, job)) + ".pickle") if cache is not None else None
    if path is not None and path.exists():
        return pickle.loads(path.read_bytes())
    result = _simulate(job)
    if path is not None:
        path.write_bytes(pickle.dumps(result))
    return result


def _simulate(job: tuple) -> dict:
    name, method, h, dt, quick = job
    # FEM with the first-order scheme: the comparison is at equal dt, and the stored results used it
    scene = scene_from_dict({**scene_dict(name, h, dt, quick), "numerics": {"scheme": "euler"}})
    recorder = FrameRecorder()
    started = wallclock.perf_counter()
    Simulation(scene, method).run(scene.initial_state(), [recorder])
    seconds = wallclock.perf_counter() - started
    grid = scene.domain.grid
    return {
        "job": job,
        "seconds": seconds,
        "grid": (grid.nx, grid.ny, grid.h),
        "times": recorder.times,
        "states": [f.state for f in recorder.frames],
        "area": recorder.series("area"),
        "elongation": recorder.series("elongation"),
        "x": recorder.series("x"),
        "y": recorder.series("y"),
    }


def _nodal(state, stride: int) -> np.ndarray:
    """All fields of a state (N, ny, nx) at every ``stride``-th node row and column."""
    grid = state.domain.grid
    return state.global_fields().reshape(-1, grid.ny, grid.nx)[:, ::stride, ::stride]


def frame_differences(a: dict, b: dict) -> dict[str, np.ndarray]:
    """Per-frame differences (see the module docstring) between run a and a run b on the
    same or a finer nested grid (b's fields injected at a's nodes)."""
    nx, ny, h = a["grid"]
    ratio = round(h / b["grid"][2])
    length = nx * h
    if not np.allclose(a["times"], b["times"]):
        raise RuntimeError("the runs' frame times differ")
    mass = np.full((ny, nx), h * h)
    mass[[0, -1]] *= 0.5  # the lumped mass of the structured mesh: half cells on the walls
    field = [np.sqrt(np.sum(mass * (_nodal(sa, 1) - _nodal(sb, ratio)) ** 2))
             for sa, sb in zip(a["states"], b["states"])]
    dx = (a["x"] - b["x"] + 0.5 * length) % length - 0.5 * length
    return {
        "field": np.array(field),
        "area": np.max(np.abs(a["area"] - b["area"]), axis=1) / (np.pi * RADIUS**2),
        "elongation": np.max(np.abs(a["elongation"] - b["elongation"]), axis=1),
        "centroid": np.max(np.hypot(dx, a["y"] - b["y"]), axis=1),
    }


def differences(a: dict, b: dict) -> dict[str, float]:
    """The largest of :func:`frame_differences` over the frames."""
    return {name: float(values.max()) for name, values in frame_differences(a, b).items()}


#: Differences below this are round-off (e.g. the centroid of a centred disc): no order.
ROUNDOFF = 1e-9


def fitted_order(hs: list[float], values: list[float]) -> float | None:
    """Least-squares slope of log(values) against log(hs); None without two values above
    round-off."""
    points = [(h, v) for h, v in zip(hs, values) if v is not None and v > ROUNDOFF]
    if len(points) < 2:
        return None
    x, y = np.log([p[0] for p in points]), np.log([p[1] for p in points])
    return float(np.polyfit(x, y, 1)[0])


def set_headline_order(scene: dict) -> None:
    """``order`` (the two finest spacings) and ``order_fit`` (all) of a scene's FEM–FD field
    difference."""
    hs, values = scene["h"], scene["fem_vs_fd"]["field"]
    scene["order"] = fitted_order(hs[-2:], values[-2:])
    scene["order_fit"] = fitted_order(hs, values)


def plan(quick: bool) -> dict:
    """Scenes → (spacings, reference spacing, reference dt)."""
    if quick:
        return {name: ((2.0, 1.0), 0.5, DT_PER_H2 * 0.25) for name in ("relax", "pair", "shear", "lattice")}
    fine = {name: ((2.0, 1.0, 0.5), 0.25, DT_PER_H2 * 0.0625) for name in ("relax", "pair", "shear")}
    return {**fine, "lattice": ((2.0, 1.0, 0.5), 0.5, 0.1)}


def diagnostic_jobs(quick: bool) -> list[tuple]:
    """FEM and FD of 'relax' and 'shear' at h = 1 with dt/2, dt/4, and at h = 2 with
    dt = 0.025; of 'small_lattice' at h = 1 and 0.5 with dt = 0.1."""
    if quick:
        return []
    jobs = []
    for method in ("fem", "fd"):
        for name in ("relax", "shear"):
            jobs += [(name, method, 1.0, 0.05, False), (name, method, 1.0, 0.025, False),
                     (name, method, 2.0, 0.025, False)]
        jobs += [("small_lattice", method, h, 0.1, False) for h in (1.0, 0.5)]
    return jobs


class _Serial:
    """map() in this process, with the executor's context-manager interface."""

    map = staticmethod(map)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def run(quick: bool = False, jobs: int = 1, cache: Path | None = None,
        only: list[str] | None = None) -> dict:
    """The comparisons; returns the dictionary written to fem_vs_fd.json. ``jobs``: runs in
    parallel processes; ``cache``: directory keeping every run (see :func:`simulate`);
    ``only``: these scenes and no diagnostics (default: every scene and the diagnostics)."""
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
    started = wallclock.perf_counter()
    scenes = plan(quick)
    if only is not None:
        unknown = sorted(set(only) - set(scenes))
        if unknown:
            raise ValueError(f"unknown scenes {unknown}; valid: {sorted(scenes)}")
        scenes = {name: scenes[name] for name in only}
    work = []
    for name, (hs, h_ref, dt_ref) in scenes.items():
        work.append((name, "fem", h_ref, dt_ref, quick))
        for h in hs:
            work += [(name, method, h, time_step(name, h), quick) for method in ("fem", "fd")]
    work = list(dict.fromkeys(work))  # the lattice's FEM at h = 0.5 is its reference
    work += diagnostic_jobs(quick) if only is None else []
    # longest first, so that two workers finish together
    work.sort(key=lambda job: -(1.0 / job[3]) * (1.0 / job[2]) ** 2 * (20 if job[0] == "lattice" else 1))
    runs = {}
    with ProcessPoolExecutor(jobs) if jobs > 1 else _Serial() as pool:
        for done in pool.map(partial(simulate, cache=cache), work):
            runs[done["job"]] = done
            print(f"  {len(runs)}/{len(work)} {done['job'][:4]}: {done['seconds']:.0f} s", file=sys.stderr, flush=True)
    out = {
        "description": "FEM (lumped mass) against the finite-difference scheme (5-point Laplacian, "
                       "third-order upwind advection, Heun) on the same grid; both against a finer FEM run",
        "quick": quick,
        "dt_rule": f"dt = {DT_PER_H2} h^2 for both methods (same dt for FEM and FD); lattice: at least "
                   f"{LATTICE_DT_FLOOR}",
        "metrics": {"field": "max over frames of the L2 norm (lumped-mass quadrature) of the field difference, "
                             "all particles together",
                    "area": "max over frames and particles of |dA|/(pi R^2)",
                    "elongation": "max over frames and particles of |dr|",
                    "centroid": "max over frames and particles of the centroid distance"},
        "scenes": {},
    }
    for name, (hs, h_ref, dt_ref) in scenes.items():
        reference = runs[(name, "fem", h_ref, dt_ref, quick)]
        scene = {"h": list(hs), "dt": [time_step(name, h) for h in hs],
                 "reference": {"method": "fem", "h": h_ref, "dt": dt_ref},
                 "fem_vs_fd": {m: [] for m in METRICS}, "fem_vs_reference": {m: [] for m in METRICS},
                 "fd_vs_reference": {m: [] for m in METRICS}, "seconds": {"reference": reference["seconds"]},
                 "fem_vs_fd_per_frame": {"time": reference["times"].tolist(), "field": [], "centroid": []}}
        for h in hs:
            fem = runs[(name, "fem", h, time_step(name, h), quick)]
            fd = runs[(name, "fd", h, time_step(name, h), quick)]
            per_frame = frame_differences(fem, fd)
            for metric in ("field", "centroid"):
                scene["fem_vs_fd_per_frame"][metric].append(per_frame[metric].tolist())
            for key, (a, b) in {"fem_vs_fd": (fem, fd), "fem_vs_reference": (fem, reference),
                                "fd_vs_reference": (fd, reference)}.items():
                for metric, value in differences(a, b).items():
                    scene[key][metric].append(value)
            scene["seconds"][f"h={h:g}"] = {"fem": fem["seconds"], "fd": fd["seconds"]}
        scene["orders"] = {key: {m: fitted_order(hs, scene[key][m]) for m in METRICS}
                           for key in ("fem_vs_fd", "fem_vs_reference", "fd_vs_reference")}
        set_headline_order(scene)
        if name == "lattice":
            scene["shear_start"] = scene_dict(name, hs[0], DT_PER_H2, quick)["phases"][0]["duration"]
            scene["periods"] = lattice_periods(scene["shear_start"], reference, {
                (method, h): runs[(name, method, h, time_step(name, h), quick)] for h in hs for method in ("fem", "fd")})
        if name == "lattice" and not quick:
            scene["note"] = ("300 time units of relaxation + 3600 of shear (the onset transient and one full "
                             "oscillation period between the first two T1 peaks); the reference is FEM at "
                             "h = 0.5 with dt = 0.1 (not 0.1 h^2, for cost)")
        out["scenes"][name] = scene
    if not quick:
        out["diagnostics"] = diagnostics(runs) if only is None else {}
        out["diagnostics"]["steepness"] = steepness()
    out["wall_time_s"] = wallclock.perf_counter() - started
    return out


def diagnostics(runs: dict) -> dict:
    """What the FEM–FD difference is made of: its dependence on dt at h = 1 and on h at
    dt = 0.025 ('relax', 'shear'), and the convergence of both methods' centroids in a
    sheared 8-particle lattice against FEM at h = 0.5 ('small_lattice')."""
    out = {}
    for name in ("relax", "shear"):
        def pair(h, dt):
            return differences(runs[(name, "fem", h, dt, False)], runs[(name, "fd", h, dt, False)])["field"]

        dts = [0.1, 0.05, 0.025]
        vs_dt = [pair(1.0, dt) for dt in dts]
        hs = [2.0, 1.0, 0.5]
        vs_h = [pair(h, 0.025) for h in hs]
        out[name] = {
            "fem_vs_fd_field_at_h1": {"dt": dts, "difference": vs_dt, "order_in_dt": fitted_order(dts, vs_dt)},
            "fem_vs_fd_field_at_dt0.025": {"h": hs, "difference": vs_h, "order_in_h": fitted_order(hs, vs_h)},
        }
    reference = runs[("small_lattice", "fem", 0.5, 0.1, False)]
    x, t = reference["x"], reference["times"]
    # the displacement of the fastest particle during the shear phase (frames 2 → 4)
    travelled = float(np.max((x[-1] - x[2]) % 28.0))
    small = {"note": "8 particles (2 per row, the lattice's spacing 14 × 12) in 28 × 48, 100 time units of "
                     "relaxation then 100 of shear at rate 0.3; centroid differences at the end, against FEM at "
                     "h = 0.5 (same dt = 0.1), relative to the largest displacement in the shear phase",
             "largest_displacement": travelled, "fd_h": [1.0, 0.5]}

    def error(method, h):
        run = runs[("small_lattice", method, h, 0.1, False)]
        return float(frame_differences(run, reference)["centroid"][-1]) / travelled

    small["fem_centroid_error_h1"] = error("fem", 1.0)
    small["fd_centroid_error"] = [error("fd", 1.0), error("fd", 0.5)]
    small["fd_error_ratio_h1_to_h0.5"] = small["fd_centroid_error"][0] / small["fd_centroid_error"][1]
    small["time"] = float(t[-1])
    out["small_lattice"] = small
    return out


def lattice_periods(shear_start: float, reference: dict, runs: dict) -> dict:
    """The oscillation period of each lattice run: the time between the first two primary
    peaks of the bulk particles' mean elongation (centroid farther than 2R from the walls)
    in the shear phase (:func:`femphase.analysis.periods.first_period`; NaN when the run did
    not oscillate twice), and its relative difference from the reference's."""
    def period(run: dict) -> float:
        t, y, r = run["times"], run["y"], run["elongation"]
        bulk = (y > 2 * RADIUS) & (y < run["grid"][1] * run["grid"][2] - 2 * RADIUS)
        mean = np.array([r[k][bulk[k]].mean() for k in range(len(t))])
        shear = t >= shear_start
        return first_period(t[shear], mean[shear])

    reference_period = period(reference)
    out = {"reference": reference_period, "note": "time between the first two primary peaks of the bulk mean "
                                                  "elongation after the shear onset (frames every 50, parabola-refined)"}
    for (method, h), run in runs.items():
        value = period(run)
        out[f"{method} h={h:g}"] = {"period": None if np.isnan(value) else value,
                                    "relative_difference": None if np.isnan(value)
                                    else (value - reference_period) / reference_period}
    return out


def steepness() -> dict:
    """Why FD's advection error is larger in the lattice than for an isolated particle:
    the interfaces' derivatives after 300 time units of relaxation (FEM, h = 1, dt = 1), an
    isolated disc (the 'shear' scene's box) against the N = 100 lattice, where neighbours
    compress each other's interfaces. FD's third-order upwind advection errs by
    ~ |u| h³/12 ∂x⁴φ, so its lag scales with the fourth x-derivative of the fields."""
    out = {"note": "max over nodes of |∇φ| and of the central-difference |∂x³φ|, |∂x⁴φ| (h = 1), median "
                   "over particles, after 300 time units of relaxation; ratio = lattice / isolated"}
    for name, table in (("isolated", {"domain": {"Lx": 48.0, "Ly": 40.0, "h": 1.0},
                                      "particles": {"layout": "single", "initial_radius": RADIUS}}),
                        ("lattice", {"domain": {"Lx": 70.0, "Ly": 240.0, "h": 1.0},
                                     "particles": {"layout": "hexagonal", "N": 100}})):
        scene = scene_from_dict({"name": name, **table, "numerics": {"scheme": "euler"},
                                 "output": {"fields": False, "checkpoint": False},
                                 "phases": [_phase(300.0, 1.0, 300.0)]})
        state = scene.initial_state()
        Simulation(scene).run(state)
        maxima = {"gradient": [], "d3x": [], "d4x": []}
        for phi, window in zip(state.fields, state.windows):
            p = pad_window(phi.reshape(window.shape), window, state.domain.lattice, 2)
            core = p[2:-2, 2:-2]
            dx = (p[2:-2, 3:-1] - p[2:-2, 1:-3]) / 2
            dy = (p[3:-1, 2:-2] - p[1:-3, 2:-2]) / 2
            row = p[2:-2]
            maxima["gradient"].append(np.hypot(dx, dy).max())
            maxima["d3x"].append(np.abs(row[:, 4:] - 2 * row[:, 3:-1] + 2 * row[:, 1:-3] - row[:, :-4]).max() / 2)
            maxima["d4x"].append(np.abs(row[:, 4:] - 4 * row[:, 3:-1] + 6 * core - 4 * row[:, 1:-3] + row[:, :-4]).max())
        out[name] = {key: float(np.median(values)) for key, values in maxima.items()}
    out["ratio"] = {key: out["lattice"][key] / out["isolated"][key] for key in out["isolated"]}
    return out


def plot(result: dict, path: Path) -> None:
    names = list(result["scenes"])
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(4.2 * (len(names) + 1), 3.8), squeeze=False)
    styles = {"fem_vs_fd": ("FEM − FD", "o-"), "fem_vs_reference": ("FEM − ref", "s--"),
              "fd_vs_reference": ("FD − ref", "^--")}
    for ax, name in zip(axes[0], names):
        scene = result["scenes"][name]
        hs = np.array(scene["h"])
        for key, (label, style) in styles.items():
            order = scene["orders"][key]["field"]
            values = np.array(scene[key]["field"], dtype=float)
            # a run that is its own reference (lattice FEM at h = 0.5) has no point
            ax.loglog(hs, np.where(values > ROUNDOFF, values, np.nan), style,
                      label=f"{label} (order {order:.2f})" if order is not None else label)
        if name in result.get("diagnostics", {}):
            diag = result["diagnostics"][name]["fem_vs_fd_field_at_dt0.025"]
            ax.loglog(diag["h"], diag["difference"], "x:", color="grey", label="FEM − FD, dt = 0.025 fixed")
        ax.loglog(hs, scene["fem_vs_fd"]["field"][0] * (hs / hs[0]) ** 2, color="k", lw=0.6, label="∝ h²")
        ax.set_xlabel("h")
        ax.set_ylabel("max over frames of ‖Δφ‖_L2")
        ax.set_title(f"{name} (dt = {', '.join(f'{dt:g}' for dt in scene['dt'])})", fontsize=10)
        ax.legend(fontsize=7)
    ax = axes[0][-1]
    lattice = result["scenes"][names[-1]]
    series = lattice["fem_vs_fd_per_frame"]
    for h, values in zip(lattice["h"], series["centroid"]):
        values = np.asarray(values)
        ax.semilogy(series["time"], np.where(values > ROUNDOFF, values, np.nan), ".-", label=f"h = {h:g}")
    shear_start = result["scenes"][names[-1]].get("shear_start")
    if shear_start is not None:
        ax.axvline(shear_start, color="grey", lw=0.6)
    ax.set_xlabel("time")
    ax.set_ylabel("max over particles of |Δ centroid|")
    ax.set_title(f"{names[-1]}: FEM − FD (shear after grey line)", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def summary(result: dict) -> str:
    lines = []
    for name, scene in result["scenes"].items():
        lines.append(f"{name}: order of FEM–FD (field) = {scene['order']}")
        for key in ("fem_vs_fd", "fem_vs_reference", "fd_vs_reference"):
            values = ", ".join(f"{v:.3g}" for v in scene[key]["field"])
            orders = {m: (round(o, 2) if o is not None else None) for m, o in scene["orders"][key].items()}
            lines.append(f"  {key:<17} field [{values}] at h = {scene['h']}; orders {orders}")
    for name, diag in result.get("diagnostics", {}).items():
        lines.append(f"diagnostic {name}: {json.dumps(diag)}")
    lines.append(f"wall time {result['wall_time_s']:.0f} s")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small, short scenes (for tests)")
    parser.add_argument("--jobs", type=int, default=1, help="runs in parallel (processes)")
    parser.add_argument("--cache", type=Path, default=None,
                        help="keep every run in this directory and reuse it on the next call")
    parser.add_argument("--output", type=Path, default=None,
                        help=f"directory for fem_vs_fd.json/.png (default {RESULTS}; --quick: none)")
    parser.add_argument("--scenes", nargs="+", default=None, metavar="NAME",
                        help="rerun only these scenes and merge them into the existing fem_vs_fd.json "
                             "(its other scenes and diagnostics are kept)")
    args = parser.parse_args(argv)
    result = run(args.quick, args.jobs, args.cache, args.scenes)
    directory = args.output or (None if args.quick else RESULTS)
    if args.scenes is not None and directory is not None and (directory / "fem_vs_fd.json").exists():
        previous = json.loads((directory / "fem_vs_fd.json").read_text())
        result = {**previous, "scenes": {**previous["scenes"], **result["scenes"]},
                  "diagnostics": {**previous.get("diagnostics", {}), **result.get("diagnostics", {})},
                  "wall_time_s": result["wall_time_s"]}
        for scene in result["scenes"].values():  # stored scenes may predate the convention
            set_headline_order(scene)
    print(summary(result))
    if directory is not None:
        save(result, directory)
        print(f"wrote {directory / 'fem_vs_fd.json'} and {directory / 'fem_vs_fd.png'}")
    return 0


def save(result: dict, directory: Path) -> None:
    """Write fem_vs_fd.json and fem_vs_fd.png of ``result`` (:func:`run`) into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "fem_vs_fd.json").write_text(json.dumps(result, indent=1) + "\n")
    plot(result, directory / "fem_vs_fd.png")


if __name__ == "__main__":
    sys.exit(main())
