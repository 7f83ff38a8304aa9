"""Files of femphase: the resolved scene as TOML, HDF5 checkpoints, field frames on the
output mesh, JSON and CSV helpers. What a run directory holds, and its guarantees, is in
:mod:`femphase.rundir`; the CSV columns are in ``docs/outputs.md``.
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
from pathlib import Path

import numpy as np

from .domain import Domain
from .errors import SceneError
from .state import State

#: The checkpoint file's ``format`` attribute and the ``version`` this code writes and reads.
CHECKPOINT_FORMAT = "femphase-checkpoint"
CHECKPOINT_VERSION = 1


def toml_value(value) -> str:
    """``value`` as a TOML literal (inline tables and arrays; nan and inf as TOML spells them)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML literal for {value!r}")


def toml_key(key) -> str:
    """A TOML key: bare when it can be, quoted otherwise."""
    key = str(key)
    return key if key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key) else json.dumps(key)


def to_toml(data: dict) -> str:
    """A small TOML writer for the resolved scene (tables, arrays of tables, plain values)."""
    lines = [f"{toml_key(k)} = {toml_value(v)}" for k, v in data.items() if not isinstance(v, (dict, list))]
    for key, table in data.items():
        if isinstance(table, dict):
            lines += ["", f"[{toml_key(key)}]"] + [f"{toml_key(k)} = {toml_value(v)}" for k, v in table.items()
                                                  if v is not None]
        elif isinstance(table, list):
            for item in table:
                lines += ["", f"[[{toml_key(key)}]]"] + [f"{toml_key(k)} = {toml_value(v)}" for k, v in item.items()]
    return "\n".join(lines) + "\n"


def save_checkpoint(path: Path, state: State, observers: dict[str, np.ndarray] | None = None,
                    metadata: dict | None = None) -> None:
    """Write the complete state to an HDF5 file, atomically (written beside it, then renamed
    over it: a crash mid-write leaves the old file intact).

    Attributes: ``format`` = "femphase-checkpoint", ``version``, ``domain`` (JSON of
    :meth:`Domain.describe`, checked on resume), ``time``, ``step``, ``phase``, ``phase_step``.
    Datasets: ``windows`` (N, 4, the domain's encoding), ``sizes`` (N,), ``values`` (all
    fields concatenated in particle order), ``radii`` (N,); group ``observers``: the
    observables' running state (the T1 counter's); group ``memory``: what the time scheme
    carries from step to step (``State.memory``). ``metadata`` (JSON-able values) is kept
    as JSON attributes ``meta_<name>`` (:func:`read_checkpoint_metadata`)."""
    import h5py

    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as handle:
        handle.attrs.update({
            "format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION,
            "domain": json.dumps(state.domain.describe(), sort_keys=True),
            "time": state.time, "step": state.step, "phase": state.phase, "phase_step": state.phase_step,
        })
        handle["windows"] = state.domain.windows_to_array(state.windows)
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
                raise SceneError("--resume", str(path), "a checkpoint of the scene's domain; it differs in "
                                 + ", ".join(f"{k} (checkpoint {saved.get(k)!r}, scene {expected.get(k)!r})"
                                             for k in differing))
            windows = domain.windows_from_array(handle["windows"][()])
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


def point_data(state: State, per_particle: bool) -> dict[str, np.ndarray]:
    """Frame data on the nodes of the domain's non-periodic mesh (see the module
    docstring), computed window by window."""
    domain = state.domain
    layout, phi = state.flat()
    phi_sum = np.bincount(layout.node_index, weights=phi, minlength=domain.n_dofs)
    # the largest φ at every dof and its particle (on a tie the later window's), window by
    # window: sorting all positions by (dof, φ) cost 15 ms of a 50 ms frame on the N = 100
    # lattice, this 2; a window's dofs are distinct, windows may share dofs
    top = np.full(domain.n_dofs, -np.inf)
    best = np.zeros(domain.n_dofs)
    for slot, particle in enumerate(layout.order):
        part = slice(layout.offsets[slot], layout.offsets[slot + 1])
        nodes, values = layout.node_index[part], phi[part]
        higher = values >= top[nodes]
        top[nodes[higher]] = values[higher]
        best[nodes[higher]] = particle
    top[top == -np.inf] = 0.0  # dofs outside every window
    data = {"phi_sum": phi_sum, "phi_max": top, "label": np.where(top > 0.5, best, -1.0)}
    if per_particle:
        data.update({f"phi_{i:03d}": state.global_field(i) for i in range(state.n_particles)})
    return {name: values[domain.dof_map] for name, values in data.items()}


_FAILPOINT_PASSES: dict[str, int] = {}


def failpoint(name: str) -> None:
    """Fault injection for the kill tests (:mod:`femphase.faults`): with the environment
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


def atomic_write(path: Path, data: bytes | str) -> None:
    """Replace ``path`` by ``data`` atomically (a temporary file beside it, then a rename):
    a kill at any instant leaves either the old or the new file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as handle:
        handle.write(data.encode() if isinstance(data, str) else data)
    failpoint(path.name)
    os.replace(tmp, path)


def write_json(path: Path, data: dict) -> None:
    """``data`` as indented JSON, replaced atomically (numpy values become numbers/lists)."""
    atomic_write(path, json.dumps(data, indent=2, default=_jsonable) + "\n")


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """A run directory's CSV as columns of floats (pandas reads the same files directly).

    A last line without its newline is a row still being appended (a frame's rows are
    written in two flushes, :meth:`femphase.rundir.Outputs.append_rows`) and is left out, so
    the CSVs of a run under way (a sweep being aggregated) can be read."""
    text = Path(path).read_text()
    reader = csv.reader(text[: text.rfind("\n") + 1].splitlines())
    header = next(reader)
    rows = np.array([[float(x) for x in row] for row in reader]).reshape(-1, len(header))
    return {name: rows[:, k] for k, name in enumerate(header)}
