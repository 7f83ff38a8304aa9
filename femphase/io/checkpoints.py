"""HDF5 checkpoints: a state and what continues it, written atomically.

``checkpoint.h5`` holds every particle's window and field, the target radii, the clock
(time, step, phase, step within the phase), the time scheme's memory (``State.memory``), the
observables' running state (the T1 counter) and a JSON record of metadata (the resolved
scene, the outputs' lengths, the method); its attributes ``format`` =
:data:`CHECKPOINT_FORMAT` and ``version`` = :data:`CHECKPOINT_VERSION` identify it, and the
domain's ``describe()`` is stored so that a resume on another discretisation is refused.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from femphase.domains.base import Domain
from femphase.errors import SceneError
from femphase.io.files import ensure_room, failpoint, partial_path
from femphase.state import State

__all__ = ["CHECKPOINT_FORMAT", "CHECKPOINT_VERSION", "load_checkpoint", "read_checkpoint_metadata", "save_checkpoint"]

#: The checkpoint file's ``format`` attribute and the ``version`` this code writes and reads.
CHECKPOINT_FORMAT = "femphase-checkpoint"
CHECKPOINT_VERSION = 1


def save_checkpoint(path: Path, state: State, observers: dict[str, np.ndarray] | None = None,
                    metadata: dict | None = None) -> None:
    """Write the complete state to an HDF5 file, atomically (written beside it, then renamed
    over it: a crash mid-write leaves the old file intact).

    Attributes: ``format`` = "femphase-checkpoint", ``version``, ``domain`` (JSON of
    :meth:`Domain.describe`, checked on resume), ``time``, ``step``, ``phase``, ``phase_step``.
    Datasets: ``windows`` (N, 4, the domain's encoding), group ``window_positions``: what the
    domain stores of windows beyond their rows (a shaped mesh window's dofs,
    :meth:`Domain.window_positions`), ``sizes`` (N,), ``values`` (all
    fields concatenated in particle order), ``radii`` (N,); group ``observers``: the
    observables' running state (the T1 counter's); group ``memory``: what the time scheme
    carries from step to step (``State.memory``). ``metadata`` (JSON-able values) is kept
    as JSON attributes ``meta_<name>`` (:func:`read_checkpoint_metadata`)."""
    import h5py

    path = Path(path)
    ensure_room(path, [*state.fields, *(observers or {}).values(), *state.memory.values()], state.time)
    tmp = partial_path(path)
    with h5py.File(tmp, "w") as handle:
        handle.attrs.update({
            "format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION,
            "domain": json.dumps(state.domain.describe(), sort_keys=True),
            "time": state.time, "step": state.step, "phase": state.phase, "phase_step": state.phase_step,
        })
        handle["windows"] = state.domain.windows_to_array(state.windows)
        positions = handle.create_group("window_positions")
        for name, values in state.domain.window_positions(state.windows).items():
            positions[name] = values
        handle["sizes"] = np.array([f.size for f in state.fields], dtype=np.int64)
        handle["values"] = np.concatenate(state.fields) if state.fields else np.zeros(0)
        handle["radii"] = state.radii
        group = handle.create_group("observers")
        for name, values in (observers or {}).items():
            group[name] = values
        memory = handle.create_group("memory")
        for name, values in state.memory.items():
            memory[name] = values
        for name, value in (metadata or {}).items():
            handle.attrs[f"meta_{name}"] = json.dumps(value)
    failpoint("checkpoint")
    os.replace(tmp, path)


def read_checkpoint_metadata(path: Path) -> dict:
    """The ``metadata`` a checkpoint was saved with (name → value)."""
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            return {name[5:]: json.loads(value) for name, value in handle.attrs.items() if name.startswith("meta_")}
    except (OSError, ValueError) as exc:
        raise SceneError("--resume", str(path), f"a readable checkpoint ({exc})") from None


def load_checkpoint(path: Path, domain: Domain) -> tuple[State, dict[str, np.ndarray]]:
    """The state saved by :func:`save_checkpoint` on ``domain``, and the observers' running
    state. SceneError (key ``--resume``) when the file is no checkpoint of this code, or was
    written on another domain."""
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            if handle.attrs.get("format") != CHECKPOINT_FORMAT or int(handle.attrs.get("version", -1)) != CHECKPOINT_VERSION:
                raise SceneError("--resume", str(path), f"a {CHECKPOINT_FORMAT} file of version {CHECKPOINT_VERSION}")
            saved = json.loads(handle.attrs["domain"])
            expected = json.loads(json.dumps(domain.describe(), sort_keys=True))
            if saved != expected:
                differing = sorted(k for k in set(saved) | set(expected) if saved.get(k) != expected.get(k))
                what = ", ".join(f"{k} (checkpoint {saved.get(k)!r}, scene {expected.get(k)!r})" for k in differing)
                if "mesh_checksum" in differing and getattr(domain, "source", None):  # the same file, edited
                    raise SceneError("domain.mesh", domain.source, f"the mesh {path} was written on; the file's "
                                     f"content differs: {what}")
                raise SceneError("--resume", str(path), f"a checkpoint of the scene's domain; it differs in {what}")
            positions = {name: handle["window_positions"][name][()] for name in handle.get("window_positions", {})}
            windows = domain.windows_from_array(handle["windows"][()], positions)
            sizes = handle["sizes"][()]
            fields = [f.copy() for f in np.split(handle["values"][()], np.cumsum(sizes)[:-1])] if len(sizes) else []
            attrs = handle.attrs
            state = State(domain, windows, fields, handle["radii"][()].copy(), float(attrs["time"]),
                          int(attrs["step"]), int(attrs["phase"]), int(attrs["phase_step"]))
            observers = {name: handle["observers"][name][()] for name in handle["observers"]}
            state.memory = {name: handle["memory"][name][()] for name in handle.get("memory", {})}
    except (OSError, KeyError) as exc:
        raise SceneError("--resume", str(path), f"a readable checkpoint ({exc})") from None
    return state, observers
