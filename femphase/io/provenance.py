"""Where and with what a run ran: software versions, host, threads, command line.

:func:`provenance` is the record each segment of a run directory keeps in run.json
(``segments[k].provenance``; every field is documented in docs/outputs.md). Nothing here
raises: a value that cannot be found (no git, not a checkout, a distribution not
installed) is recorded as ``None``.
"""

from __future__ import annotations

import datetime
import os
import platform
import socket
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from femphase import IMPORT_TIME, __version__

__all__ = ["DEPENDENCIES", "PACKAGE_DIR", "THREAD_VARIABLES", "changed_since_import", "dependency_versions",
           "git_commit", "now", "provenance", "threads"]

#: The distributions a run imports (pyproject.toml's dependencies that ``femphase run``
#: loads; matplotlib only plots). tqdm is imported only when a progress bar is shown, numba
#: only for the structured channel's windows, and tomli only before Python 3.11 (tomllib
#: after); they are recorded all the same.
DEPENDENCIES = ("numpy", "scipy", "scikit-fem", "pyamg", "meshio", "h5py", "tqdm", "numba") + (
    ("tomli",) if sys.version_info < (3, 11) else ())

#: Environment variables that set the threads of the BLAS/OpenMP libraries under numpy
#: and scipy (the CLI sets the first three to 1 unless they are set).
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

#: The femphase package's directory (a git checkout's ``femphase/`` when run from source).
PACKAGE_DIR = Path(__file__).resolve().parents[1]


def now() -> str:
    """The current time in ISO 8601 with the local UTC offset, to the second
    (e.g. "2026-12-01T04:44:07+00:00")."""
    return datetime.datetime.now().astimezone().isoformat(timespec="seconds")


def git_commit(directory: Path = PACKAGE_DIR) -> str | None:
    """The commit of the git checkout that holds ``directory``'s ``__init__.py`` (40 hex
    digits), with "-dirty" appended when a file under ``directory`` differs from that commit
    (tracked and modified, or untracked and not ignored). None when git is missing, fails,
    or the file is not tracked by a checkout (an installed copy: a site-packages inside some
    other repository must not report that repository's commit)."""
    def git(*args: str) -> str | None:
        try:
            # GIT_OPTIONAL_LOCKS=0: `git status` must not take the index lock of a checkout
            # someone may be committing in
            done = subprocess.run(["git", *args], cwd=directory, capture_output=True, text=True, timeout=10,
                                  env={**os.environ, "GIT_OPTIONAL_LOCKS": "0"})
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    if git("ls-files", "--error-unmatch", "__init__.py") is None:
        return None
    commit = git("rev-parse", "HEAD")
    if not commit:
        return None
    changes = git("status", "--porcelain", "--", ".")
    if changes is None:
        return None
    return commit + "-dirty" if changes else commit


def changed_since_import(since: float = IMPORT_TIME, prefix: str = "femphase") -> list[str]:
    """The modules named ``prefix`` or ``prefix.*`` loaded in this process whose source file
    was modified after ``since`` (a time as from ``time.time()``): the code this process runs
    then differs from the checkout that ``git_commit`` describes."""
    changed = []
    for name, module in list(sys.modules.items()):
        path = getattr(module, "__file__", None)
        if path is None or not (name == prefix or name.startswith(prefix + ".")):
            continue
        try:
            if os.stat(path).st_mtime > since:
                changed.append(name)
        except OSError:
            changed.append(name)  # deleted or moved since: also not what the checkout holds
    return sorted(changed)


def dependency_versions(names: tuple[str, ...] = DEPENDENCIES) -> dict[str, str | None]:
    """Distribution name → installed version (importlib.metadata), None if not installed."""
    versions: dict[str, str | None] = {}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def threads() -> dict[str, str | int | None]:
    """The thread settings: each of :data:`THREAD_VARIABLES` as set in the environment (a
    string, None if unset), ``cpu_count`` (os.cpu_count(): the machine's logical CPUs) and
    ``cpus_available`` (the CPUs this process may run on, e.g. a Slurm allocation; None
    where the OS does not say)."""
    record: dict[str, str | int | None] = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    record["cpu_count"] = os.cpu_count()
    try:
        record["cpus_available"] = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on macOS or Windows
        record["cpus_available"] = None
    return record


def provenance() -> dict:
    """The software and machine of this process (run.json, ``segments[k].provenance``):
    femphase version and git commit, the femphase modules whose source changed after this
    process imported them, Python, dependencies, host, platform, threads, pid and working
    directory (the command line's relative paths are relative to it)."""
    return {
        "femphase_version": __version__,
        "git_commit": git_commit(),
        "source_changed_since_import": changed_since_import(),
        "python": platform.python_version(),
        "python_executable": sys.executable,
        "dependencies": dependency_versions(),
        "host": socket.gethostname(),
        "platform": platform.platform(),
        "threads": threads(),
        "pid": os.getpid(),
        "cwd": os.getcwd(),
    }
