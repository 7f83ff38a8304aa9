"""Parameter sweeps: many runs of one scene, executed on Dask, resumable.

    femphase sweep SWEEP.toml -o DIR [--set KEY=VALUE ...] [--workers N | --scheduler ADDRESS]

A sweep file (TOML) names a base scene and the scene keys to vary::

    [sweep]
    scene = "../../examples/random.toml"   # the base scene, relative to the sweep file
    mode = "product"                       # "product" (default): every combination of the
                                           # axes; "zip": the i-th values of all axes together
    [set]                                  # optional: --set overrides of every run
    "output.fields" = false
    "phases.1.duration" = 100000.0

    [axes]                                 # --set keys → lists of values (TOML-typed)
    "phases.1.flow.rate" = [0.0161, 0.1083, 1.0]
    "particles.seed" = [1, 2, 3]           # samples are an ordinary axis

Keys are the dotted keys of ``femphase run --set`` (``docs/scenes.md``); written unquoted,
TOML makes them nested tables, which are read back as the same dotted keys (a table in
``[set]`` therefore updates the scene's table key by key). ``--set KEY=VALUE`` on the
command line adds to ``[set]`` (and wins over it), e.g. for a short smoke test of a sweep.
Axes are ordered as written; in "product" mode the last axis varies fastest. Every run's
scene is built and validated before any run starts: a bad key or value stops the sweep with
a :class:`SweepError` (a :class:`~femphase.errors.SceneError`) naming the sweep key, e.g.
``axes.particles.sed``, and the run (exit 2).

DIR, the sweep directory:

* ``sweep.toml``: the sweep file as given; ``sweep-set.json``: the command line's ``--set``
  assignments; ``base-scene.toml``: the base scene as given;
* ``sweep.json``, the index (written by the process that runs the sweep, replaced atomically
  whenever a run finishes)::

      {"format": "femphase-sweep", "version": 1, "mode": "product" | "zip",
       "axes": {key: [values...]},
       "runs": [{"id": "rate=0.1_seed=3", "directory": "runs/rate=0.1_seed=3",
                 "values": {key: value}, "status": "pending" | "done" | "failed" | "interrupted",
                 "error": str | null}]}

* ``runs/<id>/``: an ordinary run directory (:mod:`femphase.io.rundir`), written by
  :func:`femphase.run.runner.run_scene` as ``femphase run`` writes it. The id is
  ``label=value`` per axis joined by ``_``; the label is the shortest dotted suffix of the
  key that tells the axes apart (``phases.1.flow.rate`` → ``rate``), values are spelled as
  Python spells them (``0.1083``, ``1e-05``, ``true``) with characters other than
  ``A-Z a-z 0-9 . + -`` replaced by ``-``.
* ``shared/<hash>/``: relaxations shared by several runs (below); ``locks/``: lock files.

**Shared relaxations.** Runs whose scenes agree on everything but their phases after the
first (the same model, domain, particles incl. the seed, numerics, output and first phase)
start from one run of the first phase alone, ``shared/<hash>/`` (hash of that one-phase
scene, a mesh file in it by its content), computed once under a file lock; each run copies
its outputs and checkpoint and continues with ``resume=True``. The outputs are bit-identical to running the whole scene
(``tests/test_sweep.py``): a resumed run continues exactly (:mod:`femphase.io.rundir`).
Scenes with one phase, or with ``output.checkpoint = false``, are never shared, nor is a
first phase no other run has.

**Resuming.** Rerunning the same command continues the sweep: a run whose run.json says
"completed" with all its steps is skipped, one with a checkpoint (interrupted, killed) is
resumed, a failed one is started again. The state of each run is read from its run
directory, not from the index. The sweep file may change only by adding values (new runs);
any other change (of ``[sweep]``, ``[set]``, ``--set``, the axes' keys or their order, a
removed value) or a changed base scene is refused: start a new DIR. A second ``femphase
sweep`` on a DIR in use is refused.

**Execution.** Every run is one Dask task (a shared relaxation one more, which its runs
depend on), started in the sweep file's order (relaxations first) on one worker, and
roughly so on several (each worker keeps the order among the runs Dask gave it). By
default a ``LocalCluster`` of ``--workers`` processes (default: the number of cores), one
thread each, BLAS pinned to one thread; ``--scheduler ADDRESS`` uses a
running cluster instead (e.g. on SLURM with dask-jobqueue: ``docs/sweeps.md``). A worker
that dies (killed, out of memory) is replaced and its run resumed from its checkpoint on
another worker; a lock per run keeps two processes out of one run directory.
"""

from __future__ import annotations

import gc
import hashlib
import itertools
import json
import logging
import os
import re
import shutil
import time as wallclock
import uuid
import warnings
from collections.abc import Callable
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from femphase import tomlio
from femphase.errors import FemphaseError, Interrupted, SceneError
from femphase.io.console import console_handler, log_warning
from femphase.io.files import atomic_write, jsonable, locked, output_directory, writable_directory
from femphase.io.rundir import CHECKPOINT, OUTPUTS, Status
from femphase.run.runner import run_scene
from femphase.scene import Scene, parse_assignment, read_scene_data, scene_from_dict
from femphase.tomlio import toml_value

if TYPE_CHECKING:  # dask.distributed loads only where a sweep runs
    from distributed import Client

__all__ = ["EXIT_INCOMPLETE", "MODES", "SLOW_MALLOC", "TABLES", "WORKER_ENV", "load_sweep", "Run", "run_status",
           "run_sweep", "Sweep", "SweepError"]

FORMAT, VERSION = "femphase-sweep", 1
MODES = ("product", "zip")
TABLES = {"sweep": ("scene", "mode"), "set": None, "axes": None}
#: Environment of LocalCluster workers: one BLAS thread per worker process (as ``femphase run``).
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536 (to hand freed memory back
#: to the OS). Setting it stops glibc's malloc from adapting its mmap threshold, so every
#: temporary array above 128 kB is mmap'd and page-faulted afresh: a run's steps took
#: 2.5–3.5× longer in such a worker (docs/sweeps.md). LocalCluster workers start without it;
#: workers of other clusters are checked and a warning names the fix.
SLOW_MALLOC = "MALLOC_TRIM_THRESHOLD_"
#: Exit code of ``femphase sweep`` when some runs did not finish (sweep.json says why).
EXIT_INCOMPLETE = 4


class SweepError(SceneError):
    """A sweep file key or value, or a sweep directory, is invalid (exit 2); an option
    (``-o``, ``--workers``) and the sweep file argument (``SWEEP``) are named as such."""

    def __init__(self, key: str, value: object, valid: str) -> None:
        super().__init__(key, value, valid)
        if not key.startswith("-") and not key.isupper():
            self.args = (f"sweep key '{key}' = {value!r} is invalid: {valid}",)


@dataclass(frozen=True)
class Run:
    """One run of a sweep: its id, axis values, validated scene data and number of steps;
    ``relaxation``: the hash of its first phase's scene when it has later phases to branch
    from it; ``shared``: that hash when other runs share it (None: it runs alone)."""

    id: str
    values: dict
    data: dict
    total_steps: int
    relaxation: str | None = None
    shared: str | None = None


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file. ``document`` is its parsed TOML, ``text`` the file as given;
    ``assignments`` the command line's ``--set``; ``scene`` the base scene file; ``set``
    (of the file and the command line) and ``axes`` map dotted keys to values."""

    path: Path
    text: str
    document: dict
    assignments: tuple[str, ...]
    scene: Path
    mode: str
    set: dict
    axes: dict
    runs: tuple[Run, ...]

    @property
    def base_dir(self) -> Path:
        """Where relative paths of the scene (a mesh file) are resolved."""
        return self.scene.parent


def _flatten(table: dict, prefix: str = "") -> dict:
    """Nested tables → dotted keys (``phases.1.flow.rate = 1`` in TOML is a nested table).
    A table under a quoted dotted key (``"phases.1.flow" = {type = "none"}``) is a value,
    kept whole: it replaces the scene's table, as ``femphase run --set`` does."""
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict) and "." not in key:
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _overrides(document: dict, assignments: list[str] | tuple[str, ...]) -> dict:
    """The [set] table of a sweep file, then ``--set`` assignments, as dotted key → value
    (a table value whole, :func:`_flatten`)."""
    overrides = _flatten(document.get("set", {}))
    for assignment in assignments:
        parts, value = parse_assignment(assignment)
        overrides[".".join(parts)] = value
    return overrides


def load_sweep(path: str | Path, assignments: list[str] | tuple[str, ...] = ()) -> Sweep:
    """Read a sweep file and validate it, the ``--set`` ``assignments`` added to its [set],
    and the scene of every run (nothing is run)."""
    path = Path(path)
    if not path.is_file():
        raise SweepError("SWEEP", str(path), "a TOML sweep file" + (" (this path is a directory)" if path.is_dir()
                                                                     else " that exists"))
    try:
        text = path.read_text(encoding="utf-8")
        document = tomlio.loads(text)
    except (OSError, UnicodeDecodeError, tomlio.TOMLDecodeError) as exc:
        raise SweepError("SWEEP", str(path), f"a readable UTF-8 TOML file ({exc})") from None
    for name, value in document.items():
        if name not in TABLES:
            scene = "phases" in document or "domain" in document  # a scene given where its sweep belongs
            raise SweepError(name, value, f"not a known table; valid: {', '.join(f'[{t}]' for t in TABLES)}"
                             + (f" ('{path}' looks like a scene: a sweep file names its scene in [sweep] and "
                                "the values to vary in [axes], docs/sweeps.md)" if scene else ""))
        if not isinstance(value, dict):
            raise SweepError(name, value, f"a table [{name}]")
    head = document.get("sweep", {})
    for key, value in head.items():
        if key not in TABLES["sweep"]:
            raise SweepError(f"sweep.{key}", value, f"not a known key; valid: {', '.join(TABLES['sweep'])}")
    if not isinstance(head.get("scene"), str) or not head["scene"].strip():
        raise SweepError("sweep.scene", head.get("scene"), "the base scene file, a path relative to the sweep file")
    scene = (path.parent / head["scene"]).resolve()
    if not scene.is_file():
        raise SweepError("sweep.scene", head["scene"], f"a scene file that exists ({scene} "
                         + ("is a directory)" if scene.is_dir() else "does not)"))
    mode = head.get("mode", "product")
    if mode not in MODES:
        raise SweepError("sweep.mode", mode, f"one of {MODES}")
    overrides = _overrides(document, assignments)
    axes = _flatten(document.get("axes", {}))
    if not axes:
        raise SweepError("axes", {}, 'at least one axis: a dotted scene key and its values, e.g. '
                         '"phases.1.flow.rate" = [0.1, 1.0]')
    for key, values in axes.items():
        if not isinstance(values, list) or not values:
            raise SweepError(f"axes.{key}", values, "a non-empty list of values, e.g. [0.1, 1.0]")
        spelled = [_identity(v) for v in values]
        if len(set(spelled)) != len(spelled):
            raise SweepError(f"axes.{key}", values, "distinct values (a value is listed twice, or two numbers are "
                             "equal, as 1 and 1.0)")
        if key in overrides:
            raise SweepError(f"axes.{key}", values, f"a key not also in [set] (set.{key} = {overrides[key]!r})")
        inside = next((k for k in overrides if k.startswith(key + ".")), None)
        if inside is not None:  # the axis' table replaces the whole table, and the [set] key in it
            raise SweepError(f"axes.{key}", values, f"a key without [set] keys inside its table: set.{inside} = "
                             f"{overrides[inside]!r} would be replaced by each value of the axis; put it in the "
                             "axis' tables")
    if mode == "zip" and len({len(v) for v in axes.values()}) > 1:
        lengths = ", ".join(f"{k}: {len(v)}" for k, v in axes.items())
        raise SweepError("sweep.mode", mode, f'axes of one length for "zip" (they have {lengths}), or "product"')
    combos = zip(*axes.values()) if mode == "zip" else itertools.product(*axes.values())
    labels = _labels(list(axes))
    runs = [_run(scene, overrides, dict(zip(axes, combo)), labels) for combo in combos]
    ids = [run.id for run in runs]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise SweepError("axes", list(axes), f"values whose run ids differ after sanitising ({duplicates[0]!r} "
                         "twice): spell them differently")
    shared = [run.relaxation for run in runs]
    runs = [replace(run, shared=run.relaxation if shared.count(run.relaxation) > 1 else None) for run in runs]
    return Sweep(path, text, document, tuple(assignments), scene, mode, overrides, axes, tuple(runs))


def _identity(value) -> str:
    """What makes two values of an axis the same run: numbers by value (1, 1.0 and 1e0 are
    one; −0.0 is 0.0), anything else by its JSON spelling."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return repr(float(value) + 0.0)
    return json.dumps(value, sort_keys=True, default=str)


def _labels(keys: list[str]) -> dict[str, str]:
    """Each key's shortest dotted suffix that no other key ends with."""
    labels = {}
    for key in keys:
        parts = key.split(".")
        for n in range(1, len(parts) + 1):
            label = ".".join(parts[-n:])
            if not any(other != key and (other == label or other.endswith("." + label)) for other in keys):
                break
        labels[key] = label
    return labels


def _spell(value) -> str:
    """A value as a run id spells it: floats as Python's shortest repr, booleans, lists and
    tables as TOML."""
    if isinstance(value, (bool, list, dict)):
        return toml_value(value)
    return repr(value) if isinstance(value, float) else str(value)


def _run(scene: Path, overrides: dict, values: dict, labels: dict[str, str]) -> Run:
    """The run of ``values``: its id and validated scene data (SweepError naming the axis)."""
    run_id = "_".join(f"{labels[k]}={re.sub(r'[^A-Za-z0-9.+-]+', '-', _spell(v))}" for k, v in values.items())
    if len(run_id) > 120:  # file-name limits: keep it readable, make it unique
        run_id = f"{run_id[:100]}-{hashlib.sha256(run_id.encode()).hexdigest()[:12]}"
    sources = {f"set.{k}": v for k, v in overrides.items()} | {f"axes.{k}": v for k, v in values.items()}
    try:
        data = read_scene_data(scene, [f"{k.partition('.')[2]}={toml_value(v)}" for k, v in sources.items()])
        validated = scene_from_dict(data, scene.parent)
    except SceneError as exc:
        source = _source(exc, sources)
        if source is None:
            raise SweepError("sweep.scene", str(scene), f"a valid base scene: {exc}") from None
        raise SweepError(source, sources[source], f"{exc.valid} (scene key '{exc.key}', run {run_id})") from None
    relaxation = None
    # a relaxation is shared through its checkpoint, and only makes sense before other phases
    if len(validated.phases) > 1 and validated.output.checkpoint:
        relaxation = _relaxation_hash(validated)
    return Run(run_id, values, data, sum(p.n_steps for p in validated.phases), relaxation)


def _relaxation_hash(scene: Scene) -> str:
    """The name of the scene's shared relaxation: a hash of its first phase's scene, where a
    mesh file counts by its content (:func:`~femphase.domains.mesh.domain.mesh_checksum`),
    not by its absolute path, so that a sweep moved with its checkout finds its relaxations
    (runs already branched from them resume either way, :mod:`femphase.io.rundir`)."""
    description = _relaxation(scene).to_dict()
    if description["domain"].get("mesh"):
        from femphase.domains.mesh.domain import mesh_checksum

        description["domain"]["mesh"] = mesh_checksum(scene.domain.mesh)
    return hashlib.sha256(json.dumps(description, sort_keys=True, default=jsonable).encode()).hexdigest()[:16]


def _source(error: SceneError, sources: dict) -> str | None:
    """The sweep key ("set.…" or "axes.…") that set the scene key ``error`` names, or one
    inside it (a bad list index) or around it (a key set to a table); None: the base scene."""
    bad = error.key if error.key != "--set" else str(error.value).partition("=")[0]
    for source in sources:
        key = source.partition(".")[2]
        if key == bad or key.startswith(bad + ".") or bad.startswith(key + "."):
            return source
    return None


def _relaxation(scene: Scene) -> Scene:
    """The scene's first phase alone: what runs sharing it compute once."""
    return replace(scene, phases=scene.phases[:1])


# -- the sweep directory ------------------------------------------------------------------

def _index(sweep: Sweep, statuses: dict[str, tuple[str, str | None]]) -> dict:
    return {"format": FORMAT, "version": VERSION, "mode": sweep.mode, "axes": sweep.axes,
            "runs": [{"id": run.id, "directory": f"runs/{run.id}", "values": run.values,
                      "status": statuses[run.id][0], "error": statuses[run.id][1]} for run in sweep.runs]}


def _write_index(directory: Path, index: dict) -> None:
    atomic_write(directory / "sweep.json", json.dumps(index, indent=2, default=jsonable) + "\n")


#: The first line of a convergence study's sweep file (:func:`femphase.converge.study_sweep`):
#: a study's directory and a sweep's are not each other's.
STUDY_HEADER = "# femphase converge: the study's runs (a sweep file, docs/sweeps.md)"


def _check_directory(sweep: Sweep, directory: Path) -> dict[str, dict]:
    """The runs recorded in an existing sweep directory (id → entry of sweep.json); refuses
    a sweep file that changed other than by adding values, or a changed base scene."""
    stored = directory / "sweep.json"
    if not stored.exists():
        # what a start that stopped before its first index left is no sweep yet
        own = {"locks", "sweep.toml", "sweep-set.json", "base-scene.toml"}
        existing = [p.name for p in directory.iterdir() if p.name not in own] if directory.is_dir() else []
        if existing:
            raise SweepError("-o", str(directory), f"a new or empty directory, or one of a sweep (it holds "
                             f"{', '.join(sorted(existing)[:5])} but no sweep.json)")
        return {}
    try:
        index = json.loads(stored.read_text())
        old_text = (directory / "sweep.toml").read_text(encoding="utf-8")
        old = tomlio.loads(old_text)
        old_set = _overrides(old, json.loads((directory / "sweep-set.json").read_text()))
        old_scene = (directory / "base-scene.toml").read_text(encoding="utf-8")
    except (OSError, ValueError) as exc:
        raise SweepError("-o", str(directory), f"a sweep directory with readable sweep.json, sweep.toml, "
                         f"sweep-set.json and base-scene.toml ({exc})") from None
    kinds = {True: "a convergence study (femphase converge)", False: "a sweep (femphase sweep)"}
    was_study, is_study = old_text.startswith(STUDY_HEADER), sweep.text.startswith(STUDY_HEADER)
    if was_study != is_study:
        raise SweepError("-o", str(directory), f"a new directory, or one of {kinds[is_study]}: it holds "
                         f"{kinds[was_study]}")
    hint = (f"as in the sweep of {directory}, which accepts added values only (start a new directory for "
            "another sweep)")
    # the mode spelled out or left at its default is the same sweep
    head, old_head = ({"mode": "product", **document.get("sweep", {})} for document in (sweep.document, old))
    for table, new, before in (("sweep", head, old_head), ("set", sweep.set, old_set)):
        for key in sorted(set(new) | set(before)):
            if new.get(key) != before.get(key):
                was = "unset" if key not in before else f"{before[key]!r}"
                raise SweepError(f"{table}.{key}", "unset" if key not in new else new[key], f"{was} {hint}")
    old_axes = list(_flatten(old.get("axes", {})))
    if old_axes != list(sweep.axes):
        raise SweepError("axes", list(sweep.axes), f"the axes {old_axes}, in that order, {hint}")
    if old_scene != sweep.scene.read_text(encoding="utf-8"):
        raise SweepError("sweep.scene", str(sweep.scene), f"the base scene as it was when the sweep of {directory} "
                         "started (base-scene.toml there): it was changed since; start a new directory")
    # each run's values as sweep.json holds them (JSON numbers, lists for tuples)
    values = {run.id: json.loads(json.dumps(run.values, default=jsonable)) for run in sweep.runs}
    recorded = {entry["id"]: entry for entry in index.get("runs", [])}
    for run_id, entry in recorded.items():
        if values.get(run_id) != entry["values"]:
            respelled = next((other for other, written in values.items() if written == entry["values"]), None)
            if respelled is not None:  # 1 written as 1.0: one value, but the run's id is its spelling
                raise SweepError("axes", sweep.axes, f"the values spelled as before: run {run_id!r} "
                                 f"({entry['values']}) would now be named {respelled!r}, and a run's id is its "
                                 f"values as written; write them as the sweep of {directory} has them")
            raise SweepError("axes", sweep.axes, f"values that include those of run {run_id!r} "
                             f"({entry['values']}) {hint}")
    return recorded


def run_status(directory: Path, total_steps: int) -> tuple[str, str | None]:
    """(status, error) of the run directory ``directory`` for the index: "done" when it
    completed all ``total_steps``, "failed" (with run.json's message), "interrupted" when it
    holds a checkpoint to resume from, else "pending"."""
    info = Status.read(directory) or {}
    if info.get("status") == "completed" and info.get("steps") == total_steps:
        return "done", None
    if info.get("status") == "failed":
        return "failed", info.get("message") or "failed"
    if (directory / CHECKPOINT).is_file():
        return "interrupted", info.get("message") or None
    return "pending", None


# -- what a worker runs ------------------------------------------------------------------

def _ensure(scene: Scene, directory: Path, fresh: Callable[[], None] | None = None) -> None:
    """Bring ``directory`` to the end of ``scene``: skip it when done, start it again when
    failed or without a checkpoint (``fresh()`` prepares a branch instead), else resume."""
    status, _ = run_status(directory, sum(p.n_steps for p in scene.phases))
    if status == "done":
        return
    if status in ("failed", "pending") and fresh is not None:
        fresh()
        status = "interrupted"
    run_scene(scene, directory, resume=status == "interrupted", overwrite=status != "interrupted",
              progress=False, argv=["sweep", directory.name])


def _clear(directory: Path) -> None:
    """Remove femphase's outputs from a run directory (only those)."""
    for name in OUTPUTS:
        target = directory / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()


def _branch(shared: Path, directory: Path) -> None:
    """Start ``directory`` as a copy of the shared relaxation: every output, each file
    through a temporary name (whoever reads run.json meanwhile, the sweep's index or a
    user's monitor, sees no half-copied file), the checkpoint last (a kill mid-copy leaves
    no checkpoint, so the copy is redone)."""
    _clear(directory)
    directory.mkdir(parents=True, exist_ok=True)
    outputs = [name for name in OUTPUTS if name != CHECKPOINT and (shared / name).exists()]
    for name in (*outputs, CHECKPOINT):
        if (shared / name).is_dir():
            shutil.copytree(shared / name, directory / name)
        else:
            shutil.copy2(shared / name, directory / f".{name}.tmp")
            os.replace(directory / f".{name}.tmp", directory / name)


def _outcome(action: Callable[[], None]) -> dict:
    """Run ``action``; its outcome as an index status, error message, wall and CPU time
    (of the worker process, which runs one task at a time)."""
    started, cpu = wallclock.perf_counter(), wallclock.process_time()
    # the run's warnings as the command line shows them, one "femphase: warning: …" line each
    # (a worker's default is Python's file-and-line form), and into the run's run.log
    console, logger = console_handler(logging.WARNING), logging.getLogger("femphase")
    logger.addHandler(console)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = log_warning
            action()
        status, error = "done", None
    except Interrupted as exc:
        status, error = "interrupted", str(exc)
    except FemphaseError as exc:
        status, error = "failed", str(exc)
    except Exception as exc:  # a bug in one run must not stop the others: report it in the index
        status, error = "failed", f"internal error ({type(exc).__name__}: {exc})"
    finally:
        logger.removeHandler(console)
        # A finished run is cyclic garbage (its domain's cache budget holds advections that
        # hold the domain), which Python's collector, triggered by counts of container
        # allocations that numpy work hardly makes, may leave for many tasks: uncollected,
        # each run of a worker on the straight mesh holds ~175 MB more than the last.
        gc.collect()
    return {"status": status, "error": error, "seconds": wallclock.perf_counter() - started,
            "cpu_seconds": wallclock.process_time() - cpu}


def _execute_shared(data: dict, base_dir: str, directory: str) -> dict:
    """Dask task: the shared relaxation of ``data``'s scene into ``directory``, once."""
    directory = Path(directory)
    with locked(directory.parent.parent / "locks" / f"shared-{directory.name}.lock"):
        return _outcome(lambda: _ensure(_relaxation(scene_from_dict(data, base_dir)), directory))


def _execute_run(data: dict, base_dir: str, directory: str, shared: str | None = None,
                 relaxation: dict | None = None) -> dict:
    """Dask task: the run of ``data``'s scene into ``directory`` (branching from the
    relaxation in ``shared``, whose task's outcome is ``relaxation``)."""
    directory = Path(directory)
    if relaxation is not None and relaxation["status"] != "done":
        return {"status": "failed", "error": f"its shared relaxation {shared} did not finish: "
                f"{relaxation['error']}", "seconds": 0.0, "cpu_seconds": 0.0}
    fresh = (lambda: _branch(Path(shared), directory)) if shared else None
    # one process per run directory, even when a worker thought dead is still running
    with locked(directory.parent.parent / "locks" / f"{directory.name}.lock"):
        # the scene is built inside: an error there (a mesh file missing on this node) is the run's
        return _outcome(lambda: _ensure(scene_from_dict(data, base_dir), directory, fresh))


# -- the driver ---------------------------------------------------------------------------

@contextmanager
def _client(client, scheduler: str | None, workers: int | None, log: Callable[[str], None]):
    """The Dask client to use: the one given, one of the cluster at ``scheduler``, or a new
    LocalCluster of ``workers`` processes (closed on exit)."""
    if client is not None:
        yield client
        return
    import dask
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        before = {key: dask.config.config.get(key) for key in ("scheduler", "shuffle")}
        try:
            connected = Client(scheduler)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:  # unreachable, or not an address
            # a Client that failed to connect has already made itself Dask's default scheduler and
            # undoes that only when collected; a client opened before then restores the dead one's
            # setting when it closes, and xarray's netCDF writes (femphase converge's tables) then
            # asked for a distributed scheduler that was gone
            for key, value in before.items():
                if value is None:
                    dask.config.config.pop(key, None)
                else:
                    dask.config.config[key] = value
            raise SweepError("--scheduler", scheduler, "the address of a running Dask scheduler, e.g. "
                             f"tcp://host:8786 (connecting failed: {type(exc).__name__}: {exc})") from None
        with connected:
            log(f"femphase sweep: using the Dask cluster at {scheduler}")
            yield connected
        return
    n = workers or os.cpu_count() or 1
    # workers inherit this process's environment, where an earlier Dask cluster may have
    # left SLOW_MALLOC (its nannies set their pre-spawn environment here, for good)
    inherited = os.environ.pop(SLOW_MALLOC, None)
    try:
        # dashboard on a free port: a fixed one clashes with other sweeps on the machine
        with dask.config.set({f"distributed.nanny.pre-spawn-environ.{SLOW_MALLOC}": None}), \
                LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                             env=WORKER_ENV) as cluster, Client(cluster) as local:
            local.register_plugin(_interrupts_to_the_driver())
            log(f"femphase sweep: a local Dask cluster of {n} worker process{'es' if n > 1 else ''}")
            yield local
    finally:
        if inherited is not None:
            os.environ[SLOW_MALLOC] = inherited


def _interrupts_to_the_driver():
    """A worker plugin that makes a local worker ignore SIGINT. Ctrl-C in a terminal reaches
    the whole process group: the driver stops the sweep and closes the cluster, which ends
    the workers, and each worker's own KeyboardInterrupt printed some 30 lines of traceback
    from Dask's event loop. Their runs keep their checkpoints either way (a run in a worker's
    thread never saw the signal)."""
    import signal

    from distributed.diagnostics.plugin import WorkerPlugin

    class InterruptsToTheDriver(WorkerPlugin):
        name = "femphase-interrupts-to-the-driver"

        def setup(self, worker) -> None:  # in the worker's event loop: its process's main thread
            signal.signal(signal.SIGINT, signal.SIG_IGN)

    return InterruptsToTheDriver()


def _malloc_setting() -> str | None:
    """Dask task: this worker's :data:`SLOW_MALLOC` setting."""
    return os.environ.get(SLOW_MALLOC)


def _check_workers(client) -> None:
    """Warn when workers run with :data:`SLOW_MALLOC` set."""
    settings = client.run(_malloc_setting)
    slow = sorted({value for value in settings.values() if value is not None})
    if slow:  # a warning, on stderr with the others: the log is the sweep's progress
        warnings.warn(f"{sum(v is not None for v in settings.values())} of {len(settings)} workers run with "
                      f"{SLOW_MALLOC}={', '.join(slow)} (Dask's default), which makes their runs 2.5-3.5x slower; "
                      f"start them with the Dask config distributed.nanny.pre-spawn-environ.{SLOW_MALLOC}: null "
                      "(docs/sweeps.md, \"Workers\")", stacklevel=2)


def run_sweep(sweep: Sweep | str | Path, directory: str | Path, client: Client | None = None, *, assignments: list[str] = (),
              scheduler: str | None = None, workers: int | None = None,
              log: Callable[[str], None] = print) -> dict:
    """Run (or continue) a sweep into ``directory``; returns the index (sweep.json's content).

    ``sweep``: a :class:`Sweep` or the path of a sweep file (with ``assignments``, ``--set``
    overrides of every run, when a path).
    ``client``: a ``dask.distributed.Client`` to submit to; else one of the cluster at
    ``scheduler``, else a LocalCluster of ``workers`` processes (default: one per core).
    ``log`` receives one line per finished run. Nothing runs before the sweep file and every
    run's scene are validated, and an existing ``directory`` checked (SweepError)."""
    if workers is not None and not (isinstance(workers, int) and workers >= 1):
        raise SweepError("--workers", workers, "a whole number ≥ 1 (worker processes)")
    sweep = sweep if isinstance(sweep, Sweep) else load_sweep(sweep, assignments)
    directory = output_directory(directory).resolve()  # "" is refused, not taken for "."
    recorded = _check_directory(sweep, directory)
    fresh = not directory.exists()
    writable_directory(directory)
    try:
        return _run_locked(sweep, directory, recorded, client, scheduler, workers, log)
    except BaseException:
        if fresh and not (directory / "sweep.json").exists():  # what this call made, holding no sweep yet
            shutil.rmtree(directory, ignore_errors=True)
        raise


def _run_locked(sweep: Sweep, directory: Path, recorded: dict, client, scheduler: str | None, workers: int | None,
                log: Callable[[str], None]) -> dict:
    """:func:`run_sweep` in a checked, writable ``directory``, under its lock."""
    with locked(directory / "locks" / "sweep.lock", blocking=False) as mine:
        if not mine:
            raise SweepError("-o", str(directory), "a sweep directory no other femphase sweep is running on")
        statuses = {run.id: run_status(directory / "runs" / run.id, run.total_steps) for run in sweep.runs}
        for run_id, entry in recorded.items():  # the error recorded when it last ran, kept until it is retried
            if statuses[run_id][0] != "done" and entry.get("error") and not statuses[run_id][1]:
                statuses[run_id] = (statuses[run_id][0], entry["error"])
        todo = [run for run in sweep.runs if statuses[run.id][0] != "done"]
        # the cluster first: one that cannot be reached leaves the directory as it was, not
        # tied to a sweep file of which nothing ran
        with _client(client, scheduler, workers, log) if todo else nullcontext() as dask:
            atomic_write(directory / "sweep.toml", sweep.text)
            atomic_write(directory / "sweep-set.json", json.dumps(list(sweep.assignments)) + "\n")
            atomic_write(directory / "base-scene.toml", sweep.scene.read_text(encoding="utf-8"))
            _write_index(directory, _index(sweep, statuses))
            log(f"femphase sweep: {len(sweep.runs)} runs, {len(sweep.runs) - len(todo)} done, {len(todo)} to run")
            if todo:
                try:
                    _check_workers(dask)
                    _submit(sweep, directory, todo, statuses, dask, log)
                except BaseException:
                    # a run a worker finished while the cluster shut down is done, not interrupted
                    for run in todo:
                        if statuses[run.id][0] != "done" and run_status(directory / "runs" / run.id,
                                                                        run.total_steps)[0] == "done":
                            statuses[run.id] = ("done", None)
                    _write_index(directory, _index(sweep, statuses))
                    raise
        return _index(sweep, statuses)


def _submit(sweep: Sweep, directory: Path, todo: list[Run], statuses: dict, client, log) -> None:
    """Submit ``todo`` (relaxations first), update the index as each run finishes."""
    from dask.distributed import as_completed

    token = uuid.uuid4().hex[:8]  # task keys unique to this call
    base_dir = str(sweep.base_dir)
    # Dask runs higher priorities first: relaxations, then runs in the sweep file's order, so
    # that a sweep stopped early has mostly its first values done. A worker keeps to that
    # order among the tasks the scheduler gave it, but tasks whose relaxation is ready are
    # handed out to the workers at once: with two workers on poiseuille_mesh_fast.toml,
    # γ̇ = 0.0418 seed 2 started before seed 1. Without priorities Dask picks in no set order.
    priority = itertools.count(2 * len(todo), -1)
    relaxations = {}
    for run in todo:
        if run.shared and run.shared not in relaxations:
            relaxations[run.shared] = client.submit(
                _execute_shared, run.data, base_dir, str(directory / "shared" / run.shared),
                key=f"femphase-relaxation-{run.shared}-{token}", pure=False, priority=next(priority))
    futures = {}
    for run in todo:
        shared = str(directory / "shared" / run.shared) if run.shared else None
        future = client.submit(_execute_run, run.data, base_dir, str(directory / "runs" / run.id), shared,
                               relaxations.get(run.shared), key=f"femphase-run-{run.id}-{token}", pure=False,
                               priority=next(priority))
        futures[future] = run
    finished = 0
    try:
        for future in as_completed(list(futures)):
            run = futures[future]
            try:
                outcome = future.result()
            except Exception as exc:  # the task was lost (its workers died, KilledWorker), not the run
                outcome = {"status": "interrupted", "error": f"its task was lost ({type(exc).__name__}: {exc}); "
                           "rerun the sweep to resume it", "seconds": float("nan"), "cpu_seconds": float("nan")}
            finished += 1
            statuses[run.id] = (outcome["status"], outcome["error"])
            _write_index(directory, _index(sweep, statuses))
            log(f"femphase sweep: [{finished}/{len(todo)}] {run.id}: {outcome['status']} ({outcome['seconds']:.1f} s, "
                f"CPU {outcome['cpu_seconds']:.1f} s)" + (f": {outcome['error']}" if outcome["error"] else ""))
    except BaseException:  # Ctrl-C: record what did not finish; the run directories resume
        for future, run in futures.items():
            if not future.done():
                status, error = run_status(directory / "runs" / run.id, run.total_steps)
                statuses[run.id] = (status, error or ("the sweep was stopped during this run"
                                                      if status == "interrupted" else None))
        _write_index(directory, _index(sweep, statuses))
        client.cancel(list(futures) + list(relaxations.values()))
        raise
