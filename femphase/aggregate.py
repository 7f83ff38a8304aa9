"""Aggregate a sweep directory: ``femphase aggregate DIR``, and ``femphase plot DIR`` on a sweep.

A sweep directory (written by ``femphase sweep SWEEP.toml -o DIR``) holds ``sweep.json``::

    {"format": "femphase-sweep", "version": 1, "mode": "product" | "zip",
     "axes": {key: [values, ...]},
     "runs": [{"id", "directory": "runs/<id>", "values": {key: value},
               "status": "pending" | "done" | "failed" | "interrupted", "error": str | null}]}

and one ordinary run directory per run (docs/outputs.md). Keys are ``--set`` scene keys
(``phases.1.flow.rate``); in product mode the runs cover the Cartesian product of the axes,
in zip mode run k takes the k-th value of every axis. Keys ending in ``.seed`` (e.g.
``particles.seed``) are *sample* axes: repetitions of one physical setting.

``femphase aggregate DIR`` writes

``sweep.nc``     one xarray Dataset (netCDF-4 through h5netcdf): dims = the sweep's (product
                 mode: one dim per axis, named by its key, its values as coordinate; zip
                 mode: one dim ``run`` with every axis as a coordinate along it) × ``time``
                 (the union of all runs' frame times, NaN where a run has no such frame) ×
                 ``particle`` (id; NaN beyond a run's N). Variables: every column of
                 global.csv (sweep × time) and of particles.csv (sweep × time × particle),
                 per run ``run_id``, ``status`` (sweep.json's), ``run_status`` (run.json's),
                 ``error``, and the summary columns below. Units and meanings are variable
                 attributes, from :data:`PARTICLE_COLUMNS`, :data:`GLOBAL_COLUMNS` and
                 :data:`SUMMARY_COLUMNS` (tests check them against docs/outputs.md).
``summary.csv``  one row per run: ``run_id``, the axis values, ``status``, ``run_status``,
                 ``error`` and :data:`SUMMARY_COLUMNS`.

The averaging window (:func:`averaging_window`): the paper averages Ψ6 and Ψ2^L over the
last 50 of the 250 frames of its shear phase. femphase averages over the last fifth of the
frames of the scene's last phase (those after its start; rounded up, at least one frame),
which is the same for the paper's protocol. A run that has not finished (status other than
"done") is averaged over the last fifth of the frames it has written in its last phase, and
NaN if it never reached it; its row says so in ``status``, ``window_start``/``window_end``.

``femphase plot DIR`` on a sweep directory draws the summary (:mod:`femphase.plot.sweep`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time as wallclock
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from femphase import __version__
from femphase.analysis.lattice import frame_average, t1_event_times
from femphase.errors import InputError
from femphase.io.files import atomic_write
from femphase.io.reader import TIME_TOLERANCE, RunData, frame_index, mean_present, merge_times, open_run
from femphase.io.rundir import Status
from femphase.oscillations import order_series, period_estimate

if TYPE_CHECKING:
    import xarray as xr

__all__ = ["AVERAGED_FRACTION", "DATASET", "GLOBAL_COLUMNS", "GLOBAL_RENAMES", "MODES", "PARTICLE_COLUMNS",
           "RUN_INPUTS", "SAMPLE_SUFFIX", "STATUSES", "SUMMARY", "SUMMARY_COLUMNS", "SWEEP_INDEX", "TEXT_COLUMNS",
           "Aggregate", "aggregate", "averaging_window", "build_dataset", "Column", "is_current", "last_phase_frames",
           "read_summary", "read_sweep", "summarise_run", "summary_csv", "Sweep", "SweepRun", "t1_rate",
           "write_aggregate"]


SWEEP_INDEX = "sweep.json"
DATASET = "sweep.nc"
SUMMARY = "summary.csv"
SWEEP_FORMAT, SWEEP_VERSION = "femphase-sweep", 1
MODES = ("product", "zip")
STATUSES = ("pending", "done", "failed", "interrupted")
#: An axis whose key ends like this repeats one setting with another random sample.
SAMPLE_SUFFIX = ".seed"
#: The fraction of the last phase's frames that the summary averages over (the paper: 50 of 250).
AVERAGED_FRACTION = 0.2
#: Files of a run directory that the aggregate is computed from (newer ones make it stale).
RUN_INPUTS = ("particles.csv", "global.csv", "run.json", "scene.toml")


@dataclass(frozen=True)
class Column:
    """A column's unit, as docs/outputs.md writes it ("—" for a pure number), and meaning."""

    unit: str
    meaning: str

    def attrs(self, source: str, column: str) -> dict[str, str]:
        """netCDF attributes: ``units`` ("1" for a pure number, CF's convention), ``long_name``,
        and where the values came from."""
        return {"units": "1" if self.unit == "—" else self.unit, "long_name": self.meaning,
                "source": f"{source} column {column}" if column else source}


#: particles.csv (docs/outputs.md, whose table tests/test_aggregate.py checks against this one).
PARTICLE_COLUMNS = {
    "x": Column("lattice units", "phi-weighted centroid x (circular mean over the period)"),
    "y": Column("lattice units", "phi-weighted centroid y"),
    "area": Column("lattice units²", "particle area: integral of phi_i^2"),
    "elongation": Column("—", "elongation r = lambda1/lambda2 - 1 of the shape tensor"),
    "orientation": Column("radians", "nematic angle of the elongation axis from x, in (-pi/2, pi/2]"),
    "wall_contact": Column("0 or 1", "1 when phi_i exceeds the window threshold on a wall dof"),
    "psi6_abs": Column("—", "|psi6_j|: bond order over the Delaunay neighbours"),
    "psi2_abs": Column("—", "|psi2_j|: nematic order of neighbouring elongation axes (e^{2i theta})"),
}
#: global.csv (docs/outputs.md).
GLOBAL_COLUMNS = {
    "step": Column("—", "steps completed since the start of the run"),
    "free_energy": Column("energy units", "discrete free energy F_h"),
    "interface": Column("energy units", "interface energy (double well + gradient)"),
    "area": Column("energy units", "area term's energy sum_i mu (1 - int phi_i^2 / pi R_i^2)^2"),
    "repulsion": Column("energy units", "repulsion energy over ordered pairs"),
    "Psi6": Column("—", "global bond order Psi6 = |mean_j psi6_j|"),
    "Psi2": Column("—", "global nematic order Psi2^L = |mean_j psi2_j| (e^{2i theta})"),
    "lattice_angle": Column("radians", "lattice angle of lanes sliding along x, in [pi/4, pi/3]"),
    "t1_count": Column("count", "running number of T1 events since the run started"),
}
#: global.csv columns renamed in the dataset: ``area`` is the particles' area there.
GLOBAL_RENAMES = {"area": "area_energy"}
#: summary.csv's measured columns (docs/aggregation.md). "window" is :func:`averaging_window`.
SUMMARY_COLUMNS = {
    "n_frames": Column("count", "frames the run has written"),
    "n_particles": Column("count", "particles of the run"),
    "window_frames": Column("count", "frames averaged: the last fifth of the last phase's frames"),
    "window_start": Column("time units", "time of the first frame averaged"),
    "window_end": Column("time units", "time of the last frame averaged"),
    "Psi6_mean": Column("—", "Psi6 averaged over the window's frames"),
    "Psi6_std": Column("—", "standard deviation (ddof = 0) of Psi6 over the window's frames"),
    "Psi2_mean": Column("—", "Psi2^L averaged over the window's frames"),
    "Psi2_std": Column("—", "standard deviation (ddof = 0) of Psi2^L over the window's frames"),
    "elongation_mean": Column("—", "elongation r of the bulk particles, averaged over them and the window"),
    "period": Column("time units", "period of the bulk-mean r(t) after shear onset; NaN if none is detectable"),
    "period_uncertainty": Column("time units", "one standard uncertainty of period, from its cycles"),
    "period_cycles": Column("count", "cycles (primary-peak intervals) the period was measured over"),
    "t1_rate": Column("1/(particle · time unit)", "T1 events per particle per time unit over the window"),
    "cpu_time_s": Column("s", "CPU time of the run's segments (run.json; a branched run's include the shared "
                              "relaxation's); NaN for runs written before femphase recorded it"),
}
#: Summary columns that count (written as integers).
_COUNTS = ("n_frames", "n_particles", "window_frames", "period_cycles")
#: Per-run text columns of summary.csv and the dataset.
TEXT_COLUMNS = ("status", "run_status", "error")


# -- the sweep index ---------------------------------------------------------------------
@dataclass(frozen=True)
class SweepRun:
    """One run of a sweep: its index entry and its place in the sweep's dims."""

    id: str
    directory: Path
    values: dict
    status: str
    error: str | None
    position: tuple[int, ...]


@dataclass(frozen=True)
class Sweep:
    """A sweep directory's index (sweep.json), checked."""

    directory: Path
    mode: str
    axes: dict[str, list]
    runs: list[SweepRun]

    @property
    def dims(self) -> tuple[str, ...]:
        return tuple(self.axes) if self.mode == "product" else ("run",)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.axes.values()) if self.mode == "product" else (len(self.runs),)

    @property
    def sample_keys(self) -> list[str]:
        return [key for key in self.axes if key.endswith(SAMPLE_SUFFIX)]


def read_sweep(directory: str | Path) -> Sweep:
    """Read and check ``DIR/sweep.json`` (module docstring). InputError naming the bad entry,
    its value and what is valid when the directory is not a sweep or the index is malformed."""
    directory = Path(directory)
    path = directory / SWEEP_INDEX
    if not path.is_file():
        what = ("does not exist" if not directory.exists() else "is a file, not a directory"
                if not directory.is_dir() else f"has no {SWEEP_INDEX}")
        raise InputError(f"sweep directory {str(directory)!r} {what}: expected the output directory of "
                         "`femphase sweep SWEEP.toml -o DIR`")
    try:
        index = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{str(path)!r} is not readable JSON ({exc})") from None
    if not isinstance(index, dict):
        raise InputError(f"{str(path)!r} holds {type(index).__name__}, expected a JSON object")

    def bad(entry: str, value: object, valid: str) -> InputError:
        return InputError(f"{str(path)!r}: {entry} = {value!r} is invalid: {valid}")

    if index.get("format") != SWEEP_FORMAT:
        raise bad("format", index.get("format"), f"{SWEEP_FORMAT!r}")
    if index.get("version") != SWEEP_VERSION:
        raise bad("version", index.get("version"), f"{SWEEP_VERSION} (the version this femphase reads)")
    mode, axes, runs = index.get("mode"), index.get("axes"), index.get("runs")
    if mode not in MODES:
        raise bad("mode", mode, " or ".join(repr(m) for m in MODES))
    if not isinstance(axes, dict) or not axes or not all(isinstance(v, list) and v for v in axes.values()):
        raise bad("axes", axes, "an object of scene keys, each with a non-empty list of values")
    lengths = {key: len(values) for key, values in axes.items()}
    if mode == "zip" and len(set(lengths.values())) > 1:
        raise bad("axes", lengths, "axes of equal length in zip mode")
    if not isinstance(runs, list):
        raise bad("runs", runs, "a list of runs")
    n_zip = next(iter(lengths.values()))
    if mode == "zip" and len(runs) != n_zip:
        raise bad("runs", f"{len(runs)} runs", f"{n_zip} runs, one per value of the zipped axes")
    checked, seen = [], {}
    for k, run in enumerate(runs):
        if not isinstance(run, dict) or not isinstance(run.get("id"), str) or not run["id"]:
            raise bad(f"runs[{k}]", run, "an object with a non-empty string id")
        values = run.get("values")
        if not isinstance(values, dict) or set(values) != set(axes):
            raise bad(f"runs[{k}].values", values, f"a value for each axis, {sorted(axes)}")
        if run.get("status") not in STATUSES:
            raise bad(f"runs[{k}].status", run.get("status"), ", ".join(STATUSES))
        if mode == "product":
            for key, value in values.items():
                if value not in axes[key]:
                    raise bad(f"runs[{k}].values[{key!r}]", value, f"one of the axis values {axes[key]}")
            position = tuple(axes[key].index(values[key]) for key in axes)
        else:
            position = (k,)
            for key, value in values.items():
                if value != axes[key][k]:
                    raise bad(f"runs[{k}].values[{key!r}]", value, f"{axes[key][k]!r}, the axis' value {k} (zip mode)")
        if position in seen:
            raise bad(f"runs[{k}].values", values, f"values of no other run (run {seen[position]!r} has them)")
        seen[position] = run["id"]
        directory_name = run.get("directory") or f"runs/{run['id']}"
        checked.append(SweepRun(run["id"], directory / directory_name, values, run["status"], run.get("error"),
                                position))
    return Sweep(directory, mode, dict(axes), checked)


# -- per-run summaries ---------------------------------------------------------------------
def last_phase_frames(time: np.ndarray, phases: list[dict]) -> np.ndarray:
    """Indices of the frames written during the last phase (``phases`` as in run.json's
    settings): those after its start; the frame at its start ends the phase before."""
    start = sum(float(phase["duration"]) for phase in phases[:-1])
    return np.flatnonzero(np.asarray(time) > start + TIME_TOLERANCE)


def averaging_window(time: np.ndarray, phases: list[dict]) -> np.ndarray:
    """Indices of the frames averaged: the last fifth (:data:`AVERAGED_FRACTION`, rounded up)
    of the frames of the last phase (:func:`last_phase_frames`). The paper's 250 frames of
    shear give its last 50. Empty when no frame is in the last phase."""
    in_last = last_phase_frames(time, phases)
    return in_last[in_last.size - math.ceil(AVERAGED_FRACTION * in_last.size):]


def t1_rate(run: RunData, window: np.ndarray) -> float:
    """T1 events per particle per time unit over the window, from the frame before the window
    (the window's first frame when it is the run's first) to its last frame, over N times
    that time span. NaN for fewer than 3 particles or an empty span.

    The events: the run's own running count (global.csv's ``t1_count``) when it counted
    between frames (its scene has ``output.t1_interval``: runs written since that key exists), else those
    found again from the frames' centroids (:func:`femphase.analysis.lattice.t1_event_times`),
    which miss flips that come and go between frames (docs/aggregation.md)."""

    if run.n_particles < 3 or window.size == 0:
        return float("nan")
    frames = np.arange(max(window[0] - 1, 0), window[-1] + 1)
    span = float(run.time[frames[-1]] - run.time[frames[0]])
    if span <= 0:
        return float("nan")
    count = run.globals.get("t1_count")
    if count is not None and "t1_interval" in run.scene.get("output", {}):
        events = float(count[frames[-1]] - count[frames[0]])
    else:
        centroids = np.stack([run.x[frames], run.y[frames]], axis=-1)
        events = t1_event_times(list(centroids), run.time[frames], run.length).size
    return events / (run.n_particles * span)


def summarise_run(run: RunData | None) -> dict[str, float]:
    """The :data:`SUMMARY_COLUMNS` of one run (NaN, and counts 0, for what it lacks).

    Ψ6 and Ψ2^L: global.csv's columns, or computed from particles.csv when the run did not
    write them (:func:`femphase.oscillations.order_series`), averaged with
    :func:`femphase.analysis.lattice.frame_average` over :func:`averaging_window`. Elongation:
    mean over the window and the bulk particles (farther than 2R from the walls at shear
    onset, :meth:`femphase.io.reader.RunData.bulk_particles`: at a wall r is not an aspect
    ratio). Period: :func:`femphase.oscillations.period_estimate`, the period of the bulk-mean r(t)
    after shear onset with its first quarter discarded, with its uncertainty and cycles, NaN
    (and 0 cycles) when none is detectable.
    T1 rate: :func:`t1_rate`. CPU time: run.json's ``cpu_time_s``."""
    out = {name: 0 if name in _COUNTS else float("nan") for name in SUMMARY_COLUMNS}
    if run is None:
        return out
    out["n_frames"], out["n_particles"] = len(run.time), run.n_particles
    out["cpu_time_s"] = float(run.info.get("cpu_time_s", float("nan")))
    period = period_estimate(run)
    if period is not None:
        out["period"], out["period_uncertainty"], out["period_cycles"] = (period.period, period.uncertainty,
                                                                          period.n_cycles)
    window = averaging_window(run.time, run.scene["phases"])
    if window.size == 0:
        return out
    out["window_frames"] = int(window.size)
    out["window_start"], out["window_end"] = float(run.time[window[0]]), float(run.time[window[-1]])
    series = order_series(run)
    for name in ("Psi6", "Psi2"):
        out[f"{name}_mean"], out[f"{name}_std"] = frame_average(series[name][window])
    # frames where every bulk particle has vanished are NaN and left out
    out["elongation_mean"] = mean_present(run.bulk_elongation(window))
    out["t1_rate"] = t1_rate(run, window)
    return out


# -- the sweep's dataset and summary table -----------------------------------------------------
@dataclass
class Aggregate:
    """A sweep's index, dataset (module docstring) and summary, one dict per run in index order."""

    sweep: Sweep
    dataset: xr.Dataset
    summary: list[dict]


def _run_status(directory: Path) -> str:
    info = Status.read(directory)
    return str(info.get("status", "")) if info else ""


def aggregate(directory: str | Path) -> Aggregate:
    """Read a sweep directory into a dataset and its per-run summary (nothing is written)."""
    sweep = read_sweep(directory)
    tables = {run.id: open_run(run.directory, pending=True) for run in sweep.runs}
    summary, completes = [], []
    for run in sweep.runs:
        row = {"run_id": run.id, **run.values, "status": run.status, "run_status": _run_status(run.directory),
               "error": run.error or ""}
        complete = tables[run.id].complete()
        row.update(summarise_run(complete if complete.scene and len(complete.time) else None))
        summary.append(row)
        completes.append(complete)
    _warn_short_runs(sweep, completes, summary)
    return Aggregate(sweep, build_dataset(sweep, tables, summary), summary)


def _warn_short_runs(sweep: Sweep, completes: list[RunData], summary: list[dict]) -> None:
    """Warn where sweep.json calls a run done but its directory does not hold a completed
    run's frames up to the scene's end: a run directory deleted, or its tables cut, after the
    sweep ran. Its row is kept as read (status "done", ``run_status``, ``n_frames``).
    ``completes``: each run's complete frames (:meth:`RunData.complete`), which its row summarises."""
    short = []
    for run, row, table in zip(sweep.runs, summary, completes):
        if run.status != "done":
            continue
        end = sum(float(phase["duration"]) for phase in table.scene.get("phases", [])) if table.scene else math.nan
        reached = float(table.time[-1]) if len(table.time) else math.nan
        # global.csv cut on its own leaves the particles' frames whole and its columns NaN
        rows = np.any([np.isfinite(values) for values in table.globals.values()], axis=0) if table.globals else None
        globals_reached = float(table.time[np.flatnonzero(rows)[-1]]) if rows is not None and rows.any() else math.nan
        tolerance = TIME_TOLERANCE * max(1.0, abs(end))
        if not run.directory.is_dir():
            short.append(f"{run.id} (its directory is gone)")
        elif row["run_status"] != "completed" or not reached >= end - tolerance:
            short.append(f"{run.id} (run.json: {row['run_status'] or 'missing'}, frames to t = {reached:g} of {end:g})")
        elif rows is not None and not globals_reached >= end - tolerance:
            short.append(f"{run.id} (global.csv's rows to t = {globals_reached:g} of {end:g})")
    if short:
        warnings.warn(f"sweep.json calls {len(short)} run{'s' if len(short) > 1 else ''} done whose directories do "
                      "not hold a completed run "
                      f"(deleted or cut after the sweep ran): {'; '.join(short)}. Their rows are as read; delete "
                      "those run directories and rerun femphase sweep on this directory, which redoes them, then "
                      "aggregate again", stacklevel=3)


def _coordinate(values: list) -> np.ndarray:
    """An axis' values as a netCDF-writable coordinate (JSON text for lists and tables)."""
    if all(isinstance(v, (bool, int, float, str)) for v in values):
        return np.asarray(values)
    return np.asarray([json.dumps(v) for v in values])


def build_dataset(sweep: Sweep, tables: dict[str, RunData], summary: list[dict]) -> xr.Dataset:
    """The sweep's Dataset (module docstring) from its runs' tables and summary rows."""
    import xarray as xr

    time = merge_times(*(t.time for t in tables.values()))
    n_particles = max((t.n_particles for t in tables.values()), default=0)
    dims, shape = sweep.dims, sweep.shape
    variables: dict[str, tuple] = {}

    def fill(name: str, extra_dims: tuple[str, ...], extra_shape: tuple[int, ...], attrs: dict, dtype=float):
        if name not in variables:
            empty = np.full(shape + extra_shape, np.nan if dtype is float else ("" if dtype is str else 0),
                            dtype=object if dtype is str else dtype)
            variables[name] = (dims + extra_dims, empty, attrs)
        return variables[name][1]

    particle_names = {c for t in tables.values() for c in t.particles}
    for run in sweep.runs:
        run_tables = tables[run.id]
        frames = frame_index(run_tables.time, time) if run_tables.time.size else np.empty(0, int)
        for column, values in run_tables.globals.items():
            name = GLOBAL_RENAMES.get(column, column)
            if name in particle_names:  # a scene's own energy term named like a particle column
                name = f"{name}_global"
            # a column not in the table is a scene's own energy term (docs/outputs.md)
            known = GLOBAL_COLUMNS.get(column, Column("energy units", f"energy term {column}"))
            fill(name, ("time",), (time.size,), known.attrs("global.csv", column))[run.position][frames] = values
        for column, values in run_tables.particles.items():
            known = PARTICLE_COLUMNS.get(column, Column("unknown", f"{column}: a column of the scene's own observable"))
            target = fill(column, ("time", "particle"), (time.size, n_particles), known.attrs("particles.csv", column))
            target[run.position][frames, : values.shape[1]] = values
    by_position = {run.position: row for run, row in zip(sweep.runs, summary)}
    run_attrs = {"run_id": "the run's id in sweep.json (its directory is runs/<id>)",
                 "status": "the run's status in sweep.json (pending, done, failed, interrupted)",
                 "run_status": "status in the run's run.json (running, completed, failed, interrupted)",
                 "error": "the run's error in sweep.json"}
    for name, meaning in run_attrs.items():
        source = "run.json" if name == "run_status" else "sweep.json"
        target = fill(name, (), (), {"long_name": meaning, "source": source}, dtype=str)
        for position, row in by_position.items():
            target[position] = row[name]
    for name, column in SUMMARY_COLUMNS.items():
        target = fill(name, (), (), column.attrs("summary", ""), dtype=int if name in _COUNTS else float)
        for position, row in by_position.items():
            target[position] = row[name]
    coords: dict[str, object] = {"time": ("time", time, {"units": "time units", "long_name": "frame time"}),
                                 "particle": ("particle", np.arange(n_particles),
                                              {"long_name": "particle id (particles.csv column id)"})}
    if sweep.mode == "product":
        for key, values in sweep.axes.items():
            coords[key] = (key, _coordinate(values), {"long_name": f"swept scene key {key}"})
    else:
        coords["run"] = ("run", np.arange(len(sweep.runs)), {"long_name": "run index in sweep.json (zip mode)"})
        for key, values in sweep.axes.items():
            coords[key] = ("run", _coordinate(values), {"long_name": f"swept scene key {key}"})
    dataset = xr.Dataset({name: xr.Variable(*spec) for name, spec in variables.items()},
                         coords={name: xr.Variable(*spec) for name, spec in coords.items()})
    dataset.attrs.update({
        "title": f"femphase sweep {sweep.directory.resolve().name}",
        "sweep": str(sweep.directory.resolve()),
        "sweep_mode": sweep.mode,
        "sweep_axes": json.dumps(sweep.axes),
        "sample_axes": json.dumps(sweep.sample_keys),
        "femphase_version": __version__,
        "created": wallclock.strftime("%Y-%m-%dT%H:%M:%SZ", wallclock.gmtime()),
        "averaging": "summary variables: the last fifth of the frames of each run's last phase "
                     "(docs/aggregation.md)",
    })
    return dataset


# -- files -------------------------------------------------------------------------------------
def _cell(value: object) -> str:
    """summary.csv's text of a value: numbers as Python writes them back exactly (NaN as
    "nan", which numpy, pandas and :func:`read_summary` read), lists and tables as JSON."""
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return str(value).lower()
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return json.dumps(value)


def summary_csv(summary: list[dict], keys: list[str]) -> str:
    """summary.csv's text: one row per run (module docstring)."""
    columns = ["run_id", *keys, *TEXT_COLUMNS, *SUMMARY_COLUMNS]
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(columns)
    for row in summary:
        writer.writerow([_cell(row[column]) for column in columns])
    return text.getvalue()


def read_summary(path: str | Path) -> list[dict]:
    """summary.csv's rows as dicts: text columns as strings, the rest as floats where they are
    numbers (an axis of strings stays strings)."""
    def value(column: str, text: str) -> object:
        if column == "run_id" or column in TEXT_COLUMNS:
            return text
        try:
            return float(text)
        except ValueError:
            return text

    with Path(path).open(newline="") as handle:
        return [{column: value(column, text) for column, text in row.items()} for row in csv.DictReader(handle)]


def is_current(sweep: Sweep) -> bool:
    """sweep.nc and summary.csv exist and are newer than sweep.json and every run's inputs.
    Their modification time is 50 ms before :func:`write_aggregate` began to read, so that
    an input that changed while it read (a sweep finishing a run) makes them stale."""
    outputs = [sweep.directory / DATASET, sweep.directory / SUMMARY]
    if not all(path.is_file() for path in outputs):
        return False
    written = min(path.stat().st_mtime_ns for path in outputs)
    inputs = [sweep.directory / SWEEP_INDEX] + [run.directory / name for run in sweep.runs for name in RUN_INPUTS]
    return all(path.stat().st_mtime_ns <= written for path in inputs if path.is_file())


def write_aggregate(directory: str | Path) -> dict[str, Path]:
    """Write DIR/sweep.nc and DIR/summary.csv (each replaced atomically); returns their paths."""

    directory = Path(directory)
    # 50 ms early: file times come from the kernel's coarse clock, which can stand a tick
    # (up to 10 ms) behind this one, so an input written just after this line could seem older
    began = wallclock.time_ns() - 50_000_000
    result = aggregate(directory)
    paths = {"dataset": directory / DATASET, "summary": directory / SUMMARY}
    tmp = paths["dataset"].with_name(f".{DATASET}.tmp")
    result.dataset.to_netcdf(tmp, engine="h5netcdf")
    os.replace(tmp, paths["dataset"])
    atomic_write(paths["summary"], summary_csv(result.summary, list(result.sweep.axes)))
    for path in paths.values():  # as of when the inputs were read (is_current)
        os.utime(path, ns=(began, began))
    return paths
