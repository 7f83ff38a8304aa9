"""`femphase aggregate` and `femphase plot` on a sweep: a 2 rates × 2 seeds sweep of a tiny
scene (one run killed part-way), its dataset checked against the CSVs it came from, its
summary against a direct computation over the last fifth of the frames."""

import csv
import json
import os
import re
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from femphase import __version__
from femphase.aggregate import (
    GLOBAL_COLUMNS,
    PARTICLE_COLUMNS,
    SUMMARY_COLUMNS,
    aggregate,
    averaging_window,
    is_current,
    read_summary,
    read_sweep,
    summarise_run,
    write_aggregate,
)
from femphase.analysis.lattice import t1_event_times
from femphase.cli import main
from femphase.errors import InputError, ResolutionWarning
from femphase.io.reader import open_run
from femphase.plot.sweep import plot_summary
from femphase.run.runner import run_scene
from femphase.scene import read_scene_data, scene_from_dict

DOCS = Path(__file__).resolve().parents[1] / "docs"
RATE, SEED = "phases.1.flow.rate", "particles.seed"
AXES = {RATE: [0.2, 0.5], SEED: [1, 2]}
SCENE = """
name = "tiny sweep"
[domain]
Lx = 42.0
Ly = 32.0
h = 2.0
[particles]
layout = "random"
N = 6
seed = 1
[output]
fields = false
observables = ["shape", "order"]
[[phases]]
name = "relax"
duration = 20.0
dt = 1.0
frame_interval = 10.0
[[phases]]
name = "shear"
duration = 60.0
dt = 1.0
frame_interval = 5.0
flow = { type = "shear", rate = 0.3 }
"""
#: The frames of a finished run: 0, 10, 20 (relax), 25 … 80 (shear).
TIMES = np.concatenate([[0.0, 10.0, 20.0], np.arange(25.0, 81.0, 5.0)])
#: The killed run (rate 0.5, seed 2) dies writing its 6th checkpoint: frames 0 … 25 remain.
KILLED, KILLED_FRAMES = "003", 6


def _sets(rate: float, seed: int) -> list[str]:
    return [f"{RATE}={rate}", f"{SEED}={seed}"]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> Path:
    """The sweep directory as `femphase sweep` leaves it: runs/<id>/ and sweep.json."""
    directory = tmp_path_factory.mktemp("sweep")
    scene = directory / "scene.toml"
    scene.write_text(SCENE)
    runs = []
    for k, (rate, seed) in enumerate((r, s) for r in AXES[RATE] for s in AXES[SEED]):
        run_id, out = f"{k:03d}", directory / "runs" / f"{k:03d}"
        if run_id == KILLED:  # SIGKILLed by femphase's own fault injection, as a scheduler would
            command = [sys.executable, "-m", "femphase.cli", "run", str(scene), "-o", str(out), "-q"]
            command += [word for s in _sets(rate, seed) for word in ("--set", s)]
            env = dict(os.environ, FEMPHASE_FAILPOINT=f"checkpoint:{KILLED_FRAMES}",
                       PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                                   os.environ.get("PYTHONPATH", "")]))
            assert subprocess.run(command, env=env, capture_output=True).returncode == -9
        else:
            with warnings.catch_warnings():  # h = 2 (coarse, to keep the runs tiny) warns; known
                warnings.simplefilter("ignore", ResolutionWarning)
                run_scene(scene_from_dict(read_scene_data(scene, _sets(rate, seed))), out, progress=False)
        runs.append({"id": run_id, "directory": f"runs/{run_id}", "values": {RATE: rate, SEED: seed},
                     "status": "interrupted" if run_id == KILLED else "done", "error": None})
    index = {"format": "femphase-sweep", "version": 1, "mode": "product", "axes": AXES, "runs": runs}
    (directory / "sweep.json").write_text(json.dumps(index))
    assert main(["aggregate", str(directory)]) == 0
    return directory


@pytest.fixture(scope="module")
def dataset(sweep):
    with xr.open_dataset(sweep / "sweep.nc", engine="h5netcdf") as ds:
        yield ds.load()


def _table(path: Path) -> dict[str, np.ndarray]:
    """A CSV read independently of femphase: columns of floats."""
    with path.open() as handle:
        rows = list(csv.reader(handle))
    values = np.array(rows[1:], dtype=float)
    return {name: values[:, k] for k, name in enumerate(rows[0])}


def _runs(sweep: Path):
    for run in json.loads((sweep / "sweep.json").read_text())["runs"]:
        yield run, sweep / run["directory"], {RATE: run["values"][RATE], SEED: run["values"][SEED]}


def test_dataset_dims_coordinates_and_attributes(dataset, sweep):
    assert dict(dataset.sizes) == {RATE: 2, SEED: 2, "time": TIMES.size, "particle": 6}
    assert dataset[RATE].values.tolist() == AXES[RATE] and dataset[SEED].values.tolist() == AXES[SEED]
    np.testing.assert_array_equal(dataset.time.values, TIMES)
    assert dataset.Psi6.dims == (RATE, SEED, "time")
    assert dataset.x.dims == (RATE, SEED, "time", "particle")
    assert dataset.status.dims == dataset.Psi6_mean.dims == (RATE, SEED)
    assert dataset.attrs["femphase_version"] == __version__
    assert dataset.attrs["sweep_mode"] == "product" and json.loads(dataset.attrs["sweep_axes"]) == AXES
    assert json.loads(dataset.attrs["sample_axes"]) == [SEED]
    assert sweep.name in dataset.attrs["title"]
    assert dataset.x.attrs["units"] == "lattice units" and dataset.orientation.attrs["units"] == "radians"
    assert dataset.Psi6.attrs["units"] == "1" and dataset.time.attrs["units"] == "time units"
    # the area term's energy must not be confused with the particles' area
    assert dataset.area_energy.attrs["source"] == "global.csv column area"
    assert dataset.area.attrs["source"] == "particles.csv column area"
    assert dataset.area.attrs["units"] == "lattice units²" and dataset.area_energy.attrs["units"] == "energy units"
    assert dataset.period.attrs["units"] == "time units"
    assert dataset.status.sel({RATE: 0.5, SEED: 2}).item() == "interrupted"
    assert dataset.run_id.sel({RATE: 0.5, SEED: 1}).item() == "002"


def test_dataset_values_are_the_csvs(dataset, sweep):
    for run, directory, where in _runs(sweep):
        frames = _table(directory / "global.csv")
        rows = _table(directory / "particles.csv")
        at = dataset.sel(where).sel(time=frames["time"])
        for column, values in frames.items():
            name = {"area": "area_energy"}.get(column, column)
            np.testing.assert_array_equal(at[name].values, values, err_msg=f"{run['id']} {column}")
        row_at = {"time": xr.DataArray(rows["time"]), "particle": xr.DataArray(rows["id"].astype(int))}
        for column in ("x", "y", "area", "elongation", "orientation", "wall_contact", "psi6_abs", "psi2_abs"):
            np.testing.assert_array_equal(dataset[column].sel(where).sel(row_at).values, rows[column],
                                          err_msg=f"{run['id']} {column}")


def test_unfinished_run_is_padded_with_nan(dataset, sweep):
    killed = dataset.sel({RATE: 0.5, SEED: 2})
    assert killed.status.item() == "interrupted" and killed.run_status.item() == "running"
    assert killed.n_frames.item() == KILLED_FRAMES
    written = np.isfinite(killed.Psi6.values)
    np.testing.assert_array_equal(written, np.arange(TIMES.size) < KILLED_FRAMES)
    assert np.isnan(killed.x.values[KILLED_FRAMES:]).all() and np.isfinite(killed.x.values[:KILLED_FRAMES]).all()
    finished = dataset.sel({RATE: 0.5, SEED: 1})
    assert np.isfinite(finished.x.values).all()


def test_run_caught_while_appending_a_frame(sweep, tmp_path):
    """A frame's rows are flushed in two halves: a reader may see half a frame and half a row."""
    run = tmp_path / "run"
    shutil.copytree(sweep / "runs" / "000", run)
    with (run / "particles.csv").open("a") as handle:
        handle.write("85.0,0,1.5,2.5,40.0,0.1,0.2,0,0.5,0.5\n85.0,1,3.5,4.5,40.0,0.1,0.2,0,0.5,0.5\n85.0,2,3.")
    tables = open_run(run, pending=True)
    np.testing.assert_array_equal(tables.time, np.append(TIMES, 85.0))
    np.testing.assert_array_equal(tables.particles["x"][-1], [1.5, 3.5] + [np.nan] * 4)
    assert np.isnan(tables.globals["Psi6"][-1]) and np.isfinite(tables.globals["Psi6"][:-1]).all()
    complete = tables.complete()  # the analyses see the complete frames only
    np.testing.assert_array_equal(complete.time, TIMES)
    assert summarise_run(complete)["n_frames"] == TIMES.size


def test_a_damaged_run_file_is_named(sweep, tmp_path):
    # "femphase: error: Expecting value: line 1 column 1 (char 0)", of which file in which run?
    copy = tmp_path / "sweep"
    shutil.copytree(sweep, copy)
    (copy / "runs" / "001" / "run.json").write_text("garbage\n")
    with pytest.raises(InputError, match=r"runs/001/run\.json' is not a readable JSON file"):
        aggregate(copy)
    shutil.copy2(sweep / "runs" / "001" / "run.json", copy / "runs" / "001" / "run.json")
    with (copy / "runs" / "002" / "global.csv").open("a") as handle:
        handle.write("garbage,1,2\n")
    with pytest.raises(InputError, match=r"runs/002/global\.csv' is not a readable CSV table of numbers"):
        aggregate(copy)


def test_runs_called_done_whose_directories_were_cut_are_warned(sweep, tmp_path):
    # a deleted run was summarised as done with 0 frames, a cut one over a window in its
    # transient, without a word
    copy = tmp_path / "sweep"
    shutil.copytree(sweep, copy)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        aggregate(copy)  # the intact sweep: its killed run is "interrupted" in sweep.json, no warning
    shutil.rmtree(copy / "runs" / "000")
    lines = (copy / "runs" / "001" / "particles.csv").read_text().splitlines(keepends=True)
    (copy / "runs" / "001" / "particles.csv").write_text("".join(lines[:1 + 6 * 4]))  # 4 frames of 6 particles
    with pytest.warns(UserWarning, match=r"calls 2 runs done .*000 \(its directory is gone\); 001 \(run\.json: "
                                         r"completed, frames to t = 25 of 80\)"):
        result = aggregate(copy)
    assert [row["n_frames"] for row in result.summary[:2]] == [0, 4]
    # global.csv cut alone: the particles' frames whole, its columns NaN from there, without a word
    lines = (copy / "runs" / "002" / "global.csv").read_text().splitlines(keepends=True)
    (copy / "runs" / "002" / "global.csv").write_text("".join(lines[:4]))  # t = 0, 10, 20
    with pytest.warns(UserWarning, match=r"002 \(global\.csv's rows to t = 20 of 80\)"):
        aggregate(copy)


def test_averaging_window_is_the_papers_last_50_of_250_frames():
    relax, shear = 2000.0, 100000.0  # examples/random.toml: frames every 400
    time = np.concatenate([np.arange(0.0, relax + 1, 400.0), relax + np.arange(400.0, shear + 1, 400.0)])
    phases = [{"duration": relax}, {"duration": shear}]
    window = averaging_window(time, phases)
    assert window.size == 50 and time[window[0]] == relax + 201 * 400.0 and window[-1] == time.size - 1
    assert averaging_window(time[:5], phases).size == 0  # never reached the last phase
    assert averaging_window(np.array([0.0, 10.0, 20.0]), [{"duration": 30.0}]).tolist() == [2]  # ⌈2/5⌉


def test_summary_is_the_average_over_the_last_fifth_of_the_frames(sweep):
    rows = {row["run_id"]: row for row in read_summary(sweep / "summary.csv")}
    assert list(rows) == ["000", "001", "002", "003"]
    for run, directory, where in _runs(sweep):
        row = rows[run["id"]]
        assert (row[RATE], row[SEED], row["status"]) == (where[RATE], where[SEED], run["status"])
        frames, particles = _table(directory / "global.csv"), _table(directory / "particles.csv")
        t = frames["time"]
        last_phase = np.flatnonzero(t > 20.0)  # after the relax phase
        window = last_phase[-int(np.ceil(last_phase.size / 5)):]
        assert row["window_frames"] == window.size and row["window_end"] == t[-1]
        assert row["Psi6_mean"] == pytest.approx(frames["Psi6"][window].mean(), rel=1e-12)
        assert row["Psi6_std"] == pytest.approx(frames["Psi6"][window].std(), rel=1e-12, abs=1e-15)
        assert row["Psi2_mean"] == pytest.approx(frames["Psi2"][window].mean(), rel=1e-12)
        n = int(particles["id"].max()) + 1
        r, x, y = (particles[c].reshape(-1, n) for c in ("elongation", "x", "y"))
        onset = int(np.flatnonzero(t == 20.0)[0])  # bulk: farther than 2R = 16 from both walls at shear onset
        bulk = (y[onset] > 16.0) & (y[onset] < 32.0 - 16.0)
        bulk = bulk if bulk.any() else np.ones(n, bool)
        assert row["elongation_mean"] == pytest.approx(r[window][:, bulk].mean(), rel=1e-12)
        info = json.loads((directory / "run.json").read_text())
        cpu = sum(s["cpu_time_s"] for s in info["segments"])
        assert cpu > 0 and row["cpu_time_s"] == pytest.approx(cpu, rel=1e-12)
        reference = np.arange(window[0] - 1, window[-1] + 1)
        events = frames["t1_count"][reference[-1]] - frames["t1_count"][reference[0]]  # the run's own count
        assert row["t1_rate"] == pytest.approx(events / (n * (t[reference[-1]] - t[reference[0]])), rel=1e-12)
        # 80 time units hold no three clear cycles: no period, and none is invented
        assert np.isnan(row["period"]) and np.isnan(row["period_uncertainty"]) and row["period_cycles"] == 0


def test_a_runs_period_comes_with_its_uncertainty_and_cycles(sweep, monkeypatch):
    # summary.csv gave the period alone: a red-noise period from 3 cycles at ±12 % read as
    # well as the lattice's ±0.4 % from 7 (verification/README.md, "Periods in records that
    # do not oscillate")
    import femphase.aggregate as aggregate
    from femphase.analysis.periods import PeriodEstimate

    run = open_run(next((sweep / "runs").iterdir()))
    monkeypatch.setattr(aggregate, "period_estimate", lambda r: PeriodEstimate(277.4, 1.2, 7, "test"))
    row = aggregate.summarise_run(run)
    assert (row["period"], row["period_uncertainty"], row["period_cycles"]) == (277.4, 1.2, 7)


def test_runs_without_t1_interval_count_their_t1s_again_from_the_frames(sweep):
    from dataclasses import replace

    from femphase.aggregate import t1_rate
    from femphase.io.reader import open_run

    directory = sweep / "runs" / "003"
    run = open_run(directory).complete()
    output = {k: v for k, v in run.scene["output"].items() if k != "t1_interval"}
    older = replace(run, scene={**run.scene, "output": output}, globals={})  # as written before the key existed
    window = averaging_window(run.time, run.scene["phases"])
    reference = np.arange(window[0] - 1, window[-1] + 1)
    centroids = list(np.stack([run.x[reference], run.y[reference]], axis=-1))
    events = t1_event_times(centroids, run.time[reference], 42.0).size
    span = run.time[reference[-1]] - run.time[reference[0]]
    assert t1_rate(older, window) == pytest.approx(events / (run.n_particles * span), rel=1e-12)


def test_summary_csv_has_one_documented_column_per_quantity(sweep):
    with (sweep / "summary.csv").open() as handle:
        header = next(csv.reader(handle))
    assert header == ["run_id", RATE, SEED, "status", "run_status", "error", *SUMMARY_COLUMNS]


def test_zip_sweep_has_one_run_dimension(sweep, tmp_path):
    pairs = [("000", 0.2, 1), ("003", 0.5, 2)]
    runs = [{"id": i, "directory": str(sweep / "runs" / i), "values": {RATE: r, SEED: s},
             "status": "done", "error": None} for i, r, s in pairs]
    index = {"format": "femphase-sweep", "version": 1, "mode": "zip",
             "axes": {RATE: [0.2, 0.5], SEED: [1, 2]}, "runs": runs}
    (tmp_path / "sweep.json").write_text(json.dumps(index))
    product = aggregate(sweep).dataset
    zipped = aggregate(tmp_path).dataset
    assert zipped.Psi6.dims == ("run", "time") and zipped.x.dims == ("run", "time", "particle")
    assert zipped[RATE].dims == ("run",) and zipped[RATE].values.tolist() == [0.2, 0.5]
    for k, (_, r, s) in enumerate(pairs):
        np.testing.assert_array_equal(zipped.x.isel(run=k).values, product.x.sel({RATE: r, SEED: s}).values)


def test_plot_on_a_sweep_writes_the_figures_and_aggregates_first(sweep, tmp_path, capsys):
    (sweep / "summary.csv").unlink()  # stale: `plot` must aggregate again
    assert main(["plot", str(sweep), "-o", str(tmp_path), "--format", "svg"]) == 0
    err = capsys.readouterr().err
    assert (sweep / "summary.csv").is_file()
    for name in ("sweep_order", "sweep_dynamics"):
        assert (tmp_path / f"{name}.svg").stat().st_size > 1000
    assert not (tmp_path / "sweep_period.svg").exists() and "no sweep_period figure" in err
    written = (sweep / "sweep.nc").stat().st_mtime_ns
    assert main(["plot", str(sweep)]) == 0
    assert (sweep / "figures" / "sweep_order.png").is_file()
    assert (sweep / "sweep.nc").stat().st_mtime_ns == written  # current: not aggregated again
    assert is_current(read_sweep(sweep))
    os.utime(sweep / "runs" / KILLED / "particles.csv")  # a run wrote more: `plot` would aggregate again
    assert not is_current(read_sweep(sweep))


def test_plot_names_every_sweep_figure_it_leaves_out(sweep, tmp_path, capsys, monkeypatch):
    # a single particle's sweep (Ψ6, Ψ2^L NaN) lost sweep_order without a word
    from femphase.plot import sweep as sweep_plots

    monkeypatch.setattr(sweep_plots, "plot_sweep", lambda *args, **kwargs: {"sweep_dynamics": tmp_path / "d.png"})
    assert main(["plot", str(sweep), "-o", str(tmp_path)]) == 0
    captured = capsys.readouterr()  # notes on stderr: stdout lists the figures, one path a line
    assert "no sweep_order figure: no run that is done has a finite Ψ6, Ψ2^L" in captured.err
    assert "no sweep_period figure: no run that is done has a finite period" in captured.err
    assert captured.out.split() == [str(tmp_path / "d.png")]
    # the ODE's options are a run's: ignored on a sweep, an invalid value too
    assert main(["plot", str(sweep), "--ode-k", "-1"]) == 2
    assert "--ode-k = -1.0 applies to a run directory, not to the sweep" in capsys.readouterr().err


def test_an_input_that_changes_while_the_aggregate_reads_leaves_it_stale(sweep, tmp_path, monkeypatch):
    # the outputs were newer than every input although they held what sweep.json said before
    # a run finished during the aggregate: `plot` then drew "3 of 4 runs done" from them
    import shutil

    import femphase.aggregate as module

    shutil.copytree(sweep, tmp_path / "sweep")
    sweep = tmp_path / "sweep"
    read = module.aggregate

    def aggregate_while_a_run_finishes(directory):
        result = read(directory)
        now = time.time_ns()  # the sweep's index rewritten after it was read
        os.utime(sweep / "sweep.json", ns=(now, now))
        return result

    monkeypatch.setattr(module, "aggregate", aggregate_while_a_run_finishes)
    module.write_aggregate(sweep)
    assert not is_current(read_sweep(sweep))


def test_period_figure_when_a_period_was_measured(tmp_path):
    rows = [{"run_id": f"{k}", RATE: rate, SEED: float(seed), "status": "done", "period": 100.0 * rate + seed,
             **{c: 0.5 for c in SUMMARY_COLUMNS if c != "period"}}
            for k, (rate, seed) in enumerate((r, s) for r in (0.1, 0.2, 0.3) for s in (1, 2))]
    paths = plot_summary(rows, [RATE, SEED], tmp_path)
    assert set(paths) == {"sweep_order", "sweep_dynamics", "sweep_period"}
    assert paths["sweep_period"].stat().st_size > 1000


def test_not_a_sweep_is_a_clear_error(tmp_path, capsys):
    assert main(["aggregate", str(tmp_path)]) == 2
    assert "has no sweep.json" in capsys.readouterr().err
    assert main(["aggregate", str(tmp_path / "nowhere")]) == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "file").write_text("")  # it said "has no sweep.json"
    assert main(["aggregate", str(tmp_path / "file")]) == 2
    assert "is a file, not a directory" in capsys.readouterr().err


@pytest.mark.parametrize("change, message", [
    ({"format": "other"}, "format = 'other' is invalid: 'femphase-sweep'"),
    ({"version": 2}, "version = 2 is invalid: 1"),
    ({"mode": "grid"}, "mode = 'grid' is invalid: 'product' or 'zip'"),
    ({"runs": [{"id": "a", "directory": "runs/a", "values": {RATE: 0.7}, "status": "done", "error": None}]},
     "one of the axis values [0.2, 0.5]"),
    ({"runs": [{"id": "a", "directory": "runs/a", "values": {RATE: 0.2}, "status": "running", "error": None}]},
     "status = 'running' is invalid: pending, done, failed, interrupted"),
])
def test_malformed_sweep_json_names_the_entry(tmp_path, change, message):
    index = {"format": "femphase-sweep", "version": 1, "mode": "product", "axes": {RATE: [0.2, 0.5]}, "runs": []}
    (tmp_path / "sweep.json").write_text(json.dumps({**index, **change}))
    with pytest.raises(InputError, match=re.escape(message)):
        read_sweep(tmp_path)


def _doc_units(text: str, heading: str) -> dict[str, str]:
    """{column: unit} of the table under ``heading`` in a markdown file."""
    section = text.split(heading, 1)[1].split("\n#", 1)[0]
    return dict(re.findall(r"^\| `(\w+)` \| ([^|]+?) \|", section, flags=re.M))


def test_column_units_agree_with_the_docs():
    outputs = (DOCS / "outputs.md").read_text()
    particles = _doc_units(outputs, "## particles.csv")
    assert {k: v for k, v in particles.items() if k not in ("time", "id")} == \
        {name: column.unit for name, column in PARTICLE_COLUMNS.items()}
    frames = _doc_units(outputs, "## global.csv")
    assert {k: v for k, v in frames.items() if k != "time"} == {name: c.unit for name, c in GLOBAL_COLUMNS.items()}
    summary = _doc_units((DOCS / "aggregation.md").read_text(), "## summary.csv")
    assert summary == {name: column.unit for name, column in SUMMARY_COLUMNS.items()}


def test_write_aggregate_replaces_both_files(sweep):
    before = (sweep / "sweep.nc").stat().st_mtime_ns
    paths = write_aggregate(sweep)
    assert paths["dataset"].stat().st_mtime_ns >= before and paths["summary"].is_file()
    assert not list(sweep.glob(".*.tmp"))
