"""Figures of a run directory: ``femphase plot DIR [-o OUT] [--ode-rate R] [--ode-k K]``.

Four figures, written to OUT (default DIR/figures) as PNG unless ``--format`` says otherwise:

``snapshot``     the last frame: Σφ_i in grey, each particle (label = argmax_i φ_i > 1/2)
                 tinted, and a red segment through each centroid along its elongation axis,
                 of length R·r (the paper's Fig. 1b style); from checkpoint.h5, else from
                 the last frame of fields.xdmf; node values on a mesh are interpolated to
                 an image, blank outside the mesh (obstacles)
``elongation``   r(t): the mean over the bulk particles (those farther than 2R from the
                 walls at shear onset), three individual particles, and the minimal ODE
                 model (:mod:`femphase.ode`) at the run's shear rate (or ``--ode-rate``)
``limit_cycle``  the (r, 2θ) polar plane (:func:`femphase.analysis.periods.limit_cycle`) of
                 three bulk particles over the last quarter of the run, with the ODE's cycle
``order``        Ψ6, Ψ2^L, the lattice angle φ and the cumulative T1 count over time

Aligning the ODE with the simulation.  The ODE starts at t = 0 from the hexagonal lattice
(φ = π/3) and has its first T1 at τ0 = π/(2kγ̇).  The simulation's first T1 after shear
onset is found with :func:`femphase.analysis.lattice.t1_event_times` on the centroids of
particles.csv; the ODE is shifted so that its τ0 falls on it.  Without a T1 (no lattice, too
short a run) the ODE starts at shear onset, or at the first frame of a run without flow
(plotted with ``--ode-rate``).  The alignment is exact at the first T1 only: when
the ODE's period π/(kγ̇) differs from the simulation's, the phases drift apart, which is
why the comparison also offers k matched to the measured period (:func:`ode_comparison`).

Runs on the structured grid and on meshes (``[domain] kind = "mesh"``) are drawn alike; a
meshed channel's extent (its x0 and the walls' y range) comes from its domain.

Everything is also usable from Python: :func:`load_run`, the ``plot_*`` functions (each
takes a :class:`RunData` and an output path), the ``draw_*`` functions (the same on a given
matplotlib Axes, for composite figures), :func:`ode_comparison` and :func:`plot_run` (all
four figures).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from .errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: The paper's ω = kγ̇ (its fitted k).
K_PAPER = 0.01
#: Individual particles drawn in the elongation and limit-cycle figures.
N_SHOWN = 3
FIGURES = ("snapshot", "elongation", "limit_cycle", "order")


@dataclass
class RunData:
    """A run directory read back: scene (resolved, as a dict), run.json (or {} while the run
    is under way), per-particle observables as (n_frames, N) arrays and global.csv columns.
    Times in time units, angles in radians."""

    directory: Path
    scene: dict
    info: dict
    time: np.ndarray
    x: np.ndarray
    y: np.ndarray
    elongation: np.ndarray
    orientation: np.ndarray
    globals: dict

    @property
    def n_particles(self) -> int:
        return self.x.shape[1]

    @property
    def flow_phase(self) -> int | None:
        """Index of the first phase with a flow, None if there is none."""
        for index, phase in enumerate(self.scene.get("phases", [])):
            if phase.get("flow", {}).get("type", "none") != "none":
                return index
        return None

    @property
    def shear_start(self) -> float:
        """Time at which the first phase with a flow starts (the run's end if none)."""
        phases = self.scene.get("phases", [])
        index = self.flow_phase
        if index is None:
            return float(self.time[-1])
        return float(sum(p["duration"] for p in phases[:index]))

    @property
    def shear_rate(self) -> float | None:
        """γ̇ of the first phase with a flow (its "rate"), None without flow."""
        index = self.flow_phase
        return None if index is None else self.scene["phases"][index]["flow"].get("rate")

    @property
    def radius(self) -> float:
        return float(self.scene.get("model", {}).get("radius", 8.0))

    @property
    def length(self) -> float:
        return float(self.scene["domain"]["Lx"])

    @property
    def width(self) -> float:
        return float(self.scene["domain"]["Ly"])

    @property
    def kind(self) -> str:
        return str(self.scene["domain"].get("kind", "grid"))

    @cached_property
    def domain(self):
        """The run's Domain, rebuilt from scene.toml (a meshed run's mesh file must still exist)."""
        import warnings

        from .errors import ResolutionWarning
        from .scene import scene_from_dict

        with warnings.catch_warnings():  # the run itself warned about its resolution
            warnings.simplefilter("ignore", ResolutionWarning)
            return scene_from_dict(self.scene, self.directory).domain

    @cached_property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the channel: [0, Lx] × [0, Ly] on the grid; a
        meshed channel's x0 and wall range from its domain (from fields.xdmf's nodes when the
        mesh file is gone)."""
        if self.kind == "grid":
            return 0.0, self.length, 0.0, self.width
        try:
            domain = self.domain
            low, high = domain.y_range
            return domain.x0, domain.x0 + domain.period, low, high
        except (OSError, ValueError):  # SceneError is a ValueError
            xdmf = self.directory / "fields.xdmf"
            if not xdmf.exists():
                raise
            import meshio

            with meshio.xdmf.TimeSeriesReader(str(xdmf.resolve())) as reader:
                points, _ = reader.read_points_cells()
            return (float(points[:, 0].min()), float(points[:, 0].max()),
                    float(points[:, 1].min()), float(points[:, 1].max()))

    def bulk_particles(self) -> np.ndarray:
        """Mask of the particles farther than 2R from both walls at shear onset (all of them
        if none is): the rows at the walls are stretched across the wall layer and oscillate
        differently."""
        frame = min(np.searchsorted(self.time, self.shear_start - 1e-9), len(self.time) - 1)
        y = self.y[frame]
        margin = 2 * self.radius
        _, _, low, high = self.extent
        bulk = (y > low + margin) & (y < high - margin)
        return bulk if bulk.any() else np.ones_like(bulk)

    @cached_property
    def t1_times(self) -> np.ndarray:
        """Times of the T1 events after shear onset (empty for fewer than 3 particles)."""
        from .analysis.lattice import t1_event_times

        if self.n_particles < 3:
            return np.empty(0)
        frames = self.time >= self.shear_start - 1e-9
        centroids = np.stack([self.x[frames], self.y[frames]], axis=-1)
        return t1_event_times(list(centroids), self.time[frames], self.length)


def load_run(directory: str | Path) -> RunData:
    """Read a run directory written by ``femphase run`` (see :mod:`femphase.io`).

    Raises
    ------
    FileNotFoundError
        If `directory` does not exist or lacks scene.toml or particles.csv.
    ValueError
        If particles.csv holds no complete frame.
    """
    from .io import read_csv

    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"run directory {str(directory)!r} does not exist; expected the output "
                                "directory of `femphase run SCENE -o DIR`")
    for name in ("scene.toml", "particles.csv"):
        if not (directory / name).is_file():
            raise FileNotFoundError(f"{str(directory)!r} is not a femphase run directory: it has no {name} "
                                    "(expected the output directory of `femphase run SCENE -o DIR`)")
    scene = tomllib.loads((directory / "scene.toml").read_text())
    columns = read_csv(directory / "particles.csv")
    if len(columns["id"]) == 0:
        raise ValueError(f"{str(directory / 'particles.csv')!r} has no frames yet")
    n = int(columns["id"].max()) + 1
    frames = len(columns["id"]) // n

    def table(name: str) -> np.ndarray:
        return columns[name][: frames * n].reshape(frames, n)

    info_path = directory / "run.json"
    info = json.loads(info_path.read_text()) if info_path.exists() else {}
    globals_ = read_csv(directory / "global.csv") if (directory / "global.csv").exists() else {}
    return RunData(directory, scene, info, table("time")[:, 0], table("x"), table("y"),
                   table("elongation"), table("orientation"), globals_)


def ode_solution(run: RunData, rate: float, k: float = K_PAPER):
    """The minimal model at `rate` with ω = kγ̇, and the simulation time of its t = 0.

    Returns ``(solution, offset)``: the ODE's sample at ODE time s is the simulation's time
    s + offset (see the module docstring for the alignment by the first T1; a run without
    flow starts the ODE at its first frame).  ``(None, offset)`` when the run ends before
    the ODE would start.
    """
    from .ode import MinimalModelParameters, solve_minimal_model

    if run.t1_times.size:
        offset = float(run.t1_times[0]) - np.pi / (2 * k * rate)
    else:
        offset = run.shear_start if run.flow_phase is not None else float(run.time[0])
    t_end = float(run.time[-1]) - offset
    if t_end <= 0:
        return None, offset
    samples = max(2001, int(40 * t_end * k * rate / np.pi))  # ≥ 40 samples per period
    solution = solve_minimal_model(rate, t_end, parameters=MinimalModelParameters(k=k), n_samples=samples)
    return solution, offset


def measured_period(run: RunData, t_from: float | None = None) -> float | None:
    """Period of the bulk-mean r(t) after `t_from` (default: shear onset + a quarter of the
    shear phase), None when no period can be measured."""
    from .analysis.periods import oscillation_period

    start = run.shear_start if t_from is None else t_from
    frames = run.time >= start - 1e-9
    mean_r = run.elongation[frames][:, run.bulk_particles()].mean(axis=1)
    try:
        return oscillation_period(run.time[frames], mean_r, discard_fraction=0.25 if t_from is None else 0.0).period
    except ValueError:
        return None


def ode_comparison(run: RunData, rate: float, t_from: float | None = None) -> dict:
    """Bulk-mean r(t) of the simulation against the minimal model, after `t_from`.

    Two ODEs: the paper's k = 0.01 and k matched to the measured period of r̄ (k = π/(Tγ̇)),
    each aligned by the first T1.  For each: the RMS difference and the Pearson correlation
    of r̄ and r_ODE on the simulation's frames, and the mean and range of both.
    """
    start = run.shear_start if t_from is None else t_from
    frames = run.time >= start - 1e-9
    t = run.time[frames]
    mean_r = run.elongation[frames][:, run.bulk_particles()].mean(axis=1)
    period = measured_period(run, t_from)
    ks = {"paper": K_PAPER}
    if period is not None:
        ks["matched"] = np.pi / (period * rate)
    out = {"simulation": {"mean": float(mean_r.mean()), "min": float(mean_r.min()), "max": float(mean_r.max())},
           "first_t1": float(run.t1_times[0]) if run.t1_times.size else None}
    for name, k in ks.items():
        solution, offset = ode_solution(run, rate, k)
        if solution is None:
            continue
        r_ode = np.interp(t - offset, solution.time, solution.elongation)
        out[name] = {
            "k": float(k), "offset": float(offset),
            "rms_difference": float(np.sqrt(np.mean((mean_r - r_ode) ** 2))),
            "correlation": float(np.corrcoef(mean_r, r_ode)[0, 1]) if np.std(r_ode) > 0 else None,
            "mean": float(r_ode.mean()), "min": float(r_ode.min()), "max": float(r_ode.max()),
        }
    return out


def _shown_particles(run: RunData) -> np.ndarray:
    """N_SHOWN bulk particles spread over the channel's height."""
    bulk = np.flatnonzero(run.bulk_particles())
    order = bulk[np.argsort(run.y[0, bulk])]
    return order[np.linspace(0, len(order) - 1, min(N_SHOWN, len(order))).round().astype(int)]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


@dataclass
class Snapshot:
    """The last frame's fields: on the grid (ny, nx) images with the node coordinates
    (``triangles`` None), on a mesh node values with its triangles (3, n_triangles)."""

    x: np.ndarray
    y: np.ndarray
    phi_sum: np.ndarray
    label: np.ndarray
    time: float
    triangles: np.ndarray | None = None


def _last_fields(run: RunData) -> Snapshot:
    """The last frame: from checkpoint.h5 (on the run's domain, rebuilt from scene.toml),
    else from the last step of fields.xdmf (node arrays on its mesh)."""
    from .rundir import CHECKPOINT

    checkpoint = run.directory / CHECKPOINT
    xdmf = run.directory / "fields.xdmf"
    if checkpoint.exists():
        try:
            domain = run.domain
        except (OSError, ValueError):  # SceneError is a ValueError
            if not xdmf.exists():  # no other source of the fields: say why
                raise
            domain = None  # e.g. a meshed run whose mesh file moved: fields.xdmf has it all
        if domain is not None:
            return _checkpoint_fields(checkpoint, domain)
    if not xdmf.exists():
        raise FileNotFoundError(f"{str(run.directory)!r} has neither {CHECKPOINT} nor fields.xdmf to draw a snapshot from")
    import meshio

    with meshio.xdmf.TimeSeriesReader(str(xdmf.resolve())) as reader:
        points, cells = reader.read_points_cells()
        t, data, _ = reader.read_data(reader.num_steps - 1)
    triangles = np.vstack([c.data for c in cells if c.type == "triangle"]).T
    return Snapshot(points[:, 0], points[:, 1], np.asarray(data["phi_sum"]).ravel(),
                    np.asarray(data["label"]).ravel(), float(t), triangles)


def _checkpoint_fields(path: Path, domain) -> Snapshot:
    from .io import load_checkpoint, point_data

    state, _ = load_checkpoint(path, domain)
    grid = getattr(domain, "grid", None)
    if grid is not None:  # images in grid order (dof = iy·nx + ix)
        phis = state.global_fields()
        best = np.argmax(phis, axis=0)
        top = phis[best, np.arange(phis.shape[1])]
        shape = (grid.ny, grid.nx)
        x, y = grid.coordinates()
        gx, gy = np.meshgrid(x, y)
        label = np.where(top > 0.5, best, -1).reshape(shape)
        return Snapshot(gx, gy, phis.sum(axis=0).reshape(shape), label, state.time)
    data = point_data(state, per_particle=False)  # on the nodes of the non-periodic mesh
    return Snapshot(domain.mesh.p[0], domain.mesh.p[1], data["phi_sum"], data["label"], state.time, domain.mesh.t)


#: Pixels along the longer side of a meshed snapshot's image.
SNAPSHOT_PIXELS = 600


def _rasterise(snap: Snapshot, extent: tuple[float, float, float, float]) -> tuple[np.ma.MaskedArray, np.ma.MaskedArray]:
    """Node values on a mesh as images on a pixel grid over ``extent`` (drawn like the grid's,
    with no seams between triangles): Σφ interpolated linearly in its triangle, the label of
    the nearest node; masked outside the mesh (obstacles)."""
    from matplotlib.tri import LinearTriInterpolator, Triangulation
    from scipy.spatial import cKDTree

    x0, x1, y0, y1 = extent
    step = max(x1 - x0, y1 - y0) / SNAPSHOT_PIXELS
    xs = x0 + step * (np.arange(max(1, round((x1 - x0) / step))) + 0.5)
    ys = y0 + step * (np.arange(max(1, round((y1 - y0) / step))) + 0.5)
    gx, gy = np.meshgrid(xs, ys)
    mesh = Triangulation(snap.x, snap.y, snap.triangles.T)
    outside = mesh.get_trifinder()(gx, gy) < 0
    phi_sum = np.ma.masked_array(np.ma.filled(LinearTriInterpolator(mesh, snap.phi_sum)(gx, gy), 0.0), outside)
    _, nearest = cKDTree(np.column_stack([snap.x, snap.y])).query(np.column_stack([gx.ravel(), gy.ravel()]))
    label = np.ma.masked_array(np.asarray(snap.label)[nearest].reshape(gx.shape), outside)
    return phi_sum, label


def draw_snapshot(ax, run: RunData) -> None:
    """Draw the last frame with each particle's elongation axis on `ax` (module docstring)."""
    snap = _last_fields(run)
    x0, x1, y0, y1 = run.extent
    phi_sum, label = (snap.phi_sum, snap.label) if snap.triangles is None else _rasterise(snap, run.extent)
    extent = (x0, x1, y0, y1)
    ax.imshow(phi_sum, origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=2.5)
    ax.imshow(np.ma.masked_where(np.ma.getdata(label) < 0, label % 20), origin="lower", extent=extent,
              cmap="tab20", alpha=0.45, vmin=0, vmax=19)
    time = snap.time
    frame = int(np.argmin(np.abs(run.time - time)))
    half = 0.5 * run.radius * run.elongation[frame]
    dx, dy = half * np.cos(run.orientation[frame]), half * np.sin(run.orientation[frame])
    cx, cy = run.x[frame], run.y[frame]
    ax.plot(np.stack([cx - dx, cx + dx]), np.stack([cy - dy, cy + dy]), color="red", lw=1.2)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(f"t = {time:g}", fontsize=8)


def plot_snapshot(run: RunData, path: Path) -> Path:
    """The last frame with each particle's elongation axis (see the module docstring)."""
    plt = _pyplot()
    x0, x1, y0, y1 = run.extent
    aspect = (y1 - y0) / (x1 - x0)
    fig, ax = plt.subplots(figsize=(3.0, min(2.2 * aspect, 12) + 0.6))
    draw_snapshot(ax, run)
    ax.set_title(ax.get_title() + "\nred: elongation axis, length R·r", fontsize=8)
    return _save(fig, path)


def draw_elongation(ax, run: RunData, ode_rate: float | None = None, ode_k: float = K_PAPER,
                    t_from: float | None = None) -> None:
    """Draw r(t) on `ax`: bulk mean, a few particles, and the minimal model from `t_from`
    (default: the start of the run)."""
    frames = run.time >= (run.time[0] if t_from is None else t_from) - 1e-9
    t = run.time[frames]
    for j in _shown_particles(run):
        ax.plot(t, run.elongation[frames, j], lw=0.6, alpha=0.6, label=f"particle {j}")
    ax.plot(t, run.elongation[frames][:, run.bulk_particles()].mean(axis=1), color="green", lw=1.8,
            label="bulk mean")
    rate = ode_rate if ode_rate is not None else run.shear_rate
    solution, offset = ode_solution(run, rate, ode_k) if rate else (None, 0.0)
    if solution is not None:
        shown = solution.time + offset >= t[0]
        ax.plot(solution.time[shown] + offset, solution.elongation[shown], color="red", lw=1.2,
                label=f"ODE, γ̇ = {rate:g}, k = {ode_k:.4g}")
    if run.flow_phase is not None and run.shear_start >= t[0]:
        ax.axvline(run.shear_start, color="k", ls=":", lw=0.8, label="shear onset")
    t1 = run.t1_times[run.t1_times >= t[0]]
    if t1.size:
        ax.plot(t1, np.zeros_like(t1), "|", color="k", ms=8, label="T1 events")
    ax.set_xlabel("time")
    ax.set_ylabel("elongation r = λ1/λ2 − 1")
    ax.legend(fontsize=7, ncol=3, loc="upper left")


def plot_elongation(run: RunData, path: Path, ode_rate: float | None = None, ode_k: float = K_PAPER) -> Path:
    """r(t): bulk mean, a few particles, and the minimal model (see the module docstring)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.6))
    draw_elongation(ax, run, ode_rate, ode_k)
    return _save(fig, path)


def draw_limit_cycle(ax, run: RunData, ode_rate: float | None = None, ode_k: float = K_PAPER,
                     late_fraction: float = 0.25) -> None:
    """Draw (r cos 2θ, r sin 2θ) of a few bulk particles over the last `late_fraction` of the
    run on `ax`, with the ODE's cycle over the same times."""
    from .analysis.periods import limit_cycle

    late = run.time >= run.time[-1] - late_fraction * (run.time[-1] - run.time[0])
    shown = _shown_particles(run)
    for j in shown:
        ax.plot(*limit_cycle(run.elongation[late, j], run.orientation[late, j]), lw=0.9, label=f"particle {j}")
    reach = float(np.nanmax(run.elongation[late][:, shown]))
    rate = ode_rate if ode_rate is not None else run.shear_rate
    solution, offset = ode_solution(run, rate, ode_k) if rate else (None, 0.0)
    if solution is not None:
        ode_late = solution.time + offset >= run.time[late][0]
        ax.plot(*limit_cycle(solution.elongation[ode_late], solution.orientation[ode_late]), color="red", lw=1.2,
                label=f"ODE, k = {ode_k:.4g}")
        reach = max(reach, float(solution.elongation[ode_late].max()))
    reach = 1.1 * max(reach, 0.05)
    for angle in (0.0, np.pi / 2):  # 2θ = 0 (flow axis), π/2 (θ = π/4, the strain axis)
        ax.plot([-reach * np.cos(angle), reach * np.cos(angle)], [-reach * np.sin(angle), reach * np.sin(angle)],
                color="grey", lw=0.5)
    ax.set_xlim(-reach, reach)
    ax.set_ylim(-reach, reach)
    ax.set_aspect("equal")
    ax.set_xlabel("r cos 2θ")
    ax.set_ylabel("r sin 2θ")
    ax.legend(fontsize=7, loc="lower left")


def plot_limit_cycle(run: RunData, path: Path, ode_rate: float | None = None, ode_k: float = K_PAPER) -> Path:
    """(r cos 2θ, r sin 2θ) over the last quarter of the run, with the ODE's cycle."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(4.6, 4.6))
    draw_limit_cycle(ax, run, ode_rate, ode_k)
    ax.set_title("limit cycle, last quarter of the run", fontsize=9)
    return _save(fig, path)


def order_series(run: RunData) -> dict[str, np.ndarray]:
    """Ψ6, Ψ2^L and the lattice angle per frame: global.csv's columns when the run wrote them
    (output.observables = ["order"]), else computed from particles.csv with the observable
    :class:`femphase.observables.Order`; NaN for fewer than 3 particles."""
    if "Psi6" in run.globals and len(run.globals["Psi6"]) == len(run.time):
        return {name: run.globals[name] for name in ("Psi6", "Psi2", "lattice_angle")}
    from .analysis.lattice import frame_order

    rows = []
    for k in range(len(run.time)):
        order = frame_order(np.stack([run.x[k], run.y[k]], axis=1), run.orientation[k], run.length)
        rows.append([order["Psi6"], order["Psi2"], order["lattice_angle"]])
    rows = np.asarray(rows, dtype=float).reshape(-1, 3)
    return {"Psi6": rows[:, 0], "Psi2": rows[:, 1], "lattice_angle": rows[:, 2]}


def plot_order(run: RunData, path: Path) -> Path:
    """Ψ6 and Ψ2^L, the lattice angle φ and the cumulative T1 count over time."""
    plt = _pyplot()
    series = order_series(run)
    fig, axes = plt.subplots(3, 1, figsize=(8, 6.5), sharex=True)
    axes[0].plot(run.time, series["Psi6"], label="Ψ6 (bond order)")
    axes[0].plot(run.time, series["Psi2"], label="Ψ2^L (nematic order)")
    axes[0].set_ylim(-0.02, 1.02)
    axes[0].legend(fontsize=7)
    axes[1].plot(run.time, np.degrees(series["lattice_angle"]), color="C2")
    for angle, name in ((60, "hexagonal"), (45, "square")):
        axes[1].axhline(angle, color="grey", ls=":", lw=0.8)
        axes[1].text(run.time[0], angle, name, fontsize=7, va="bottom")
    axes[1].set_ylabel("lattice angle φ (°)")
    t1 = run.t1_times
    axes[2].step(np.concatenate([[run.time[0]], t1, [run.time[-1]]]),
                 np.concatenate([[0], np.arange(1, t1.size + 1), [t1.size]]), where="post", color="k")
    axes[2].set_ylabel("T1 events (cumulative)")
    axes[2].set_xlabel("time")
    if run.flow_phase is not None:
        for ax in axes:
            ax.axvline(run.shear_start, color="k", ls=":", lw=0.8)
    if run.n_particles < 3:
        axes[0].text(0.5, 0.5, "fewer than 3 particles: no order parameters", transform=axes[0].transAxes,
                     ha="center")
    return _save(fig, path)


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def plot_run(directory: str | Path, output: str | Path | None = None, *, ode_rate: float | None = None,
             ode_k: float = K_PAPER, fmt: str = "png") -> dict[str, Path]:
    """Write all four figures of a run directory; returns {figure name: path}.

    `output` defaults to DIR/figures; `ode_rate` to the run's shear rate (no ODE when the
    run has no flow and none is given).
    """
    run = load_run(directory)
    out = Path(output) if output is not None else run.directory / "figures"
    if ode_rate is not None and not (np.isfinite(ode_rate) and ode_rate > 0):
        raise ValueError(f"--ode-rate = {ode_rate!r} is invalid: the shear rate γ̇ must be a finite number > 0")
    return {
        "snapshot": plot_snapshot(run, out / f"snapshot.{fmt}"),
        "elongation": plot_elongation(run, out / f"elongation.{fmt}", ode_rate, ode_k),
        "limit_cycle": plot_limit_cycle(run, out / f"limit_cycle.{fmt}", ode_rate, ode_k),
        "order": plot_order(run, out / f"order.{fmt}"),
    }


def run_cli(args: argparse.Namespace) -> int:
    """`femphase plot DIR`: write the four figures and list them (a sweep's figures when DIR
    holds sweep.json, :mod:`femphase.aggregate`)."""
    from .aggregate import SWEEP_INDEX, plot_cli

    if (args.directory / SWEEP_INDEX).is_file():
        return plot_cli(args)
    try:
        paths = plot_run(args.directory, args.output, ode_rate=args.ode_rate, ode_k=args.ode_k, fmt=args.format)
    except (ValueError, OSError) as exc:  # this module's input errors; the CLI prints them as such
        raise InputError(str(exc)) from None
    for path in paths.values():
        print(path)
    return 0


def register_cli(subparsers: argparse._SubParsersAction) -> None:
    """Add the `plot` subcommand to the femphase command line."""
    parser = subparsers.add_parser(
        "plot", help="figures of a run directory (snapshot, r(t) vs the ODE, limit cycle, order)",
        description=__doc__.split("\n\n")[0],
    )
    parser.add_argument("directory", type=Path, help="run directory written by `femphase run`, or a sweep "
                        "directory (sweep.json; its figures are described in docs/aggregation.md)")
    parser.add_argument("-o", "--output", type=Path, default=None, help="output directory (default DIR/figures)")
    parser.add_argument("--ode-rate", type=float, default=None,
                        help="shear rate γ̇ of the ODE model (default: the run's shear rate)")
    parser.add_argument("--ode-k", type=float, default=K_PAPER, help=f"ω = kγ̇ of the ODE (default {K_PAPER}, the paper's)")
    parser.add_argument("--format", default="png", choices=["png", "pdf", "svg"], help="image format (default png)")
    parser.set_defaults(func=run_cli)
