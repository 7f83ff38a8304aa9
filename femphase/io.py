"""Run directories: what ``femphase run`` writes, and reading it back.

DIR/
  scene.toml      the resolved scene (every default filled in)
  fields.xdmf     fields per frame on the non-periodic mesh (+ fields.h5; opens in ParaView):
                  phi_sum = Σ_i φ_i, phi_max = max_i φ_i, label = argmax_i φ_i where it
                  exceeds 1/2 else −1, and phi_000 … when output.per_particle_fields
  particles.csv   one row per particle per frame: time, id, x, y, area, elongation,
                  orientation (+ psi6_abs, psi2_abs with output.observables = ["order"])
  global.csv      one row per frame: time, step, free_energy, interface, area, repulsion
                  (+ Psi6, Psi2, lattice_angle, t1_count with "order")
  checkpoint.npz  the last frame's complete state; ``femphase run --resume`` continues from it
  run.json        version, method, settings, steps, wall time, status and message
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import meshio
import numpy as np

from .mesh import ChannelGrid
from .state import State
from .windows import Window

PARTICLE_COLUMNS = ["time", "id", "x", "y", "area", "elongation", "orientation"]
GLOBAL_COLUMNS = ["time", "step", "free_energy", "interface", "area", "repulsion"]
ORDER_PARTICLE_COLUMNS = ["psi6_abs", "psi2_abs"]
ORDER_GLOBAL_COLUMNS = ["Psi6", "Psi2", "lattice_angle", "t1_count"]


def to_toml(data: dict) -> str:
    """A small TOML writer for the resolved scene (tables, arrays of tables, plain values)."""

    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, (dict, list))]
    for key, table in data.items():
        if isinstance(table, dict):
            lines += ["", f"[{key}]"] + [f"{k} = {value(v)}" for k, v in table.items() if v is not None]
        elif isinstance(table, list):
            for item in table:
                lines += ["", f"[[{key}]]"] + [f"{k} = {value(v)}" for k, v in item.items()]
    return "\n".join(lines) + "\n"


def save_checkpoint(path: Path, state: State, observers: dict[str, np.ndarray] | None = None) -> None:
    """Write the complete state atomically (a crash mid-write leaves the old file intact),
    with the ``observers``' running state (the T1 counter's) under their own names."""
    tmp = path.with_suffix(".tmp.npz")
    np.savez(
        tmp,
        grid=np.array([state.grid.nx, state.grid.ny]),
        spacing=state.grid.h,
        windows=np.array([[w.iy0, w.ny, w.ix0, w.nx] for w in state.windows], dtype=np.int64),
        values=np.concatenate([f.ravel() for f in state.fields]),
        radii=state.radii,
        clock=np.array([state.time]),
        counters=np.array([state.step, state.phase, state.phase_step]),
        **(observers or {}),
    )
    os.replace(tmp, path)


def load_observers(path: Path) -> dict[str, np.ndarray]:
    """The observers' running state kept in a checkpoint (empty for older checkpoints)."""
    with np.load(path) as data:
        return {name: data[name].copy() for name in data.files if name.startswith("t1_")}


def load_checkpoint(path: Path) -> State:
    with np.load(path) as data:
        grid = ChannelGrid(int(data["grid"][0]), int(data["grid"][1]), float(data["spacing"]))
        windows = [Window(*map(int, row)) for row in data["windows"]]
        sizes = [w.ny * w.nx for w in windows]
        chunks = np.split(data["values"], np.cumsum(sizes)[:-1])
        fields = [c.reshape(w.ny, w.nx).copy() for c, w in zip(chunks, windows)]
        step, phase, phase_step = map(int, data["counters"])
        return State(grid, windows, fields, data["radii"].copy(), float(data["clock"][0]), step, phase, phase_step)


def point_data(state: State, dof_map: np.ndarray, per_particle: bool) -> dict[str, np.ndarray]:
    """Frame data on the nodes of the non-periodic mesh (see the module docstring)."""
    phis = state.global_fields()
    best = np.argmax(phis, axis=0)
    top = phis[best, np.arange(phis.shape[1])]
    data = {
        "phi_sum": phis.sum(axis=0),
        "phi_max": top,
        "label": np.where(top > 0.5, best, -1).astype(float),
    }
    if per_particle:
        data.update({f"phi_{i:03d}": phi for i, phi in enumerate(phis)})
    return {name: values[dof_map] for name, values in data.items()}


class FieldWriter:
    """fields.xdmf + fields.h5 through meshio; on resume keeps the frames up to t_keep."""

    def __init__(self, directory: Path, mesh, keep_until: float | None = None) -> None:
        self.path = directory / "fields.xdmf"
        kept = []
        if keep_until is not None and self.path.exists():
            with meshio.xdmf.TimeSeriesReader(str(self.path.resolve())) as reader:
                reader.read_points_cells()
                for k in range(reader.num_steps):
                    t, data, _ = reader.read_data(k)
                    if t <= keep_until + 1e-9:
                        kept.append((t, {name: np.array(v) for name, v in data.items()}))
        self._writer = meshio.xdmf.TimeSeriesWriter(str(self.path.resolve()))
        # meshio opens the .h5 file relative to the working directory, not to the .xdmf
        cwd = os.getcwd()
        os.chdir(directory)
        try:
            self._writer.__enter__()
        finally:
            os.chdir(cwd)
        points = np.vstack([mesh.p, np.zeros(mesh.p.shape[1])]).T
        self._writer.write_points_cells(points, [("triangle", mesh.t.T)])
        for t, data in kept:
            self._writer.write_data(t, point_data=data)

    def write(self, time: float, data: dict[str, np.ndarray]) -> None:
        self._writer.write_data(time, point_data=data)

    def close(self) -> None:
        self._writer.__exit__(None, None, None)


class CsvWriter:
    """A CSV file with a header; on resume keeps the rows whose time ≤ t_keep."""

    def __init__(self, path: Path, columns: list[str], keep_until: float | None = None) -> None:
        rows = []
        if keep_until is not None and path.exists():
            with path.open() as handle:
                rows = [r for r in csv.reader(handle)][1:]
            rows = [r for r in rows if float(r[0]) <= keep_until + 1e-9]
        self._handle = path.open("w", newline="")
        self._csv = csv.writer(self._handle)
        self._csv.writerow(columns)
        self._csv.writerows(rows)

    def write_rows(self, rows) -> None:
        self._csv.writerows(rows)
        self._handle.flush()

    def close(self) -> None:
        self._handle.close()


def write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=2, default=_jsonable) + "\n")


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """A run directory's CSV as columns of floats (pandas reads the same files directly)."""
    with Path(path).open() as handle:
        reader = csv.reader(handle)
        header = next(reader)
        rows = np.array([[float(x) for x in row] for row in reader]).reshape(-1, len(header))
    return {name: rows[:, k] for k, name in enumerate(header)}
