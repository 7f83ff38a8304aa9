"""Reading a run directory back: the one reader that figures, comparisons and sweep
aggregates use.

:func:`open_run` reads what ``femphase run`` wrote (:mod:`femphase.io.rundir`): the resolved
``scene.toml``, ``run.json``, and ``particles.csv`` and ``global.csv`` on one axis of frame
times (the union of both files' times, :func:`merge_times`), as a :class:`RunData`.
Per-particle columns are (F, N) arrays, global columns (F,) arrays, NaN where a file lacks a
frame or a row (a run under way, or killed between writing the two files);
:meth:`RunData.complete` keeps the frames every particle has. :meth:`RunData.fields` opens the
field frames of ``fields.xdmf``. Columns and units: ``docs/outputs.md``. Times in time units,
lengths in lattice units, angles in radians.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import meshio
import numpy as np

from femphase import tomlio
from femphase.analysis.lattice import t1_event_times
from femphase.domains.base import Domain
from femphase.errors import InputError, ResolutionWarning, SceneError
from femphase.io.files import read_csv
from femphase.scene import Scene, scene_from_dict

__all__ = ["RELATIVE_TIME_TOLERANCE", "TIME_TOLERANCE", "FieldFrames", "RunData", "match_times", "mean_present",
           "merge_times", "open_run"]

#: Frame times closer than this (time units) are the same frame: runs with different time
#: steps reach the same frame time up to round-off. Far into a run the round-off grows
#: with the time: the clock sums dt step by step, and 9.6·10⁵ steps of 0.1 end 1.1e-6 past
#: t = 96000; so frames also match within :data:`RELATIVE_TIME_TOLERANCE` of their time.
TIME_TOLERANCE = 1e-6
RELATIVE_TIME_TOLERANCE = 1e-9


def _tolerance(time: np.ndarray) -> np.ndarray:
    return TIME_TOLERANCE + RELATIVE_TIME_TOLERANCE * np.abs(time)


def match_times(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ia, ib) of the frame times a and b share (within TIME_TOLERANCE, or
    RELATIVE_TIME_TOLERANCE of the time); b sorted."""
    if a.size == 0 or b.size == 0:
        return np.empty(0, dtype=int), np.empty(0, dtype=int)
    position = np.searchsorted(b, a)
    below, above = np.clip(position - 1, 0, b.size - 1), np.clip(position, 0, b.size - 1)
    nearest = np.where(np.abs(b[below] - a) <= np.abs(b[above] - a), below, above)
    keep = np.abs(b[nearest] - a) <= _tolerance(a)
    return np.flatnonzero(keep), nearest[keep]


def merge_times(*times: np.ndarray) -> np.ndarray:
    """The sorted union of frame times, times within the tolerance of :func:`match_times` taken
    as one (the first)."""
    merged = np.sort(np.concatenate([np.asarray(t, dtype=float).ravel() for t in times] + [np.empty(0)]))
    if merged.size == 0:
        return merged
    return merged[np.concatenate([[True], np.diff(merged) > _tolerance(merged[1:])])]


def frame_index(times: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Index into ``frames`` (sorted, from :func:`merge_times` of ``times``) of each time."""
    rows, index = match_times(np.asarray(times, dtype=float), frames)
    if rows.size != len(times):  # merge_times covers every time: a miss is a bug here
        raise AssertionError("frame times not covered by their union")
    return index


class FieldFrames:
    """The field frames of a run's ``fields.xdmf``, on the nodes of the mesh it was written
    on (the domain's non-periodic mesh): ``points`` (n, 2), ``triangles`` (n_triangles, 3),
    ``times`` (frames,). A context manager; :meth:`read` gives one frame's node arrays
    (``phi_sum``, ``label``, and ``phi_000``, ``phi_001``, … with ``output.per_particle_fields``)."""

    def __init__(self, path: Path) -> None:
        self._reader = meshio.xdmf.TimeSeriesReader(str(Path(path).resolve()))
        points, cells = self._reader.read_points_cells()
        self.points = points[:, :2]
        self.triangles = np.vstack([c.data for c in cells if c.type == "triangle"])
        self.times = np.array([float(e.find("Time").get("Value")) for e in self._reader.collection])

    def read(self, k: int) -> tuple[float, dict[str, np.ndarray]]:
        """(time, {name: node values}) of frame ``k`` (negative counts from the end)."""
        time, data, _ = self._reader.read_data(k % len(self.times))
        return float(time), {name: np.asarray(values).ravel() for name, values in data.items()}

    def close(self) -> None:
        self._reader.__exit__(None, None, None)

    def __enter__(self) -> "FieldFrames":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class RunData:
    """A run directory read back (see the module docstring).

    directory  the run directory
    scene      the resolved scene (scene.toml as a dict; {} when it is not there yet)
    info       run.json ({} when it is not there yet)
    time       (F,) frame times
    particles  particles.csv column → (F, N), NaN where the file lacks the row
    globals    global.csv column → (F,), NaN where the file lacks the frame
    """

    directory: Path
    scene: dict
    info: dict
    time: np.ndarray
    particles: dict[str, np.ndarray]
    globals: dict[str, np.ndarray]

    # -- the tables ---------------------------------------------------------------------
    @property
    def n_particles(self) -> int:
        return next(iter(self.particles.values())).shape[1] if self.particles else 0

    @property
    def x(self) -> np.ndarray:
        return self.particles["x"]

    @property
    def y(self) -> np.ndarray:
        return self.particles["y"]

    @property
    def elongation(self) -> np.ndarray:
        return self.particles["elongation"]

    @property
    def orientation(self) -> np.ndarray:
        return self.particles["orientation"]

    def complete(self) -> "RunData":
        """The run on the frames for which particles.csv lists every particle. A row is
        listed where any of its columns is a number: a vanished particle's row has NaN
        shape columns but its area (:func:`femphase.analysis.shape.present`)."""
        keep = np.zeros(0, bool)
        if self.particles:
            keep = np.any([np.isfinite(values) for values in self.particles.values()], axis=0).all(axis=1)
        return replace(self, time=self.time[keep], particles={k: v[keep] for k, v in self.particles.items()},
                       globals={k: v[keep] for k, v in self.globals.items()})

    # -- the scene ----------------------------------------------------------------------
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
        """γ̇ of the first phase with a flow where that flow is a linear shear, as the paper
        and the minimal model give it (u = γ̇ y/Ly, a velocity; a ``scale = "shear_rate"``
        flow's rate times Ly); None for other flows (the minimal model is of simple shear)
        and without flow."""
        index = self.flow_phase
        flow = None if index is None else self.scene["phases"][index]["flow"]
        if flow is None or flow.get("type") != "shear":
            return None
        return float(flow["rate"]) * (self.width if flow.get("scale") == "shear_rate" else 1.0)

    @property
    def radius(self) -> float:
        return float(self.scene.get("model", {}).get("radius", 8.0))

    @property
    def radii(self) -> np.ndarray:
        """(N,) target radii R_i (lattice units): ``particles.radii``, else the model's R."""
        given = self.scene.get("particles", {}).get("radii")
        return np.broadcast_to(np.asarray(self.radius if given is None else given, dtype=float), (self.n_particles,))

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
    def loaded_scene(self) -> Scene:
        """The run's :class:`~femphase.scene.Scene`, built from scene.toml (a meshed run's mesh
        file must still exist)."""
        with warnings.catch_warnings():  # the run itself warned about its resolution
            warnings.simplefilter("ignore", ResolutionWarning)
            try:
                return scene_from_dict(self.scene, self.directory)
            except SceneError as exc:  # which run's scene: compare reads two
                raise SceneError(exc.key, exc.value, f"{exc.valid} (in {self.directory / 'scene.toml'})") from None

    @property
    def domain(self) -> Domain:
        """The run's Domain (:attr:`loaded_scene`'s)."""
        return self.loaded_scene.domain

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
            if not (self.directory / "fields.xdmf").exists():
                raise
            with self.fields() as frames:
                points = frames.points
            return (float(points[:, 0].min()), float(points[:, 0].max()),
                    float(points[:, 1].min()), float(points[:, 1].max()))

    # -- analyses of the frames -----------------------------------------------------------
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

    def bulk_elongation(self, frames=slice(None)) -> np.ndarray:
        """r̄(t): the elongation averaged over the bulk particles (:meth:`bulk_particles`) at
        each of ``frames``, over those present (a vanished particle's elongation is NaN,
        :func:`femphase.analysis.shape.present`); NaN where none is."""
        return mean_present(self.elongation[frames][..., self.bulk_particles()], axis=-1)

    @cached_property
    def t1_times(self) -> np.ndarray:
        """Times of the T1 events after shear onset (empty for fewer than 3 particles)."""
        if self.n_particles < 3:
            return np.empty(0)
        frames = self.time >= self.shear_start - 1e-9
        centroids = np.stack([self.x[frames], self.y[frames]], axis=-1)
        return t1_event_times(list(centroids), self.time[frames], self.length)

    # -- field frames ---------------------------------------------------------------------
    def fields(self) -> FieldFrames:
        """The field frames of fields.xdmf (ValueError when the run wrote none)."""
        path = self.directory / "fields.xdmf"
        if not path.is_file():
            raise ValueError(f"run '{self.directory}' has no fields.xdmf (it was run with output.fields = false)")
        return FieldFrames(path)


def mean_present(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """The mean of ``values`` along ``axis`` (all of them for None) over the entries that are
    not NaN (a vanished particle's shape columns are, :func:`femphase.analysis.shape.present`);
    NaN where every entry is, without numpy's empty-slice warning."""
    values = np.asarray(values, dtype=float)
    counts = np.sum(~np.isnan(values), axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counts > 0, np.nansum(values, axis=axis) / counts, np.nan)
    return float(mean) if axis is None else mean


def _read_damaged(path: Path, kind: str, read):
    """``read(path)``; InputError naming the file where it cannot be read as ``kind`` (a
    damaged file in one run of many must be found by its path)."""
    try:
        return read(path)
    except (ValueError, StopIteration) as exc:  # StopIteration: a CSV without even a header
        raise InputError(f"{str(path)!r} is not a readable {kind} ({str(exc) or 'it is empty'}): the file is "
                         "damaged; rerun its run (or restore the file)") from None


#: The columns every run's tables have, by file (a table without them is damaged).
TABLE_KEYS = {"particles.csv": ("time", "id"), "global.csv": ("time",)}


def open_run(directory: str | Path, *, pending: bool = False) -> RunData:
    """Read a run directory written by ``femphase run``.

    ``pending=False`` (a finished or running run): FileNotFoundError when the directory does
    not exist or lacks scene.toml or particles.csv. ``pending=True`` (a sweep's run that may
    not have started): whatever is there, no frames when nothing is."""
    directory = Path(directory)
    if not pending:
        if not directory.is_dir():
            what = "is a file, not a directory" if directory.exists() else "does not exist"
            raise FileNotFoundError(f"run directory {str(directory)!r} {what}; expected the output "
                                    "directory of `femphase run SCENE -o DIR`")
        for name in ("scene.toml", "particles.csv"):
            if not (directory / name).is_file():
                raise FileNotFoundError(f"{str(directory)!r} is not a femphase run directory: it has no {name} "
                                        "(expected the output directory of `femphase run SCENE -o DIR`)")
    scene_path, info_path = directory / "scene.toml", directory / "run.json"
    scene = _read_damaged(scene_path, "TOML scene", lambda path: tomlio.loads(path.read_text())) \
        if scene_path.is_file() else {}
    info = _read_damaged(info_path, "JSON file", lambda path: json.loads(path.read_text())) \
        if info_path.is_file() else {}
    tables = {name: _read_damaged(directory / name, "CSV table of numbers", read_csv)
              if (directory / name).is_file() else {} for name in ("particles.csv", "global.csv")}
    for name, table in tables.items():
        missing = [key for key in TABLE_KEYS[name] if table and key not in table]
        if missing:
            raise InputError(f"{str(directory / name)!r} has no column {missing[0]!r} (its columns: "
                             f"{', '.join(table)}): the file is damaged; rerun its run (or restore the file)")
    rows, frame_rows = tables["particles.csv"], tables["global.csv"]
    time = merge_times(rows.get("time", np.empty(0)), frame_rows.get("time", np.empty(0)))
    globals_ = {}
    if frame_rows:
        at = frame_index(frame_rows["time"], time)
        for name, values in frame_rows.items():
            if name != "time":
                globals_[name] = np.full(time.size, np.nan)
                globals_[name][at] = values
    particles = {}
    if rows and rows["id"].size:
        at, ids = frame_index(rows["time"], time), rows["id"].astype(int)
        for name, values in rows.items():
            if name not in ("time", "id"):
                particles[name] = np.full((time.size, ids.max() + 1), np.nan)
                particles[name][at, ids] = values
    return RunData(directory, scene, info, time, particles, globals_)
