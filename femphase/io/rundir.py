"""Run directories that never lose data: atomic frame-by-frame output, refusals, resumes.

DIR/ ::

  scene.toml         the resolved scene of the latest segment (every default filled in)
  particles.csv      one row per particle per frame (columns: docs/outputs.md)
  global.csv         one row per frame
  fields.xdmf        the field frames, opens in ParaView; rewritten (atomically) every frame
  fields/mesh.h5     the non-periodic mesh the fields live on
  fields/frame_NNNNNN.h5   one file per frame: phi_sum, phi_max, label (+ phi_000 … with
                     output.per_particle_fields), written to a temporary name and renamed
  checkpoint.h5      the last checkpoint (:func:`femphase.io.checkpoints.save_checkpoint`), with the
                     scene that wrote it and the size of every output at that moment
  run.json           status ("running", "completed", "failed", "interrupted"), progress,
                     start and end times, and the history of segments (one per start or
                     resume, each with its command line, wall time and provenance:
                     versions, host, threads); with the adaptive scheme, ``substeps``: per
                     phase, the accepted, rejected and capped substeps; replaced
                     atomically at every frame
  run.log            the log (:class:`RunLog`): a header line per segment, status lines,
                     warnings, how each segment ended; appended, never cut
  .femphase.lock     held (``flock``) by the process writing the run: a second ``femphase
                     run`` into the directory (a resume, an overwrite) is refused while it
                     runs; holds that process's pid and host

Guarantees. Every file is either appended (the CSVs, flushed at every frame) or replaced
atomically (write to a temporary name, then ``os.replace``), so a kill at any instant leaves
every file either as it was or as it will be (and at most a hidden partial file
``.NAME.tmp`` beside it, which the next write replaces and ``--overwrite`` deletes); the
checkpoint records the byte length of each CSV and the number of field frames when it was
written. ``--resume`` cuts every output back
to that record and continues from the checkpoint, so after any sequence of kills, interrupts
and resumes the outputs equal those of an uninterrupted run (bit for bit: the stepping is
deterministic). A frame's outputs are written before its checkpoint, so at most the frames
after the last checkpoint are lost. run.json and run.log record wall times and hosts, so
they differ between runs; they are not among the outputs a resume reproduces.
"""

from __future__ import annotations

import datetime
import json
import logging
import os
import time as wallclock
import warnings
from pathlib import Path
from typing import Iterable
from xml.sax.saxutils import escape

import numpy as np

from femphase import tomlio
from femphase.errors import OutputWarning, SceneError
from femphase.io.files import (
    FileLock,
    atomic_write,
    ensure_room,
    failpoint,
    jsonable,
    output_directory,
    partial_path,
    writable_directory,
)
from femphase.io.provenance import now
from femphase.model.parameters import PAPER_SYMBOLS

__all__ = ["CHECKPOINT", "COMPARISON", "COMPARISON_DIR", "FIELDS_DIR", "FIGURES", "FIGURES_DIR", "FROZEN_TABLES", "LOCK", "OUTPUTS", "RUN_LOG", "Outputs", "RunLog",
           "Status", "frame_time", "prepare_directory", "resume_position"]

CHECKPOINT = "checkpoint.h5"
RUN_LOG = "run.log"
#: The lock file of the process writing a run (:func:`prepare_directory`); never deleted.
LOCK = ".femphase.lock"
#: Where ``femphase plot`` and ``femphase compare`` write by default inside a run directory:
#: they describe its run, so ``--overwrite`` deletes their files with it (:data:`FIGURES`,
#: :data:`COMPARISON`), and other files there stay.
FIGURES_DIR = "figures"
COMPARISON_DIR = "compare"
#: The figures ``femphase plot`` writes into ``figures/``, each in any format (``NAME.png`` …).
FIGURES = ("snapshot", "elongation", "limit_cycle", "order")
#: The files ``femphase compare`` writes into its output folder.
COMPARISON = ("compare.csv", "compare.json", "compare.png")
#: Everything femphase writes into a run directory (``--overwrite`` deletes only these).
OUTPUTS = ("scene.toml", "particles.csv", "global.csv", "fields.xdmf", "fields", CHECKPOINT, "run.json", RUN_LOG)
FIELDS_DIR = "fields"
#: The field folder's mesh file, and its frame files (:func:`frame_file`) as a glob pattern.
MESH_FILE = "mesh.h5"
FRAME_FILES = "frame_[0-9][0-9][0-9][0-9][0-9][0-9].h5"


def frame_file(index: int) -> str:
    """The name of field frame ``index`` (from 0) in the field folder."""
    return f"frame_{index:06d}.h5"
#: The package logger (as :data:`femphase.run.trackers.LOGGER`; that module imports the simulation,
#: which imports this one).
_LOGGER = logging.getLogger("femphase")


def frame_time(time: float) -> float:
    """``time`` as the outputs give it (the CSVs, the field frames, run.json): to 12
    significant digits. The clock adds dt step by step, to the last bit as a run step by
    step would (the checkpoint keeps it so); written as it is, ten steps of 0.1 made
    0.9999999999999999 and a filter ``time == 1.0`` found nothing."""
    return float(f"{time:.12g}")


def _written_without_checkpoints(directory: Path) -> bool:
    """Whether the run's scene.toml sets output.checkpoint = false (False when unreadable)."""
    try:
        return tomlio.loads((directory / "scene.toml").read_text(encoding="utf-8"))["output"]["checkpoint"] is False
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError):
        return False


def prepare_directory(directory: Path, *, resume: bool, overwrite: bool) -> FileLock:
    """Create the run directory, or check that an existing one may be used, and take its
    lock (:data:`LOCK`); nothing is written or removed before every check has passed.
    Returns the lock, held: the caller releases it when the run ends.

    A directory holding femphase outputs is refused unless ``resume`` (continue it) or
    ``overwrite`` (delete femphase's files in it, and only those: :data:`OUTPUTS`, and the
    figures and comparisons of the run replaced in :data:`FIGURES_DIR` and
    :data:`COMPARISON_DIR`); a directory another process is running in is refused either way
    (two resumes of one run would append every frame twice; an overwrite would delete the
    files of the run under way)."""
    directory = output_directory(directory)
    existing = [name for name in OUTPUTS if (directory / name).exists()]
    if resume:
        if not (directory / CHECKPOINT).is_file():
            why = ("; this run was written with output.checkpoint = false, so it cannot be continued: rerun it "
                   "with --overwrite" if _written_without_checkpoints(directory) else
                   " (it does not exist: start the run without --resume)" if not directory.exists() else
                   f" ({CHECKPOINT} there is not a file)" if (directory / CHECKPOINT).exists() else
                   f" (it has {', '.join(existing) or 'no femphase output'}"
                   + ("; a run stopped before its first checkpoint is replaced with --overwrite)" if existing else ")"))
            raise SceneError("--resume", str(directory), f"a run directory that holds {CHECKPOINT}{why}")
    elif existing and not overwrite:
        advice = ("continue it with --resume or replace it with --overwrite" if (directory / CHECKPOINT).is_file()
                  else f"replace it with --overwrite (it has no {CHECKPOINT} to continue from: it stopped before "
                  "its first)")
        raise SceneError("-o", str(directory), f"a directory without a run (it holds one: {', '.join(existing)}); "
                         + advice)
    if (directory / "sweep.json").is_file():  # a run's files among a sweep's would be read as neither
        raise SceneError("-o", str(directory), "a directory that is not a sweep's: it holds sweep.json; a sweep's "
                         "runs are in its runs/<id>/, run by femphase sweep")
    writable_directory(directory)
    lock = FileLock(directory / LOCK)
    try:
        taken = lock.acquire(blocking=False)
    except OSError as exc:
        raise SceneError("-o", str(directory), f"a directory femphase can lock ({exc.strerror or exc})") from None
    if not taken:
        raise SceneError("-o", str(directory), f"a directory no other femphase process is writing to: {lock.holder()} "
                         "is running a run there; wait for it to end, or stop it with Ctrl-C or kill (it keeps its "
                         "last checkpoint)")
    if overwrite and not resume:
        files, folders = _own_files(directory)
        for path in files:
            path.unlink()
        for folder in folders:  # emptied of femphase's files; a user's files keep it
            if not any(folder.iterdir()):
                folder.rmdir()
    return lock


def _own_files(directory: Path) -> tuple[list[Path], list[Path]]:
    """(files, folders): what femphase wrote into a run directory, by name, for
    ``--overwrite`` to delete (:data:`OUTPUTS`, the field frames, the figures and comparison
    in :data:`FIGURES_DIR` and :data:`COMPARISON_DIR`, and the partial files a killed run leaves, :func:`partial_path`);
    other files in those folders are the user's and stay. SceneError, before anything is
    deleted, where one of those names is not a file."""
    fields = [MESH_FILE, FRAME_FILES]
    derived = {FIGURES_DIR: [f"{name}.*" for name in FIGURES], COMPARISON_DIR: list(COMPARISON),
               FIELDS_DIR: fields + [partial_path(Path(name)).name for name in fields]}
    files = [path for name in OUTPUTS if name != FIELDS_DIR
             for path in (directory / name, partial_path(directory / name)) if path.exists()]
    folders = [directory / name for name in derived if (directory / name).is_dir()]
    files += [path for folder in folders for pattern in derived[folder.name] for path in sorted(folder.glob(pattern))]
    odd = [path for path in files if not path.is_file()]
    if odd:
        raise SceneError("--overwrite", str(directory), f"a run directory whose femphase outputs are files: "
                         f"{odd[0].relative_to(directory)} is not one (nothing was deleted)")
    return files, folders


class Outputs:
    """The appendable outputs of a run directory: the two CSVs and the field frames."""

    def __init__(self, directory: Path, particle_columns: list[str], global_columns: list[str],
                 fields: bool = True) -> None:
        """``fields``: the run writes field frames (fields.xdmf and fields/)."""
        self.directory = Path(directory)
        self.fields = fields
        self.columns = {"particles.csv": ["time", "id"] + list(particle_columns),
                        "global.csv": ["time", "step"] + list(global_columns)}
        self.field_times: list[float] = []
        self._handles: dict[str, object] = {}
        self._frame_datasets: dict[int, list[str] | None] = {}  # of frames written by earlier segments

    # -- opening ------------------------------------------------------------------------
    def start_new(self, mesh) -> None:
        for name, columns in self.columns.items():
            atomic_write(self.directory / name, ",".join(columns) + "\n")
        if self.fields:
            self._write_mesh(mesh)
            self._write_xdmf(mesh)
        self._open()

    def start_from(self, record: dict, mesh) -> None:
        """Cut every output back to ``record`` (what a checkpoint saw) and reopen them."""
        sizes = {}
        for name, columns in self.columns.items():  # every check before any cut
            path = self.directory / name
            sizes[path] = size = int(record["bytes"][name])
            if not path.is_file() or path.stat().st_size < size:
                raise SceneError("--resume", str(path), f"a file of at least {size} bytes, as when the checkpoint "
                                 "was written (the run directory was changed since)")
            with open(path, "rb") as handle:
                written = handle.readline().decode(errors="replace").rstrip("\n").split(",")
            if written != columns:
                missing, extra = [c for c in columns if c not in written], [c for c in written if c not in columns]
                raise SceneError("--resume", str(path), f"a CSV with the columns this run writes, {columns}; the "
                                 f"file lacks {missing} and has {extra} besides: output.observables, and the free "
                                 "energy's terms given from Python, must stay as the run started")
        for path, size in sizes.items():
            os.truncate(path, size)
        self.field_times = [float(t) for t in record["field_times"]]
        fields = self.directory / FIELDS_DIR
        if fields.is_dir():
            for child in fields.glob(FRAME_FILES):
                if int(child.stem.split("_")[1]) >= len(self.field_times):
                    child.unlink()
        if self.fields or self.field_times:
            if not (fields / MESH_FILE).is_file():
                self._write_mesh(mesh)
            self._write_xdmf(mesh)
        self._open()

    def _open(self) -> None:
        self._handles = {name: open(self.directory / name, "a", newline="") for name in self.columns}

    def record(self) -> dict:
        """The size of every output now (stored in checkpoints)."""
        return {"bytes": {name: handle.tell() for name, handle in self._handles.items()},
                "field_times": list(self.field_times)}

    # -- appending ----------------------------------------------------------------------
    def append_rows(self, name: str, rows: Iterable[Iterable]) -> None:
        handle = self._handles[name]
        text = "".join(",".join(_cell(v) for v in row) + "\n" for row in rows)
        half = len(text) // 2
        handle.write(text[:half])
        handle.flush()
        failpoint("csv")  # a kill here leaves half a frame's rows: resume must cut them
        handle.write(text[half:])
        handle.flush()

    def append_fields(self, time: float, data: dict[str, np.ndarray], mesh) -> None:
        import h5py

        index = len(self.field_times)
        path = self.directory / FIELDS_DIR / frame_file(index)
        ensure_room(path, data.values(), time)
        tmp = partial_path(path)
        with h5py.File(tmp, "w") as handle:
            handle.attrs["time"] = time
            for name, values in data.items():
                handle[name] = values
        failpoint("fields")
        os.replace(tmp, path)
        self.field_times.append(float(time))
        self._write_xdmf(mesh, sorted(data))  # sorted, as h5py lists a file's datasets

    def close(self) -> None:
        for handle in self._handles.values():
            handle.close()
        self._handles = {}

    # -- the field files ----------------------------------------------------------------
    def _write_mesh(self, mesh) -> None:
        import h5py

        folder = self.directory / FIELDS_DIR
        folder.mkdir(exist_ok=True)
        tmp = partial_path(folder / MESH_FILE)
        with h5py.File(tmp, "w") as handle:
            handle["points"] = np.vstack([mesh.p, np.zeros(mesh.p.shape[1])]).T
            handle["triangles"] = mesh.t.T.astype(np.int64)
        os.replace(tmp, folder / MESH_FILE)

    def _write_xdmf(self, mesh, names: list[str] | None = None) -> None:
        """fields.xdmf: the mesh, then one grid per frame referring to its frame file."""
        n_points, n_cells = mesh.p.shape[1], mesh.t.shape[1]
        grids = []
        for index, time in enumerate(self.field_times):
            frame = f"{FIELDS_DIR}/{frame_file(index)}"
            datasets = self._frame_names(index, names)
            if datasets is None:  # lost: left out, the other frames still open
                continue
            attributes = "".join(
                f'<Attribute Name="{escape(name)}" AttributeType="Scalar" Center="Node">'
                f'<DataItem DataType="Float" Dimensions="{n_points}" Format="HDF" Precision="8">'
                f"{frame}:/{escape(name)}</DataItem></Attribute>"
                for name in datasets)
            grids.append(
                '<Grid><xi:include xpointer="xpointer(//Grid[@Name=&quot;mesh&quot;]/*[self::Topology or '
                f'self::Geometry])" /><Time Value="{time!r}" />{attributes}</Grid>')
        xdmf = (
            '<Xdmf xmlns:xi="http://www.w3.org/2003/XInclude" Version="3.0"><Domain>'
            '<Grid Name="TimeSeries_femphase" GridType="Collection" CollectionType="Temporal">'
            + "".join(grids) + "</Grid>"
            '<Grid Name="mesh" GridType="Uniform"><Geometry GeometryType="XYZ">'
            f'<DataItem DataType="Float" Dimensions="{n_points} 3" Format="HDF" Precision="8">'
            f"{FIELDS_DIR}/{MESH_FILE}:/points</DataItem></Geometry>"
            f'<Topology TopologyType="Triangle" NumberOfElements="{n_cells}">'
            f'<DataItem DataType="Int" Dimensions="{n_cells} 3" Format="HDF" Precision="8">'
            f"{FIELDS_DIR}/{MESH_FILE}:/triangles</DataItem></Topology></Grid></Domain></Xdmf>\n")
        atomic_write(self.directory / "fields.xdmf", xdmf)

    def _frame_names(self, index: int, names: list[str] | None) -> list[str] | None:
        """The datasets of frame ``index`` (read from its file for frames of earlier segments);
        None, with a warning once, for a frame file that is missing or damaged: a resumed run
        goes on, and fields.xdmf leaves that frame out."""
        if names is not None and index == len(self.field_times) - 1:
            return names
        if index not in self._frame_datasets:
            import h5py

            path = self.directory / FIELDS_DIR / frame_file(index)
            try:
                with h5py.File(path, "r") as handle:
                    self._frame_datasets[index] = list(handle)
            except OSError:
                self._frame_datasets[index] = None
                state = "is missing" if not path.exists() else "cannot be read as HDF5 (truncated or overwritten)"
                warnings.warn(f"the field frame {path} (t = {self.field_times[index]:g}) {state}; the run goes on, "
                              "and fields.xdmf leaves that frame out", OutputWarning, stacklevel=2)
        return self._frame_datasets[index]


def _cell(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return repr(float(value))


#: Scene tables a resumed run must keep (any change would make the state meaningless).
FROZEN_TABLES = ("model", "domain", "particles")
#: Keys of those tables that may change on resume: the mesh file's path, which changes when
#: a run directory or a sweep moves to another folder or machine. Its content may not: the
#: checkpoint records the mesh's checksum, and :func:`femphase.io.checkpoints.load_checkpoint`
#: refuses another mesh, naming it.
MOVABLE = {("domain", "mesh")}


#: Parameter name → the paper's symbol, which scenes accept as well (model.mu for
#: model.area_stiffness): a refusal names both.
_PAPER_NAMES = {name: symbol for symbol, name in PAPER_SYMBOLS.items()}


def resume_position(saved: dict, scene: dict, time: float) -> tuple[int, int, list[str]]:
    """Where a run saved at ``time`` by a scene ``saved`` (its resolved dict) continues under
    ``scene``: (phase, steps done in it, the changes as "key: old → new").

    Compatible changes: the mesh file's path (:data:`MOVABLE`; not its content), numerics
    (but the diagonals), output cadence and fields, the dt, duration and frame interval of
    the phase under way (the time already spent in it must be a whole number of new steps
    and within the new duration), anything of later phases, longer or additional phases
    (extending a finished run). Refused, with a SceneError naming the key: the model, domain
    and particles, numerics.diagonals, output.observables, and the duration or flow of
    phases already done or the flow of the phase under way, and the dt or frame interval of
    phases done and not extended (the run's scene.toml would describe steps it never took)."""
    changes = [f"name: {saved.get('name')!r} → {scene.get('name')!r}"] if saved.get("name") != scene.get("name") else []
    for table in FROZEN_TABLES:
        old, new = saved.get(table, {}), scene.get(table, {})
        for key in sorted(set(old) | set(new)):
            if old.get(key) == new.get(key):
                continue
            if (table, key) not in MOVABLE:
                symbol = _PAPER_NAMES.get(key) if table == "model" else None  # the spelling a user may have typed
                named = f"{table}.{key}" + (f" (model.{symbol})" if symbol else "")
                raise SceneError(named, new.get(key), f"{old.get(key)!r} as in the checkpoint: a resumed "
                                 f"run cannot change its {table} (start a new run directory instead)")
            changes.append(f"{table}.{key}: {old.get(key)!r} → {new.get(key)!r}")
    for table, frozen in (("numerics", ("diagonals",)), ("output", ("observables",))):
        old, new = saved.get(table, {}), scene.get(table, {})
        for key in sorted(set(old) | set(new)):
            if old.get(key) == new.get(key):
                continue
            if key in frozen:
                raise SceneError(f"{table}.{key}", new.get(key), f"{old.get(key)!r} as in the checkpoint: it cannot "
                                 "change on resume")
            changes.append(f"{table}.{key}: {old.get(key)!r} → {new.get(key)!r}")
    old_phases, new_phases = saved.get("phases", []), scene["phases"]
    tolerance = 1e-9 * max(1.0, abs(time))
    start = 0.0
    for k, old in enumerate(old_phases):
        end = start + old["duration"]
        if start > time - tolerance and not (k == 0 and time <= tolerance):
            break
        if k >= len(new_phases):
            raise SceneError("phases", len(new_phases), f"at least {k + 1} phases: phase {k} was under way or done "
                             f"at t = {time:g}")
        new = new_phases[k]
        if new.get("flow") != old.get("flow") and time > start + tolerance:
            raise SceneError(f"phases.{k}.flow", new.get("flow"), f"{old.get('flow')!r} as in the checkpoint: "
                             f"phase {k} already ran with that flow until t = {min(end, time):g}")
        if end < time - tolerance and abs(new["duration"] - old["duration"]) > tolerance:
            raise SceneError(f"phases.{k}.duration", new["duration"], f"{old['duration']:g} as in the checkpoint: "
                             f"phase {k} ended at t = {end:g}, before the checkpoint (t = {time:g})")
        if end >= time - tolerance and new["duration"] < time - start - tolerance:  # under way, or just ended
            raise SceneError(f"phases.{k}.duration", new["duration"], f"at least {time - start:g}: phase {k} has "
                             f"already run {time - start:g} time units (t = {time:g}); a run is not shortened "
                             "(start a new run directory for a shorter one)")
        if start + new["duration"] <= time + tolerance:  # done, and not extended: nothing of it runs again
            for key in ("dt", "frame_interval"):
                if new[key] != old[key]:
                    raise SceneError(f"phases.{k}.{key}", new[key], f"{old[key]:g} as in the checkpoint: phase {k} "
                                     f"ran with it until t = {min(end, time):g} and does not run again")
        start = end
    for k, (old, new) in enumerate(zip(old_phases, new_phases)):
        for key in ("name", "duration", "dt", "frame_interval", "flow"):
            if old.get(key) != new.get(key):
                changes.append(f"phases.{k}.{key}: {old.get(key)!r} → {new.get(key)!r}")
    if len(new_phases) != len(old_phases):
        changes.append(f"phases: {len(old_phases)} → {len(new_phases)}")
    start = 0.0
    for k, phase in enumerate(new_phases):
        end = start + phase["duration"]
        if time < end - tolerance:
            steps = (time - start) / phase["dt"]
            if abs(steps - round(steps)) > 1e-6 * max(1.0, steps):
                raise SceneError(f"phases.{k}.dt", phase["dt"], f"a step that divides the {time - start:g} time units "
                                 f"phase {k} has already run (t = {time:g})")
            return k, round(steps), changes
        start = end
    return len(new_phases), 0, changes


class Status:
    """run.json: the run's status, times and history of segments, replaced atomically.

    ``base``: the fields of this segment's run (version, method, scene); ``previous``: the
    run.json of a resumed run, whose segments and start time are kept. Times are ISO 8601
    with the UTC offset (:func:`femphase.io.provenance.now`), wall and CPU times in seconds (CPU:
    the process's, all its threads, so that a run's cost can be read off on a loaded machine
    where wall time is not)."""

    def __init__(self, directory: Path, base: dict, previous: dict | None) -> None:
        self.path = Path(directory) / "run.json"
        previous = previous or {}
        self.data = dict(base)
        self.data["segments"] = list(previous.get("segments", []))
        # one reading for the run's and its segment's start: two could straddle a second
        # (a run's first segment then seemed to start after the run)
        self.opened = now()
        self.data["started"] = previous.get("started") or self.opened
        self.data["ended"] = None
        self.started, self.cpu_started = wallclock.perf_counter(), wallclock.process_time()

    @staticmethod
    def read(directory: Path) -> dict | None:
        path = Path(directory) / "run.json"
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            return None

    def begin_segment(self, segment: dict) -> None:
        self.data["segments"].append({**segment, "started": self.opened, "ended": None, "status": "running"})

    def update(self, **values) -> None:
        """Set top-level fields (``status`` among them: a status other than "running" ends
        the segment, with its end time) and write run.json."""
        self.data.update(values)
        segment = self.data["segments"][-1]
        segment["wall_time_s"] = wallclock.perf_counter() - self.started
        segment["cpu_time_s"] = wallclock.process_time() - self.cpu_started
        segment["time"], segment["step"] = self.data.get("time"), self.data.get("steps")
        if values.get("status", "running") != "running":
            segment["status"] = values["status"]
            segment["ended"] = self.data["ended"] = now()
        for key in ("wall_time_s", "cpu_time_s"):  # runs from before CPU times were recorded lack them
            self.data[key] = sum(s.get(key, 0.0) for s in self.data["segments"])
        atomic_write(self.path, json.dumps(self.data, indent=2, default=jsonable) + "\n")


class RunLog:
    """run.log: the records of the ``femphase`` logger (INFO and above) while a run writes
    its directory, appended (a resumed run continues the file; nothing cuts it, so a kill
    may leave a partial last line). Each segment starts with a header line ``=== segment K
    …`` and ends with a line saying how it ended (ERROR for a failure, with the step and
    time). Lines: ISO 8601 time with UTC offset, level, message.

    While open, the femphase logger's level is lowered to INFO if it was above (logging's
    default is WARNING), so that status lines reach the file; :meth:`close` restores it."""

    def __init__(self, directory: Path, header: str) -> None:
        self.handler = logging.FileHandler(Path(directory) / RUN_LOG, mode="a", encoding="utf-8")
        self.handler.setLevel(logging.INFO)
        self.handler.setFormatter(_RunLogFormatter("%(asctime)s %(levelname)s %(message)s"))
        self.write(logging.INFO, header)
        self.level = _LOGGER.level
        if _LOGGER.getEffectiveLevel() > logging.INFO:
            _LOGGER.setLevel(logging.INFO)
        _LOGGER.addHandler(self.handler)

    def write(self, level: int, message: str) -> None:
        """A line in run.log only (the header and the end: the console has its own)."""
        self.handler.handle(_LOGGER.makeRecord(_LOGGER.name, level, __file__, 0, message, (), None))

    def close(self, level: int, message: str) -> None:
        """Write the segment's last line and detach from the logger."""
        _LOGGER.removeHandler(self.handler)
        _LOGGER.setLevel(self.level)
        self.write(level, message)
        self.handler.close()


class _RunLogFormatter(logging.Formatter):
    def formatTime(self, record: logging.LogRecord, datefmt: str | None = None) -> str:
        return datetime.datetime.fromtimestamp(record.created).astimezone().isoformat(timespec="milliseconds")
