"""`femphase compare`: differences between runs, and between a run and external grid data."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from femphase.compare import (
    GridData,
    compare_runs,
    grid_data_from_run,
    load_grid_data,
    register_cli,
    save_grid_data,
)
from femphase.scene import scene_from_dict
from femphase.simulation import run_scene


def tiny_scene(h: float = 1.0, per_particle: bool = True, fields: bool = True, frame: float = 1.0):
    return scene_from_dict({
        "name": "tiny",
        "domain": {"Lx": 24.0, "Ly": 24.0, "h": h},
        "particles": {"layout": "list", "centres": [[8.0, 12.0], [17.0, 12.0]], "initial_radius": 5.0},
        "output": {"fields": fields, "per_particle_fields": per_particle},
        "phases": [{"name": "relax", "duration": 3.0, "dt": 0.1, "frame_interval": frame}],
    })


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two identical FEM runs, an FD run, and FEM runs without per-particle fields."""
    root = tmp_path_factory.mktemp("runs")
    paths = {}
    for name, method, kwargs in [("fem", "fem", {}), ("fem_again", "fem", {}), ("fd", "fd", {}),
                                 ("sum_only", "fem", {"per_particle": False}),
                                 ("no_fields", "fem", {"fields": False}),
                                 ("coarse", "fem", {"h": 2.0}),
                                 ("other_frames", "fem", {"frame": 1.5})]:
        paths[name] = root / name
        run_scene(tiny_scene(**kwargs), paths[name], method=method, progress=False)
    return paths


def maxima(result: dict) -> dict:
    return {name: row["max"] for name, row in result["summary"].items()}


def test_identical_runs_differ_by_nothing(runs):
    result = compare_runs(runs["fem"], runs["fem_again"], fields=True)
    assert result["field_mode"] == "per_particle"
    np.testing.assert_allclose(result["time"], [0.0, 1.0, 2.0, 3.0])
    assert set(maxima(result)) >= {"x", "area", "energy_total", "phi_l2", "phi_sum_linf"}
    assert all(value == 0 for value in maxima(result).values())


def test_fem_and_fd_runs_differ(runs):
    result = compare_runs(runs["fem"], runs["fd"], fields=True)
    largest = maxima(result)
    for name in ("area", "energy_total", "phi_l2", "phi_linf", "phi_sum_l2"):
        assert largest[name] > 0
    # both start from the same state; the methods agree closely (same spatial operator)
    assert result["series"]["phi_l2"][0] == 0
    assert largest["phi_linf"] < 0.05
    assert np.asarray(result["per_particle"]["phi_l2"]).shape == (4, 2)


def test_without_per_particle_fields_the_total_field_is_compared(runs):
    result = compare_runs(runs["fem"], runs["sum_only"], fields=True)
    assert result["field_mode"] == "phi_sum"
    assert "phi_l2" not in result["series"]
    assert maxima(result)["phi_sum_l2"] == 0
    observables_only = compare_runs(runs["fem"], runs["no_fields"])
    assert observables_only["field_mode"] == "none"


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_grid_data_round_trips_and_compares_equal_to_its_run(runs, tmp_path, suffix):
    data = grid_data_from_run(runs["fem"])
    assert data.phi.shape == (4, 2, 25, 24)  # (F, N, ny, nx): no seam copy in x
    path = tmp_path / f"fem{suffix}"
    save_grid_data(path, data)
    loaded = load_grid_data(path)
    for name in ("time", "x", "y", "phi"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(data, name))
    result = compare_runs(runs["fem"], path)
    assert result["field_mode"] == "per_particle"
    largest = maxima(result)
    assert largest["phi_l2"] == 0 and largest["phi_sum_linf"] == 0
    # observables recomputed from the fields equal the run's particles.csv
    for name in ("x", "y", "area", "elongation"):
        assert largest[name] < 1e-10
    assert "energy_total" not in largest  # energies: only between two run directories


def test_grid_data_against_another_run_reports_the_difference(runs, tmp_path):
    path = tmp_path / "fd.npz"
    save_grid_data(path, grid_data_from_run(runs["fd"]))
    by_data = maxima(compare_runs(runs["fem"], path))
    by_runs = maxima(compare_runs(runs["fem"], runs["fd"], fields=True))
    assert by_data["phi_l2"] == pytest.approx(by_runs["phi_l2"], rel=1e-12)
    assert by_data["area"] == pytest.approx(by_runs["area"], rel=1e-6)


def test_cli_prints_a_table_and_writes_csv_json_and_plot(runs, tmp_path, capsys):
    parser = argparse.ArgumentParser()
    register_cli(parser.add_subparsers())
    args = parser.parse_args(["compare", str(runs["fem"]), str(runs["fd"]), "--fields", "-o", str(tmp_path / "out")])
    assert args.func(args) == 0
    printed = capsys.readouterr().out
    assert "phi_l2" in printed and "max |A − B|" in printed
    for name in ("compare.csv", "compare.json", "compare.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0
    header = (tmp_path / "out" / "compare.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "time" and "phi_l2" in header and "energy_repulsion" in header


def test_default_output_is_inside_dir_b(runs):
    parser = argparse.ArgumentParser()
    register_cli(parser.add_subparsers())
    args = parser.parse_args(["compare", str(runs["fem"]), str(runs["fem_again"])])
    assert args.func(args) == 0
    assert (runs["fem_again"] / "compare" / "compare.csv").exists()


def test_bad_inputs_give_clear_errors(runs, tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        compare_runs(runs["fem"], tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="not a run directory: it has no scene.toml"):
        compare_runs(tmp_path / "empty", runs["fem"])
    with pytest.raises(ValueError, match="grids differ"):
        compare_runs(runs["fem"], runs["coarse"])
    with pytest.raises(ValueError, match="has no fields.xdmf"):
        compare_runs(runs["fem"], runs["no_fields"], fields=True)
    data = grid_data_from_run(runs["fem"])
    shifted = tmp_path / "shifted.npz"
    save_grid_data(shifted, GridData(data.time + 0.5, data.x, data.y, data.phi))
    with pytest.raises(ValueError, match="no common frame times"):
        compare_runs(runs["fem"], shifted)
    # frames at 0 and 3 are shared with a run written every 1.5 time units
    np.testing.assert_allclose(compare_runs(runs["fem"], runs["other_frames"])["time"], [0.0, 3.0])


def test_malformed_grid_data_is_rejected(runs, tmp_path):
    data = grid_data_from_run(runs["fem"])
    np.savez(tmp_path / "missing.npz", time=data.time, x=data.x, y=data.y)
    with pytest.raises(ValueError, match=r"lacks \['phi'\]"):
        compare_runs(runs["fem"], tmp_path / "missing.npz")
    with pytest.raises(ValueError, match=r"expected \(F, N, ny, nx\) = \(4, N, 25, 24\)"):
        GridData(data.time, data.x, data.y, data.phi[:, :, :, :-1])
    with pytest.raises(ValueError, match="uniform grid starting at 0"):
        GridData(data.time, data.x + 0.5, data.y, data.phi).grid()
    (tmp_path / "junk.npz").write_text("not a zip file")
    with pytest.raises(ValueError, match="cannot be read"):
        compare_runs(runs["fem"], tmp_path / "junk.npz")
    with pytest.raises(ValueError, match="suffix"):
        save_grid_data(tmp_path / "data.txt", data)
