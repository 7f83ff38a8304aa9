"""Compare two runs, or a run and external grid data: ``femphase compare DIR_A DIR_B``.

    femphase compare DIR_A DIR_B [-o OUT] [--fields]

Each input is a run directory (read by :func:`femphase.io.reader.open_run`) of a structured-grid or a meshed
run, or a file of **external grid data**,
NumPy ``.npz`` or HDF5 (``.h5``/``.hdf5``) holding four arrays:

    time  (F,)             frame times (time units)
    x     (nx,)            node columns x = ix·h, ix = 0 … nx−1 (periodic: no copy of x = Lx)
    y     (ny,)            node rows y = iy·h, iy = 0 … ny−1 (the walls are y = 0 and y = Ly)
    phi   (F, N, ny, nx)   nodal values of every particle's field, phi[f, i, iy, ix]

i.e. the nodes of the run's grid (:mod:`femphase.domains.grid.lattice`), the particles in the run's order.
:func:`grid_data_from_run` and :func:`save_grid_data` write a grid run in this layout.

Which inputs can be compared: two runs always by their observables and energies (their
periods must agree: grid runs at different h, meshed runs, a meshed and a grid run); their
fields only when both are on the same domain (for grids the same nx, ny, h; else the same
:meth:`~femphase.domains.base.Domain.describe`: kind, dofs, period, mesh checksum), else a clear
error. Grid data holds fields only, so it is compared only with grid runs on its grid.

What is compared, at the frame times both inputs have (matched to 1e-6 time units plus 1e-9
of the time; the summary says how many frames each input has and how many matched):

* observables, per frame: the largest ``|difference|`` over the particles (particles matched by
  id) of the centroid x (minimum image over the period) and y, the area ∫φ², the elongation
  and the orientation (nematic: differences taken modulo π; only for particles whose
  elongation is ≥ 0.01 in both inputs, a disc has no orientation; a mesh whose diagonals
  all point one way, meshes/straight_structured.vtu, reads a disc as r = 0.026 along them,
  docs/outputs.md, so there the orientations of near-discs are the mesh's). The centroid and shape
  are taken over the particles present in both inputs (a vanished particle's are NaN,
  docs/outputs.md); the area over all, so a particle that vanished in one input only
  shows there. Runs read them from
  particles.csv; for grid data they are computed from the fields
  (:func:`femphase.analysis.shape.shape_observables`);
* energies (two run directories only; global.csv): ``|difference|`` of the free energy and of
  its interface, area and repulsion parts;
* fields (with ``--fields``, always when an input is grid data): the L2 norm with the
  lumped-mass (nodal) quadrature, ‖e‖ = (Σ_k m_k e_k²)^½, and the L∞ norm of the
  difference. Per particle (``phi_l2`` = (Σ_i ‖Δφ_i‖²)^½, ``phi_linf`` = max_i ‖Δφ_i‖∞, and
  every particle's ‖Δφ_i‖ in compare.json) when both inputs have per-particle fields (grid
  data, or runs with ``output.per_particle_fields = true``); always for the total
  Σ_i φ_i (``phi_sum_l2``, ``phi_sum_linf``).

Warnings: two runs whose particles start more than 1 apart, a run compared with itself,
and two runs whose ``[model]`` or ``[particles]`` tables or channel widths differ (their
differences are then not the methods'). The table marks a ``final`` value taken at an
earlier common frame than the last (one input lacks the last rows).

Output in OUT (default DIR_B/compare, or B's file name with the suffix ``_compare`` next to
it; checked writable before the comparison): compare.csv (one row per common frame),
compare.json (the same plus a summary and the per-particle field differences) and
compare.png; a summary table is printed.
"""

from __future__ import annotations

import csv
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from skfem import MeshTri

from femphase.analysis.shape import shape_observables
from femphase.domains.base import Domain
from femphase.domains.grid.domain import GridDomain
from femphase.domains.grid.lattice import ChannelGrid, grid_dof_map
from femphase.io.reader import FieldFrames, match_times, open_run
from femphase.io.rundir import COMPARISON, COMPARISON_DIR
from femphase.state import State

__all__ = ["ENERGIES", "FIELD_NORMS", "GRID_SUFFIXES", "OBSERVABLES", "ORIENTATION_MIN_ELONGATION", "START_OFFSET",
           "GridData", "Source", "compare_runs", "default_output", "format_table", "grid_data_from_run", "load_grid_data",
           "open_source", "save_grid_data", "write_comparison"]

#: Suffixes of grid data files (NumPy .npz, HDF5).
GRID_SUFFIXES = (".npz", ".h5", ".hdf5")
#: Orientations are compared only where both elongations are at least this: a disc has none.
ORIENTATION_MIN_ELONGATION = 0.01
OBSERVABLES = ("x", "y", "area", "elongation", "orientation")
#: global.csv column → name in the comparison (``area`` is taken by the particle area).
ENERGIES = {"free_energy": "energy_total", "interface": "energy_interface",
            "area": "energy_area", "repulsion": "energy_repulsion"}
FIELD_NORMS = ("phi_sum_l2", "phi_sum_linf", "phi_l2", "phi_linf")


@dataclass
class GridData:
    """Fields on the nodes of a channel grid: phi (F, N, ny, nx) at times (F,)."""

    time: np.ndarray
    x: np.ndarray
    y: np.ndarray
    phi: np.ndarray

    def __post_init__(self) -> None:
        self.time, self.x, self.y = (np.asarray(a, dtype=float) for a in (self.time, self.x, self.y))
        for name in ("time", "x", "y"):
            if getattr(self, name).ndim != 1:
                raise ValueError(f"grid data: '{name}' has shape {getattr(self, name).shape}; expected a 1-D array")
        shape = (self.time.size, self.y.size, self.x.size)
        if self.phi.ndim != 4 or (self.phi.shape[0], *self.phi.shape[2:]) != shape:
            raise ValueError(
                f"grid data: 'phi' has shape {self.phi.shape}; expected (F, N, ny, nx) = "
                f"({shape[0]}, N, {shape[1]}, {shape[2]}) from the sizes of time, y and x"
            )
        if self.phi.shape[1] == 0:
            raise ValueError(f"grid data: 'phi' has shape {self.phi.shape}, the fields of N = 0 particles; "
                             "expected at least one particle")
        if not (np.all(np.isfinite(self.time)) and np.all(np.diff(self.time) > 0)):
            raise ValueError(f"grid data: 'time' must be finite and strictly increasing (got {self.time.tolist()[:6]}"
                             f"{' …' if self.time.size > 6 else ''})")
        bad = ~np.isfinite(self.phi)
        if bad.any():
            frame = int(np.argwhere(bad)[0][0])
            raise ValueError(f"grid data: 'phi' holds {int(bad.sum())} NaN or infinite values, the first in frame "
                             f"{frame} (t = {self.time[frame]:g}); compare finite fields")

    def grid(self) -> ChannelGrid:
        """The channel grid of x and y; ValueError when they are not a uniform lattice from 0."""
        if self.x.size < 2 or self.y.size < 2:
            raise ValueError("grid data: x and y need at least 2 nodes each")
        h = float(self.x[1] - self.x[0])
        grid = ChannelGrid(nx=self.x.size, ny=self.y.size, h=h)
        x, y = grid.coordinates()
        if h <= 0 or not (np.allclose(self.x, x, atol=1e-9 * h) and np.allclose(self.y, y, atol=1e-9 * h)):
            raise ValueError(
                "grid data: x and y must be the nodes x = ix·h, y = iy·h of a uniform grid starting at 0 "
                f"(got x from {self.x[0]:g} to {self.x[-1]:g}, y from {self.y[0]:g} to {self.y[-1]:g})"
            )
        return grid


def save_grid_data(path: str | Path, data: GridData) -> None:
    """Write grid data as .npz or HDF5 (.h5, .hdf5), chosen by the suffix."""
    path = Path(path)
    arrays = {"time": data.time, "x": data.x, "y": data.y, "phi": data.phi}
    if path.suffix == ".npz":
        np.savez_compressed(path, **arrays)
    elif path.suffix in (".h5", ".hdf5"):
        import h5py

        with h5py.File(path, "w") as handle:
            for name, values in arrays.items():
                handle.create_dataset(name, data=values)
    else:
        raise ValueError(f"grid data file '{path}': the suffix must be one of {GRID_SUFFIXES}")


def load_grid_data(path: str | Path) -> GridData:
    """Read grid data written in the layout of the module docstring."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"'{path}' is neither a run directory nor a grid data file"
                         + ("" if path.exists() else " (it does not exist)"))
    try:
        if path.suffix == ".npz":
            import zipfile

            if not zipfile.is_zipfile(path):  # np.load would blame pickled data in a damaged file
                raise ValueError("it is not a NumPy .npz archive (a zip file of arrays, numpy.savez)")
            with np.load(path) as handle:
                arrays = {name: handle[name] for name in handle.files}
        elif path.suffix in (".h5", ".hdf5"):
            import h5py

            with h5py.File(path, "r") as handle:  # the arrays at the top level; groups are not read
                arrays = {name: handle[name][()] for name in handle if isinstance(handle[name], h5py.Dataset)}
        else:
            raise ValueError(f"grid data file '{path}': the suffix must be one of {GRID_SUFFIXES}")
    except (OSError, ValueError) as exc:
        if "suffix" in str(exc):
            raise
        raise ValueError(f"grid data file '{path}' cannot be read: {exc}") from None
    missing = [name for name in ("time", "x", "y", "phi") if name not in arrays]
    if missing:
        raise ValueError(
            f"grid data file '{path}' lacks {missing}; it must hold time (F,), x (nx,), y (ny,) and phi (F, N, ny, nx)"
            " (in an HDF5 file as datasets at its top level, not in a group)"
        )
    return GridData(arrays["time"], arrays["x"], arrays["y"], np.asarray(arrays["phi"], dtype=float))


# -- the inputs, behind one interface ---------------------------------------------------------
@dataclass
class Source:
    """One side of a comparison: a run directory (on any domain) or grid data."""

    label: str
    domain: Domain
    is_run: bool
    particle_times: np.ndarray = field(default_factory=lambda: np.empty(0))
    observables: dict = field(default_factory=dict)  # name → (F, N)
    energy_times: np.ndarray = field(default_factory=lambda: np.empty(0))
    settings: dict = field(default_factory=dict)  # a run's resolved scene
    energies: dict = field(default_factory=dict)  # name → (F,)
    field_times: np.ndarray = field(default_factory=lambda: np.empty(0))
    per_particle: bool = False
    _frames: FieldFrames | None = None
    _grid_data: GridData | None = None
    _dof_map: np.ndarray | None = None

    @property
    def grid(self) -> ChannelGrid | None:
        """The channel grid of a structured domain, None for a meshed one."""
        return getattr(self.domain, "grid", None)

    @property
    def lumped_mass(self) -> np.ndarray:
        return self.domain.operators.lumped_mass

    def describe(self) -> str:
        if self.grid is not None:
            return f"{self.grid.nx} × {self.grid.ny} nodes at h = {self.grid.h:g}"
        d = self.domain.describe()
        return f"a {d['kind']} domain of {d['n_dofs']} dofs, period {self.domain.period:g}"

    def fields(self, k: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Frame k of the fields: Σ_i φ_i (n_dofs,) and φ (N, n_dofs) or None, in dof order
        (grid order on the structured channel)."""
        if self._grid_data is not None:
            phi = self._grid_data.phi[k].reshape(self._grid_data.phi.shape[1], -1)
            return phi.sum(axis=0), phi

        def on_dofs(values):  # mesh nodes → dofs (the seam's copy lands on its partner)
            out = np.empty(self.domain.n_dofs)
            out[self._dof_map] = values
            return out

        try:  # a damaged frame file: named by run and frame, not by h5py's or numpy's message alone
            _, data = self._frames.read(k)
            names = particle_field_names(data)
            phi = np.stack([on_dofs(data[n]) for n in names]) if names else None
            return on_dofs(data["phi_sum"]), phi
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"run '{self.label}': its field frame {k} (t = {self.field_times[k]:g}) cannot be read "
                             f"({type(exc).__name__}: {exc}); the frame file is damaged or missing") from None

    def close(self) -> None:
        if self._frames is not None:
            self._frames.close()


def particle_field_names(names) -> list[str]:
    """A frame's per-particle field names (``phi_000``, …) in particle order: by number, as
    text put ``phi_1000`` between ``phi_100`` and ``phi_101``."""
    return sorted((n for n in names if n.startswith("phi_") and n[4:].isdigit()), key=lambda n: int(n[4:]))


def open_source(path: str | Path, need_fields: bool) -> Source:
    """Read a run directory's scene and CSVs (and open its fields), or load grid data."""
    path = Path(path)
    if path.is_dir():
        return _open_run(path, need_fields)
    if path.suffix in GRID_SUFFIXES or path.is_file():
        return _open_grid_data(path)
    raise ValueError(
        f"'{path}' does not exist; give a run directory (from `femphase run`) or a grid data file "
        f"({', '.join(GRID_SUFFIXES)})"
    )


def _open_run(path: Path, need_fields: bool) -> Source:
    for name in ("scene.toml", "particles.csv", "global.csv"):
        if not (path / name).is_file():
            raise ValueError(f"'{path}' is not a run directory: it has no {name}")
    run = open_run(path)
    scene = run.loaded_scene
    domain = scene.domain
    source = Source(str(path), domain, True)
    frames = run.complete()
    if frames.time.size == 0:
        raise ValueError(f"run '{path}' has no frame in particles.csv (it holds its header only): nothing to compare")
    source.particle_times = frames.time
    source.settings = run.scene
    source.observables = {name: frames.particles[name] for name in OBSERVABLES}
    written = np.isfinite(run.globals["free_energy"])
    source.energy_times = run.time[written]
    source.energies = {ENERGIES[k]: run.globals[k][written] for k in ENERGIES}
    if need_fields:
        if not (path / "fields.xdmf").is_file():
            raise ValueError(
                f"run '{path}' has no fields.xdmf (it was run with output.fields = false); "
                "compare it without --fields"
            )
        fields = run.fields()
        source._frames = fields
        if source.grid is not None:
            source._dof_map = grid_dof_map(MeshTri(fields.points.T.copy(), fields.triangles.T.copy()), source.grid)
        else:  # written on the domain's own mesh (femphase.io.fields.point_data)
            mesh = domain.mesh
            if fields.points.shape[0] != mesh.p.shape[1] or not np.allclose(fields.points.T, mesh.p,
                                                                            atol=1e-9 * domain.spacing):
                fields.close()
                raise ValueError(
                    f"run '{path}': fields.xdmf is not on the mesh of its scene ({fields.points.shape[0]} nodes, "
                    f"the mesh {mesh.p.shape[1]}); was the mesh file changed after the run?"
                )
            source._dof_map = domain.dof_map
        source.field_times = fields.times
        source.per_particle = bool(scene.output.per_particle_fields)
    return source


def _open_grid_data(path: Path) -> Source:
    data = load_grid_data(path)
    domain = GridDomain(data.grid())
    source = Source(str(path), domain, False, _grid_data=data)
    source.field_times = data.time
    source.per_particle = True
    # observables from the fields, as a run computes them
    window = domain.full_window()
    n = data.phi.shape[1]
    shapes = []
    for k in range(data.time.size):
        state = State(domain, [window] * n, [phi.ravel() for phi in data.phi[k]], np.ones(n))
        shapes.append(shape_observables(state))
    source.particle_times = data.time
    source.observables = {name: np.array([getattr(s, name) for s in shapes]) for name in OBSERVABLES}
    return source


def grid_data_from_run(directory: str | Path) -> GridData:
    """A run's per-particle fields (output.per_particle_fields = true) as grid data."""
    source = open_source(directory, need_fields=True)
    try:
        if not source.is_run or not source.per_particle:
            raise ValueError(f"'{directory}' has no per-particle fields; run it with output.per_particle_fields = true")
        grid = source.grid
        if grid is None:
            raise ValueError(f"'{directory}' is a run on a {source.domain.kind} domain; grid data holds the "
                             "fields of structured-grid runs only")
        phi = np.stack([source.fields(k)[1] for k in range(source.field_times.size)])
        x, y = grid.coordinates()
        return GridData(source.field_times, x, y, phi.reshape(phi.shape[0], phi.shape[1], grid.ny, grid.nx))
    finally:
        source.close()


# -- the comparison -----------------------------------------------------------------------


def _span(times: np.ndarray) -> str:
    # 9 digits: times 2e-6 apart printed alike at %g
    return f"{times.size} frames, t = {times.min():.9g} … {times.max():.9g}" if times.size else "no frames"


def _on_frames(times: np.ndarray, table_times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """values (one per table time) at ``times``; NaN where the table has no such frame."""
    out = np.full(times.size, np.nan)
    rows, k = match_times(times, table_times)
    out[rows] = values[k]
    return out


def _difference(name: str, a: np.ndarray, b: np.ndarray, length: float) -> np.ndarray:
    d = a - b
    if name == "x":  # centroids on the periodic line: the minimum image
        d = (d + 0.5 * length) % length - 0.5 * length
    elif name == "orientation":  # nematic axes: θ and θ + π are the same
        d = (d + 0.5 * np.pi) % np.pi - 0.5 * np.pi
    return np.abs(d)


def compare_runs(a: str | Path, b: str | Path, fields: bool = False) -> dict:
    """Differences between two runs, or a run and grid data (see the module docstring).

    Returns {"a", "b", "grid" (nx, ny, h; None for a meshed domain), "domain" (A's
    :meth:`~femphase.domains.base.Domain.describe`), "time" (common frame times), "series"
    {quantity: per-frame values}, "summary" {quantity: {"max", "at_time", "final"}},
    "per_particle" {"phi_l2": (F, N) list when available}, "field_mode"}. Raises ValueError
    with the reason when an input cannot be read, the grids (or, for fields, the domains)
    differ or there is no common frame time.
    """
    # grid data holds nothing but fields, so they are compared whenever an input is grid data
    fields = fields or not (Path(a).is_dir() and Path(b).is_dir())
    sa = open_source(a, fields)
    try:
        sb = open_source(b, fields)
    except Exception:
        sa.close()
        raise
    try:
        return _compare(sa, sb, fields)
    finally:
        sa.close()
        sb.close()


def _check_domains(a: Source, b: Source, with_fields: bool) -> None:
    """Domains must share the period, and the whole discretisation (for grids: the same
    grid) when their fields are compared, as they are whenever an input is grid data."""
    if a.grid is not None and b.grid is not None:
        if a.grid == b.grid:
            return
        if with_fields:
            raise ValueError(
                f"the grids differ: '{a.label}' has {a.grid.nx} × {a.grid.ny} nodes at h = {a.grid.h:g}, "
                f"'{b.label}' has {b.grid.nx} × {b.grid.ny} at h = {b.grid.h:g}; fields are compared only on "
                "the same grid" + (": compare the runs without --fields (observables and energies)"
                                   if a.is_run and b.is_run else ", and grid data holds nothing else (its x stops "
                                   "one spacing short of Lx: the periodic copy x = Lx is no node)")
            )
    if not np.isclose(a.domain.period, b.domain.period, rtol=1e-9, atol=0.0):
        raise ValueError(
            f"the domains differ in period: '{a.label}' has {a.domain.period:g}, '{b.label}' has "
            f"{b.domain.period:g}; compare runs on domains of the same period"
        )
    if not (a.is_run and b.is_run):
        run = a if a.is_run else b
        raise ValueError(
            f"grid data is compared only with runs on the structured grid; '{run.label}' is a run on "
            f"{run.describe()}"
        )
    if with_fields:
        da, db = a.domain.describe(), b.domain.describe()
        if da != db:
            # keys of both (a grid states no period, a mesh no nx): "period" differed for 70 and 70
            differing = sorted(k for k in set(da) & set(db) if da[k] != db[k])
            raise ValueError(
                f"the fields of '{a.label}' ({a.describe()}) and '{b.label}' ({b.describe()}) lie on "
                f"different domains (they differ in {', '.join(differing)}); fields are compared only "
                "between runs on the same domain: compare these without --fields (observables and energies)"
            )


def _warn_other_physics(a: Source, b: Source) -> None:
    """Warn where two runs are one (a directory compared with itself), or differ in their
    model or their channel, not only in the method: the differences are then not the
    methods' (compare checks the period alone, and runs on other discretisations are what
    it is for)."""
    if not (a.is_run and b.is_run):
        return
    if Path(a.label).resolve() == Path(b.label).resolve():
        warnings.warn(f"'{a.label}' is compared with itself: every difference is 0", stacklevel=4)
        return
    differing = []
    for table in ("model", "particles"):
        one, other = a.settings.get(table, {}), b.settings.get(table, {})
        differing += [f"{table}.{key}: {one.get(key)!r} against {other.get(key)!r}" for key in sorted(set(one) | set(other))
                      if one.get(key) != other.get(key)]
    if not np.isclose(a.domain.width, b.domain.width, rtol=1e-9):
        differing.append(f"the channel's width: {a.domain.width:g} against {b.domain.width:g}")
    if differing:
        warnings.warn(f"'{a.label}' and '{b.label}' differ in more than the method: {'; '.join(differing)}; their "
                      "differences are not the discretisations' alone", stacklevel=4)


#: Lattice units two inputs' particles may be apart at t = 0 before :func:`compare_runs`
#: warns that the runs did not start from the same state.
START_OFFSET = 1.0


def _compare(a: Source, b: Source, with_fields: bool) -> dict:
    _check_domains(a, b, with_fields)
    ia, ib = match_times(a.particle_times, b.particle_times)
    if ia.size == 0:
        raise ValueError(
            f"no common frame times: '{a.label}' has {_span(a.particle_times)}, "
            f"'{b.label}' has {_span(b.particle_times)}"
        )
    n_a, n_b = a.observables["x"].shape[1], b.observables["x"].shape[1]
    if n_a != n_b:
        raise ValueError(f"'{a.label}' has {n_a} particles, '{b.label}' has {n_b}; they must match")
    times = a.particle_times[ia]
    _warn_other_physics(a, b)
    series: dict[str, np.ndarray] = {}
    # an orientation is defined only for particles that are elongated in both inputs
    elongated = np.minimum(a.observables["elongation"][ia], b.observables["elongation"][ib]) >= ORIENTATION_MIN_ELONGATION
    for name in OBSERVABLES:
        diff = _difference(name, a.observables[name][ia], b.observables[name][ib], a.domain.period)
        if name == "orientation":
            diff = np.where(elongated, diff, -np.inf)
        # over the particles present in both: a vanished particle's shape columns are NaN (its
        # area is not, so a particle vanished in one input only shows in the area's difference)
        largest = np.where(np.isnan(diff), -np.inf, diff).max(axis=1)
        series[name] = np.where(np.isfinite(largest), largest, np.nan)
    start = max(series["x"][0], series["y"][0])
    if times[0] == 0.0 and start > START_OFFSET:  # particles are paired by id
        warnings.warn(f"'{a.label}' and '{b.label}' start from different states: at t = 0 their particles (paired "
                      f"by id) are up to {start:.3g} apart in x or y, so the differences are not the methods'. A "
                      "random layout places its particles differently on different domains; give both runs the "
                      'same centres with layout = "list"', stacklevel=3)
    if a.is_run and b.is_run:
        for name in ENERGIES.values():
            series[name] = np.abs(_on_frames(times, a.energy_times, a.energies[name])
                                  - _on_frames(times, b.energy_times, b.energies[name]))
    per_particle = {}
    mode = "none"
    if with_fields:
        rows_a, ka = match_times(times, a.field_times)
        rows_b, kb = match_times(times, b.field_times)
        rows, pick_a, pick_b = np.intersect1d(rows_a, rows_b, return_indices=True)
        if rows.size == 0:
            raise ValueError(
                f"no common frame times of the fields: '{a.label}' has {_span(a.field_times)}, "
                f"'{b.label}' has {_span(b.field_times)}"
            )
        mode = "per_particle" if a.per_particle and b.per_particle else "phi_sum"
        names = FIELD_NORMS if mode == "per_particle" else FIELD_NORMS[:2]
        norms = {name: np.full(times.size, np.nan) for name in names}
        particle_l2 = np.full((times.size, n_a), np.nan)
        m = a.lumped_mass
        for row, k_a, k_b in zip(rows, ka[pick_a], kb[pick_b]):
            sum_a, phi_a = a.fields(k_a)
            sum_b, phi_b = b.fields(k_b)
            e = sum_a - sum_b
            norms["phi_sum_l2"][row] = np.sqrt(e**2 @ m)
            norms["phi_sum_linf"][row] = np.abs(e).max()
            if mode == "per_particle":
                if phi_a.shape != phi_b.shape:
                    raise ValueError(
                        f"'{a.label}' has fields of {phi_a.shape[0]} particles, '{b.label}' of {phi_b.shape[0]}"
                    )
                e = phi_a - phi_b
                particle_l2[row] = np.sqrt(e**2 @ m)
                norms["phi_l2"][row] = np.sqrt(np.sum(particle_l2[row] ** 2))
                norms["phi_linf"][row] = np.abs(e).max()
        series.update(norms)
        if mode == "per_particle":
            per_particle["phi_l2"] = particle_l2
    summary = {}
    for name, values in series.items():
        finite = np.isfinite(values)
        if not finite.any():
            continue
        k = int(np.nanargmax(values))
        summary[name] = {"max": float(values[k]), "at_time": float(times[k]),
                         "final": float(values[finite][-1]), "final_time": float(times[finite][-1])}
    return {
        "a": a.label,
        "b": b.label,
        "grid": {"nx": a.grid.nx, "ny": a.grid.ny, "h": a.grid.h} if a.grid is not None else None,
        "domain": a.domain.describe(),
        "n_particles": int(n_a),
        "frames": {"a": int(a.particle_times.size), "b": int(b.particle_times.size)},
        "time": times,
        "series": series,
        "summary": summary,
        "per_particle": per_particle,
        "field_mode": mode,
    }


# -- output -------------------------------------------------------------------------------
def format_table(result: dict) -> str:
    """The summary table that ``femphase compare`` prints."""
    t = result["time"]
    lines = [
        f"A: {result['a']}",
        f"B: {result['b']}",
        f"{t.size} common frames (of {result['frames']['a']} in A and {result['frames']['b']} in B), "
        f"t = {t[0]:g} … {t[-1]:g}; {result['n_particles']} particles; fields compared: {result['field_mode']}",
        "",
        f"{'quantity':<18}{'max |A − B|':>14}{'at t':>12}{'final':>14}",
    ]
    early = []
    for name, row in result["summary"].items():
        mark = "" if row["final_time"] == t[-1] else "*"
        early += [f"{name} at t = {row['final_time']:g}"] if mark else []
        lines.append(f"{name:<18}{row['max']:>14.4g}{row['at_time']:>12.6g}{row['final']:>14.4g}{mark}")
    if early:  # one input lacks the last rows of these: their final value is an earlier frame's
        lines.append(f"* final value of an earlier common frame: {', '.join(early)}")
    return "\n".join(lines)


def write_comparison(result: dict, directory: str | Path) -> Path:
    """compare.csv, compare.json and compare.png in ``directory`` (created)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    names = list(result["series"])
    table, summary, figure = COMPARISON
    with (directory / table).open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["time"] + names)
        for k, t in enumerate(result["time"]):
            writer.writerow([repr(float(t))] + [repr(float(result["series"][n][k])) for n in names])

    def plain(value):
        if isinstance(value, np.ndarray):
            return [plain(v) for v in value.tolist()] if value.ndim else plain(value.item())
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        if isinstance(value, list):
            return [plain(v) for v in value]
        if isinstance(value, float) and not np.isfinite(value):
            return None
        return value

    (directory / summary).write_text(json.dumps(plain(result), indent=1) + "\n")
    _plot(result, directory / figure)
    return directory


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("observables (max over particles)", OBSERVABLES),
              ("energies", tuple(ENERGIES.values())), ("fields", FIELD_NORMS)]
    panels = [(title, [n for n in names if n in result["series"]]) for title, names in panels]
    panels = [(title, names) for title, names in panels if names]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels), 3.6), squeeze=False)
    for ax, (title, names) in zip(axes[0], panels):
        for name in names:
            values = np.asarray(result["series"][name], dtype=float)
            ax.plot(result["time"], np.where(values > 0, values, np.nan), marker=".", label=name)
        ax.set_yscale("log")
        ax.set_xlabel("time")
        ax.set_ylabel("|A − B|")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7)
    fig.suptitle(f"A = {Path(result['a']).name}, B = {Path(result['b']).name}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def default_output(b: str | Path) -> Path:
    b = Path(b)
    return b / COMPARISON_DIR if b.is_dir() else b.with_name(b.stem + "_compare")
