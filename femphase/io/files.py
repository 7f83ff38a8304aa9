"""Writing files that survive a kill, and reading the run directory's tables.

:func:`atomic_write` replaces a file through a temporary name and ``os.replace``, so a
reader sees the old or the new file, never a part; :func:`write_json` writes JSON so;
:func:`read_csv` reads ``particles.csv`` and ``global.csv`` (columns in ``docs/outputs.md``);
:func:`failpoint` is the fault injection of the kill tests; :func:`output_directory` checks a
command's ``-o`` before anything is computed; :class:`FileLock` and :func:`locked` keep two
processes out of one directory. What a run directory holds, and its guarantees, is in
:mod:`femphase.io.rundir`.
"""

from __future__ import annotations

import csv
import errno
import fcntl
import json
import os
import signal
import warnings
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from femphase.errors import LockWarning, NoRoomError, SceneError

__all__ = ["ROOM_RESERVE", "FileLock", "atomic_write", "ensure_room", "failpoint", "jsonable", "locked",
           "output_directory", "read_csv", "write_json"]


_FAILPOINT_PASSES: dict[str, int] = {}

#: What ``flock`` raises on a filesystem that has no locks (ENOLCK on NFS without its lock
#: daemon; EOPNOTSUPP or ENOSYS on some FUSE and network filesystems).
NO_LOCKS = frozenset({errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS})


def failpoint(name: str) -> None:
    """Fault injection for the kill tests (:mod:`femphase.testing.faults`): with the environment
    variable FEMPHASE_FAILPOINT = "name:n", the n-th time the run passes the point ``name``
    the process kills itself with SIGKILL, as a scheduler or the OOM killer would. Points:
    "csv" (half of a frame's rows written), "fields" (a field frame written, not yet
    renamed), "checkpoint" (written, not yet renamed), and every atomically replaced file by
    its name ("fields.xdmf", "run.json", "scene.toml") between writing and renaming."""
    spec = os.environ.get("FEMPHASE_FAILPOINT")
    if not spec or spec.partition(":")[0] != name:
        return
    _FAILPOINT_PASSES[name] = _FAILPOINT_PASSES.get(name, 0) + 1
    if _FAILPOINT_PASSES[name] == int(spec.partition(":")[2] or 1):
        os.kill(os.getpid(), signal.SIGKILL)


#: Bytes an HDF5 file takes beyond its arrays' (its metadata and chunk index), and what the
#: run's small files (CSV rows, run.json, fields.xdmf) need after it: kept free on top.
ROOM_RESERVE = 4 * 2**20


def ensure_room(path: Path, arrays: Iterable, time: float) -> None:
    """NoRoomError when the device holding ``path`` (a file to write) has less free than the
    bytes of ``arrays`` (what the file will hold) and :data:`ROOM_RESERVE`: the run stops
    before the write, at simulated time ``time``. A quota (EDQUOT) is not seen here; the
    write then fails as it must."""
    import shutil

    nbytes = sum(int(np.asarray(values).nbytes) for values in arrays)
    free = shutil.disk_usage(Path(path).parent).free
    if free < nbytes + ROOM_RESERVE:
        raise NoRoomError(f"the run stopped at t = {time:g}: the device holding {Path(path).parent} has "
                          f"{free / 2**20:.1f} MiB free, and {Path(path).name} needs about "
                          f"{(nbytes + ROOM_RESERVE) / 2**20:.1f} MiB; free space there and continue with --resume")


def partial_path(path: Path) -> Path:
    """Where a file is written before it is renamed into place at ``path`` (hidden, beside
    it): what a kill between the two leaves behind."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp")


def atomic_write(path: Path, data: bytes | str) -> None:
    """Replace ``path`` by ``data`` atomically (:func:`partial_path`, then a rename): a
    kill at any instant leaves either the old or the new file."""
    path = Path(path)
    tmp = partial_path(path)
    with open(tmp, "wb") as handle:
        handle.write(data.encode() if isinstance(data, str) else data)
    failpoint(path.name)
    os.replace(tmp, path)


def write_json(path: Path, data: dict) -> None:
    """``data`` as indented JSON, replaced atomically (numpy values become numbers/lists)."""
    atomic_write(path, json.dumps(data, indent=2, default=jsonable) + "\n")


def jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """A run directory's CSV as columns of floats (pandas reads the same files directly).

    A last line without its newline is a row still being appended (a frame's rows are
    written in two flushes, :meth:`femphase.io.rundir.Outputs.append_rows`) and is left out, so
    the CSVs of a run under way (a sweep being aggregated) can be read."""
    text = Path(path).read_text()
    reader = csv.reader(text[: text.rfind("\n") + 1].splitlines())
    header = next(reader)
    rows = np.array([[float(x) for x in row] for row in reader]).reshape(-1, len(header))
    return {name: rows[:, k] for k, name in enumerate(header)}


def output_directory(path: str | Path) -> Path:
    """``path`` as the directory a command writes into (its ``-o``): SceneError naming
    ``-o`` when it is empty or names an existing file. Nothing is created here."""
    if not str(path).strip():
        raise SceneError("-o", str(path), "a directory path (it is empty)")
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise SceneError("-o", str(path), "a directory (this path is a file)")
    # the nearest part of it that exists must be a directory one can write in: said before
    # any work, not as an OSError from the first file written after it
    existing = next(parent for parent in (path, *path.absolute().parents) if parent.exists())
    if not existing.is_dir():
        raise SceneError("-o", str(path), f"a directory path ({existing} is a file)")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise SceneError("-o", str(path), f"a directory femphase can write to ({existing} is not writable)")
    return path


def writable_directory(path: Path) -> None:
    """Create ``path`` (with its parents) and check that a file can be written in it:
    SceneError naming ``-o`` otherwise (a parent that is a file, no permission), before any
    output, rather than an OSError from the first file written."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".femphase-write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise SceneError("-o", str(path), f"a directory femphase can write to ({exc.strerror or exc})") from None


class FileLock:
    """An exclusive ``flock`` on ``path`` (created), held from :meth:`acquire` until
    :meth:`release`. The kernel drops it when its process dies, so a killed process never
    leaves a stale lock; the file stays, holding the last holder's pid and host for the
    message of a process refused it (:meth:`holder`). On a filesystem without locks
    (:data:`NO_LOCKS`) it is taken without one, with a :class:`~femphase.errors.LockWarning`:
    refusing would stop every run there, where most users run one process per directory."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._handle: int | None = None

    def acquire(self, blocking: bool = True) -> bool:
        """Take the lock (waiting for it when ``blocking``); False when another process holds it."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
        except BlockingIOError:
            os.close(handle)
            return False
        except OSError as exc:
            if exc.errno not in NO_LOCKS:
                os.close(handle)
                raise
            warnings.warn(f"{self.path.parent} is on a filesystem without locks ({exc.strerror}): nothing keeps "
                          "a second femphase process out of it; run one at a time there", LockWarning, stacklevel=2)
        os.ftruncate(handle, 0)
        os.write(handle, f"pid {os.getpid()} on {os.uname().nodename}\n".encode())
        self._handle = handle
        return True

    def release(self) -> None:
        """Give the lock up (nothing when not held)."""
        if self._handle is not None:
            os.close(self._handle)  # releases the lock
            self._handle = None

    def holder(self) -> str:
        """Who took the lock last ("pid N on HOST"), as its file says."""
        try:
            return self.path.read_text().strip() or "another process"
        except OSError:
            return "another process"


@contextmanager
def locked(path: Path, blocking: bool = True) -> Iterator[bool]:
    """A :class:`FileLock` on ``path`` while inside; yields False when ``blocking`` is off
    and another process holds it."""
    lock = FileLock(path)
    try:
        yield lock.acquire(blocking)
    finally:
        lock.release()
