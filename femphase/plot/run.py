"""Figures of a run directory: ``femphase plot DIR [-o OUT] [--ode-rate R] [--ode-k K]``.

Four figures, written to OUT (default DIR/figures) as PNG unless ``--format`` says otherwise:

================ =================================================================================
``snapshot``     the last frame: Σφ_i in grey, each particle (label = argmax_i φ_i > 1/2)
                 tinted, and a red segment through each centroid along its elongation axis,
                 of length R_i·r, R_i the particle's target radius (the paper's Fig. 1b
                 style); from checkpoint.h5, else from the last frame of fields.xdmf;
                 node values on a mesh are interpolated to
                 an image, blank outside the mesh (obstacles)
``elongation``   r(t): the mean over the bulk particles (those farther than 2R from the
                 walls at shear onset), three individual particles, and the minimal ODE
                 model (:mod:`femphase.model.minimal`) at the run's shear rate (or ``--ode-rate``)
``limit_cycle``  the (r, 2θ) polar plane (:func:`femphase.analysis.periods.limit_cycle`) of
                 three bulk particles over the last quarter of the run, with the ODE's cycle
``order``        Ψ6, Ψ2^L, the lattice angle φ and the cumulative T1 count over time: the
                 run's own counter (global.csv ``t1_count``, which looks between frames),
                 or counted from the frames where the run has none
================ =================================================================================

The ODE is aligned with the simulation by its first T1 event as seen in the frames
(:mod:`femphase.oscillations`; a run without flow starts it at its first frame, plotted
with ``--ode-rate``), so to within a frame interval: write frames several times per
period for the comparison.

Runs on the structured grid and on meshes (``[domain] kind = "mesh"``) are drawn alike; a
meshed channel's extent (its x0 and the walls' y range) comes from its domain.

Everything is also usable from Python: the ``plot_*`` functions (each takes a
:class:`~femphase.io.reader.RunData` from :func:`femphase.io.reader.open_run` and an output
path), the ``draw_*`` functions (the same on a given matplotlib Axes, for composite
figures) and :func:`plot_run` (all four figures of a run directory).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from femphase.analysis.periods import limit_cycle
from femphase.io.checkpoints import load_checkpoint
from femphase.io.fields import point_data
from femphase.io.files import writable_directory
from femphase.io.reader import RunData, match_times, open_run
from femphase.io.rundir import CHECKPOINT, FIGURES, FIGURES_DIR
from femphase.model.minimal import MAX_HALF_PERIODS, ParameterError
from femphase.oscillations import K_PAPER, ode_alignment, ode_fits, ode_solution, order_series
from femphase.plot.figures import pyplot, save

__all__ = ["FIGURES", "N_SHOWN", "SNAPSHOT_PIXELS", "Snapshot", "draw_elongation", "draw_limit_cycle",
           "draw_snapshot", "plot_elongation", "plot_limit_cycle", "plot_order", "plot_run", "plot_snapshot"]


#: Individual particles drawn in the elongation and limit-cycle figures.
N_SHOWN = 3








def _shown_particles(run: RunData) -> np.ndarray:
    """N_SHOWN bulk particles spread over the channel's height."""
    bulk = np.flatnonzero(run.bulk_particles())
    order = bulk[np.argsort(run.y[0, bulk])]
    return order[np.linspace(0, len(order) - 1, min(N_SHOWN, len(order))).round().astype(int)]


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
    with run.fields() as frames:
        t, data = frames.read(-1)
        points, triangles = frames.points, frames.triangles.T
    return Snapshot(points[:, 0], points[:, 1], data["phi_sum"], data["label"], t, triangles)


def _checkpoint_fields(path: Path, domain) -> Snapshot:
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
    if snap.triangles is None:  # the grid's node values, one pixel centred on each node
        phi_sum, label = snap.phi_sum, snap.label
        hx, hy = (x1 - x0) / phi_sum.shape[1], (y1 - y0) / max(phi_sum.shape[0] - 1, 1)
        extent = (x0 - 0.5 * hx, x1 - 0.5 * hx, y0 - 0.5 * hy, y1 + 0.5 * hy)
    else:
        phi_sum, label = _rasterise(snap, run.extent)
        extent = (x0, x1, y0, y1)
    ax.imshow(phi_sum, origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=2.5)
    ax.imshow(np.ma.masked_where(np.ma.getdata(label) < 0, label % 20), origin="lower", extent=extent,
              cmap="tab20", alpha=0.45, vmin=0, vmax=19)
    time = snap.time
    _, match = match_times(np.array([time]), run.time)
    if match.size:  # the axes of that frame; a table cut since has none, and another frame's would mislead
        frame = int(match[0])
        half = 0.5 * run.radii * run.elongation[frame]
        dx, dy = half * np.cos(run.orientation[frame]), half * np.sin(run.orientation[frame])
        cx, cy = run.x[frame], run.y[frame]
        ax.plot(np.stack([cx - dx, cx + dx]), np.stack([cy - dy, cy + dy]), color="red", lw=1.2)
    else:
        warnings.warn(f"{str(run.directory)!r}: particles.csv has no complete frame at the fields' t = {time:g} "
                      f"(its frames end at t = {run.time[-1]:g}): the snapshot is drawn without elongation axes",
                      stacklevel=3)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(f"t = {time:g}" + ("" if match.size else " (no axes: no table frame)"), fontsize=8)


def plot_snapshot(run: RunData, path: Path) -> Path:
    """The last frame with each particle's elongation axis (see the module docstring)."""
    plt = pyplot()
    x0, x1, y0, y1 = run.extent
    aspect = (y1 - y0) / (x1 - x0)
    fig, ax = plt.subplots(figsize=(3.0, min(2.2 * aspect, 12) + 0.6))
    draw_snapshot(ax, run)
    ax.set_title(ax.get_title() + "\nred: elongation axis, length R_i·r", fontsize=8)
    return save(fig, path)


def draw_elongation(ax, run: RunData, ode_rate: float | None = None, ode_k: float = K_PAPER,
                    t_from: float | None = None) -> None:
    """Draw r(t) on `ax`: bulk mean, a few particles, and the minimal model from `t_from`
    (default: the start of the run)."""
    frames = run.time >= (run.time[0] if t_from is None else t_from) - 1e-9
    t = run.time[frames]
    marker = "o" if t.size < 3 else None  # a line through one frame draws nothing
    for j in _shown_particles(run):
        ax.plot(t, run.elongation[frames, j], lw=0.6, alpha=0.6, marker=marker, ms=3, label=f"particle {j}")
    ax.plot(t, run.bulk_elongation(frames), color="green", lw=1.8, marker=marker, ms=4,
            label="bulk mean")
    unfinished = _unfinished(run)
    if unfinished:
        ax.set_title(unfinished, fontsize=8, color="darkred")
    rate = ode_rate if ode_rate is not None else run.shear_rate
    solution, offset = ode_solution(run, rate, ode_k) if rate and rate > 0 else (None, 0.0)
    if solution is not None:
        shown = solution.time + offset >= t[0]
        aligned = ode_alignment(run, rate, ode_k)[1]
        ax.plot(solution.time[shown] + offset, solution.elongation[shown], color="red", lw=1.2,
                label=f"ODE, γ̇ = {rate:g}, k = {ode_k:.4g}" + (", from flow onset" if aligned == "shear onset" else ""))
    if run.flow_phase is not None and run.shear_start >= t[0]:
        ax.axvline(run.shear_start, color="k", ls=":", lw=0.8, label="flow onset")
    t1 = run.t1_times[run.t1_times >= t[0]]
    if t1.size:
        ax.plot(t1, np.zeros_like(t1), "|", color="k", ms=8, label="T1 events")
    ax.set_xlabel("time")
    ax.set_ylabel("elongation r = λ1/λ2 − 1")
    ax.legend(fontsize=7, ncol=3, loc="upper left")


def plot_elongation(run: RunData, path: Path, ode_rate: float | None = None, ode_k: float = K_PAPER) -> Path:
    """r(t): bulk mean, a few particles, and the minimal model (see the module docstring)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.6))
    draw_elongation(ax, run, ode_rate, ode_k)
    return save(fig, path)


def draw_limit_cycle(ax, run: RunData, ode_rate: float | None = None, ode_k: float = K_PAPER,
                     late_fraction: float = 0.25) -> None:
    """Draw (r cos 2θ, r sin 2θ) of a few bulk particles over the last `late_fraction` of the
    run on `ax`, with the ODE's cycle over the same times."""
    late = run.time >= run.time[-1] - late_fraction * (run.time[-1] - run.time[0])
    shown = _shown_particles(run)
    for j in shown:
        ax.plot(*limit_cycle(run.elongation[late, j], run.orientation[late, j]), lw=0.9, label=f"particle {j}")
    drawn = run.elongation[late][:, shown]
    drawn = drawn[np.isfinite(drawn)]  # vanished particles' rows are NaN
    reach = float(drawn.max()) if drawn.size else 0.0
    rate = ode_rate if ode_rate is not None else run.shear_rate
    solution, offset = ode_solution(run, rate, ode_k) if rate and rate > 0 else (None, 0.0)
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
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(4.6, 4.6))
    draw_limit_cycle(ax, run, ode_rate, ode_k)
    ax.set_title("limit cycle, last quarter of the run", fontsize=9)
    return save(fig, path)




def plot_order(run: RunData, path: Path) -> Path:
    """Ψ6 and Ψ2^L, the lattice angle φ and the cumulative T1 count over time."""
    plt = pyplot()
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
    counted = run.globals.get("t1_count")
    if counted is not None and np.any(np.isfinite(counted)):
        # the run's own counter, which looks between frames: counting from the frames alone
        # misses the exchanges that come and go between two of them (4× too few at γ̇ = 1
        # with frames 400 apart, docs/outputs.md)
        axes[2].step(run.time, counted, where="post", color="k")
        axes[2].set_ylabel("T1 events (cumulative,\nthe run's counter)")
    else:
        t1 = run.t1_times
        axes[2].step(np.concatenate([[run.time[0]], t1, [run.time[-1]]]),
                     np.concatenate([[0], np.arange(1, t1.size + 1), [t1.size]]), where="post", color="k")
        axes[2].set_ylabel("T1 events (cumulative,\nfrom the frames)")
    axes[2].set_xlabel("time")
    if run.flow_phase is not None:
        for ax in axes:
            ax.axvline(run.shear_start, color="k", ls=":", lw=0.8)
    if run.n_particles < 3:
        axes[0].text(0.5, 0.5, "fewer than 3 particles: no order parameters", transform=axes[0].transAxes,
                     ha="center")
    return save(fig, path)


def plot_run(directory: str | Path, output: str | Path | None = None, *, ode_rate: float | None = None,
             ode_k: float = K_PAPER, fmt: str = "png") -> dict[str, Path]:
    """Write the four figures of a run directory; returns {figure name: path}.

    `output` defaults to DIR/figures; `ode_rate` to the run's shear rate
    (:attr:`~femphase.io.reader.RunData.shear_rate`, linear shears only: no ODE when the run
    has none and none is given; none either, with a warning, when that shear runs towards
    −x or when one solve of it would not span the run, :func:`~femphase.oscillations.ode_fits`). A run written without
    fields and checkpoint has no snapshot: the other three, and a warning."""
    run = open_run(directory).complete()
    if len(run.time) == 0:
        raise ValueError(f"{str(Path(directory) / 'particles.csv')!r} has no frames yet")
    out = Path(output) if output is not None else run.directory / FIGURES_DIR
    # both checked before any figure is written
    if ode_rate is not None and not (np.isfinite(ode_rate) and ode_rate > 0):
        raise ParameterError("ode_rate", ode_rate, "the shear rate γ̇ of the ODE: a finite number > 0")
    if not (np.isfinite(ode_k) and ode_k > 0):
        raise ParameterError("ode_k", ode_k, "the ODE's k (ω = k γ̇): a finite number > 0")
    writable_directory(out)  # one that cannot be made is named as -o, before any figure is drawn
    rate = ode_rate if ode_rate is not None else run.shear_rate
    if rate is not None and rate < 0:  # the run's own rate: a shear towards −x
        warnings.warn(f"no minimal-model curve: it is drawn for γ̇ > 0, and the run's shear is γ̇ = {rate:g} "
                      f"(the mirror image of γ̇ = {-rate:g}, θ → −θ; --ode-rate {-rate:g} draws that)", stacklevel=2)
        ode_rate = 0.0
    elif rate and not ode_fits(run, rate, ode_k):  # one solve would take hours: the figures without it
        warnings.warn(f"no minimal-model curve: at γ̇ = {rate:g} the run spans more than {MAX_HALF_PERIODS} of its "
                      f"half periods π/(2kγ̇) = {np.pi / (2 * ode_k * rate):.3g}", stacklevel=2)
        ode_rate = 0.0  # no ODE
    unfinished = _unfinished(run)
    if unfinished:
        warnings.warn(f"{str(run.directory)!r}: {unfinished}", stacklevel=2)
    figures = {}
    if run_has_fields(run):
        figures["snapshot"] = plot_snapshot(run, out / f"snapshot.{fmt}")
    else:  # output.fields = false and output.checkpoint = false: the tables' figures only
        warnings.warn(f"no snapshot: {str(run.directory)!r} has neither {CHECKPOINT} nor fields.xdmf "
                      "(output.checkpoint and output.fields were false)", stacklevel=2)
    figures["elongation"] = plot_elongation(run, out / f"elongation.{fmt}", ode_rate, ode_k)
    figures["limit_cycle"] = plot_limit_cycle(run, out / f"limit_cycle.{fmt}", ode_rate, ode_k)
    figures["order"] = plot_order(run, out / f"order.{fmt}")
    return figures


def _unfinished(run: RunData) -> str | None:
    """What to say of a run that did not complete (run.json's status), or whose tables end
    before the run did (cut or damaged since), else None."""
    status, end = run.info.get("status"), run.info.get("time")
    if status not in (None, "completed"):
        return f"run status {status!r}: its frames end at t = {run.time[-1]:g}"
    if status == "completed" and end is not None and not match_times(np.array([float(end)]), run.time[-1:])[0].size:
        return (f"particles.csv's complete frames end at t = {run.time[-1]:g}, before the run's end at t = "
                f"{float(end):g} (the table was cut or damaged since)")
    return None


def run_has_fields(run: RunData) -> bool:
    """Whether a run directory holds fields to draw a snapshot from (checkpoint.h5 or fields.xdmf)."""
    return (run.directory / CHECKPOINT).exists() or (run.directory / "fields.xdmf").exists()
