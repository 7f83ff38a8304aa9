"""`femphase compare`: differences between runs (grid and mesh), and between a run and external grid data."""

from __future__ import annotations

import argparse
import warnings

import numpy as np
import pytest

from femphase.cli.compare import register
from femphase.compare import GridData, compare_runs, format_table, grid_data_from_run, load_grid_data, save_grid_data
from femphase.run.runner import run_scene
from femphase.scene import scene_from_dict


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
    register(parser.add_subparsers())
    args = parser.parse_args(["compare", str(runs["fem"]), str(runs["fd"]), "--fields", "-o", str(tmp_path / "out")])
    assert args.func(args) == 0
    printed = capsys.readouterr().out
    assert "phi_l2" in printed and "max |A − B|" in printed
    for name in ("compare.csv", "compare.json", "compare.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0
    header = (tmp_path / "out" / "compare.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "time" and "phi_l2" in header and "energy_repulsion" in header


def test_an_output_path_through_a_file_is_refused_before_comparing(runs, capsys):
    # NotADirectoryError after the whole comparison: "internal error", exit 1
    from femphase.cli import main

    assert main(["compare", str(runs["fem"]), str(runs["fd"]), "-o", str(runs["fem"] / "run.json" / "sub")]) == 2
    assert "run.json is a file" in capsys.readouterr().err


def test_default_output_is_inside_dir_b(runs):
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(["compare", str(runs["fem"]), str(runs["fem_again"])])
    assert args.func(args) == 0
    assert (runs["fem_again"] / "compare" / "compare.csv").exists()


def test_grid_runs_at_different_h_compare_by_observables(runs):
    """A study's runs at h = 1 and 2: the same disc pair, its observables O(h²) apart."""
    result = compare_runs(runs["fem"], runs["coarse"])
    assert result["field_mode"] == "none" and "energy_total" in result["series"]
    largest = maxima(result)
    assert 0 < largest["area"] < 0.05 * np.pi * 8.0**2 and largest["x"] < 0.1 and largest["y"] < 0.1


def test_bad_inputs_give_clear_errors(runs, tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        compare_runs(runs["fem"], tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="not a run directory: it has no scene.toml"):
        compare_runs(tmp_path / "empty", runs["fem"])
    with pytest.raises(ValueError, match="grids differ.*compare the runs without --fields"):
        compare_runs(runs["fem"], runs["coarse"], fields=True)
    with pytest.raises(ValueError, match="grids differ.*grid data holds nothing else"):
        save_grid_data(tmp_path / "fine.npz", grid_data_from_run(runs["fem"]))
        compare_runs(runs["coarse"], tmp_path / "fine.npz")
    with pytest.raises(ValueError, match="has no fields.xdmf"):
        compare_runs(runs["fem"], runs["no_fields"], fields=True)
    data = grid_data_from_run(runs["fem"])
    shifted = tmp_path / "shifted.npz"
    save_grid_data(shifted, GridData(data.time + 0.5, data.x, data.y, data.phi))
    with pytest.raises(ValueError, match="no common frame times"):
        compare_runs(runs["fem"], shifted)
    # a run with its tables' headers only: an internal error (KeyError 'x')
    import shutil

    shutil.copytree(runs["fem"], tmp_path / "headers")
    for name in ("particles.csv", "global.csv"):
        path = tmp_path / "headers" / name
        path.write_text(path.read_text().splitlines(keepends=True)[0])
    with pytest.raises(ValueError, match="has no frame in particles.csv"):
        compare_runs(tmp_path / "headers", runs["fem"])
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
    with pytest.raises(ValueError, match="'time' must be finite and strictly increasing"):
        GridData(data.time[::-1], data.x, data.y, data.phi)
    broken = data.phi.copy()
    broken[2, 0, 3, 4] = np.nan
    with pytest.raises(ValueError, match=f"1 NaN or infinite values, the first in frame 2 \\(t = {data.time[2]:g}\\)"):
        GridData(data.time, data.x, data.y, broken)
    (tmp_path / "junk.npz").write_text("not a zip file")  # np.load said it held pickled data
    with pytest.raises(ValueError, match="cannot be read: it is not a NumPy .npz archive"):
        compare_runs(runs["fem"], tmp_path / "junk.npz")
    import h5py

    with h5py.File(tmp_path / "grouped.h5", "w") as handle:  # an internal error (TypeError)
        for name in ("time", "x", "y", "phi"):
            handle[f"fields/{name}"] = getattr(data, name)
    with pytest.raises(ValueError, match=r"lacks \['time', 'x', 'y', 'phi'\].*not in a group"):
        compare_runs(runs["fem"], tmp_path / "grouped.h5")
    with pytest.raises(ValueError, match=r"the fields of N = 0 particles"):  # "need at least one array"
        GridData(data.time, data.x, data.y, data.phi[:, :0])
    with pytest.raises(ValueError, match="suffix"):
        save_grid_data(tmp_path / "data.txt", data)


# -- meshed runs ----------------------------------------------------------------------------

def mesh_scene(mesh_file, dt: float = 0.1, per_particle: bool = True, solver: str = "auto"):
    """tiny_scene's two particles on a meshed 24 × 24 channel (``mesh_file``, a .vtu)."""
    return scene_from_dict({
        "name": "tiny mesh",
        "domain": {"kind": "mesh", "mesh": mesh_file.name, "h": 1.0},
        "particles": {"layout": "list", "centres": [[8.0, 12.0], [17.0, 12.0]], "initial_radius": 5.0},
        "output": {"fields": True, "per_particle_fields": per_particle},
        "numerics": {"solver": solver},
        "phases": [{"name": "relax", "duration": 3.0, "dt": dt, "frame_interval": 1.0}],
    }, mesh_file.parent)


@pytest.fixture(scope="module")
def mesh_runs(tmp_path_factory):
    """Two identical runs on a Delaunay mesh, one with half the time step, one on the
    structured channel's triangulation read as a mesh."""
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing, structured_channel

    root = tmp_path_factory.mktemp("mesh_runs")
    wall = lambda height: (lambda x: 0 * x + height)  # noqa: E731
    write_domain(root / "delaunay.vtu", *delaunay_channel(24.0, edge_for_spacing(1.0), wall(0.0), wall(24.0), seed=1))
    write_domain(root / "square.vtu", *structured_channel(24.0, 24.0, 1.0))
    paths = {}
    for name, mesh, kwargs in [("mesh", "delaunay.vtu", {}), ("mesh_again", "delaunay.vtu", {}),
                               ("half_dt", "delaunay.vtu", {"dt": 0.05}),
                               ("sum_only", "delaunay.vtu", {"per_particle": False}),
                               # exact solves, as the structured channel's: the same discretisation
                               ("square", "square.vtu", {"solver": "direct"})]:
        paths[name] = root / name
        run_scene(mesh_scene(root / mesh, **kwargs), paths[name], progress=False)
    return paths


def test_identical_mesh_runs_and_a_mesh_run_and_itself_differ_by_nothing(mesh_runs):
    for b in ("mesh_again", "mesh"):
        result = compare_runs(mesh_runs["mesh"], mesh_runs[b], fields=True)
        assert result["field_mode"] == "per_particle"
        assert result["grid"] is None and result["domain"]["kind"] == "mesh"
        np.testing.assert_allclose(result["time"], [0.0, 1.0, 2.0, 3.0])
        assert set(maxima(result)) >= {"x", "y", "area", "elongation", "energy_total", "phi_l2", "phi_sum_linf"}
        assert all(value == 0 for value in maxima(result).values()), b
    assert compare_runs(mesh_runs["mesh"], mesh_runs["sum_only"], fields=True)["field_mode"] == "phi_sum"


def test_mesh_runs_with_different_time_steps_differ_in_fields_and_observables(mesh_runs):
    result = compare_runs(mesh_runs["mesh"], mesh_runs["half_dt"], fields=True)
    largest = maxima(result)
    for name in ("area", "energy_total", "phi_l2", "phi_linf", "phi_sum_l2"):
        assert largest[name] > 0
    assert result["series"]["phi_l2"][0] == 0  # the same initial state
    assert largest["phi_linf"] < 0.05  # dt = 0.1 and 0.05 agree closely
    assert np.asarray(result["per_particle"]["phi_l2"]).shape == (4, 2)
    # the field norms use the mesh's lumped mass: the sum's L2 norm is bounded by the particles'
    assert np.all(result["series"]["phi_sum_l2"] <= np.sqrt(2) * result["series"]["phi_l2"] + 1e-15)


def test_runs_on_different_domains_compare_observables_but_not_fields(runs, mesh_runs, capsys):
    from femphase.cli import main

    # a Delaunay mesh against the structured triangulation read as a mesh: O(h²) apart
    result = compare_runs(mesh_runs["mesh"], mesh_runs["square"])
    assert result["field_mode"] == "none" and "energy_total" in result["series"]
    largest = maxima(result)
    assert 0 < largest["x"] < 0.01 and largest["y"] < 0.01 and 0 < largest["area"] < 0.1  # area ≈ 80
    # the structured channel and its triangulation read as a mesh: the same discretisation;
    # only the shape tensor's rule differs (central differences on the grid, exact P1
    # gradients on a mesh, whose bias on a disc is ≈ 0.03 h²)
    largest = maxima(compare_runs(runs["fem"], mesh_runs["square"]))
    assert largest["x"] < 1e-10 and largest["y"] < 1e-10 and largest["area"] < 1e-9
    assert largest["energy_total"] < 1e-9 and largest["elongation"] < 0.05
    with pytest.raises(ValueError, match="different domains .* compare these without --fields"):
        compare_runs(mesh_runs["mesh"], mesh_runs["square"], fields=True)
    with pytest.raises(ValueError, match="different domains .*kind") as refused:
        compare_runs(runs["fem"], mesh_runs["square"], fields=True)
    assert "(they differ in kind)" in str(refused.value)  # and "period": the grid states none, 24 and 24
    assert main(["compare", str(mesh_runs["mesh"]), str(mesh_runs["square"]), "--fields"]) == 2
    err = capsys.readouterr().err
    assert "different domains" in err and "Traceback" not in err


def test_grid_data_and_mesh_runs_are_not_compared(runs, mesh_runs, tmp_path):
    with pytest.raises(ValueError, match="structured-grid runs only"):
        grid_data_from_run(mesh_runs["mesh"])
    path = tmp_path / "fem.npz"
    save_grid_data(path, grid_data_from_run(runs["fem"]))
    with pytest.raises(ValueError, match="grid data is compared only with runs on the structured grid"):
        compare_runs(mesh_runs["square"], path)


def test_cli_compares_mesh_runs_into_dir_b(mesh_runs, capsys):
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(["compare", str(mesh_runs["mesh"]), str(mesh_runs["half_dt"]), "--fields"])
    assert args.func(args) == 0
    assert "phi_l2" in capsys.readouterr().out
    for name in ("compare.csv", "compare.json", "compare.png"):
        assert (mesh_runs["half_dt"] / "compare" / name).stat().st_size > 0


def test_runs_that_start_apart_are_warned_about(tmp_path):
    # the same N and seed give different random layouts on different domains: compare paired
    # unrelated particles (|Δy| 219 at t = 0) without a word
    from femphase.run.runner import run_scene
    from femphase.scene import scene_from_dict

    for name, centres in (("a", [[10.0, 10.0], [30.0, 30.0]]), ("b", [[30.0, 30.0], [10.0, 10.0]])):
        run_scene(scene_from_dict({"name": name, "domain": {"Lx": 40.0, "Ly": 40.0},
                                   "particles": {"layout": "list", "centres": centres},
                                   "phases": [{"duration": 2.0, "dt": 1.0, "frame_interval": 1.0}]}),
                  tmp_path / name, progress=False)
    with pytest.warns(UserWarning, match=r"start from different states: at t = 0 .* up to 20 apart"):
        compare_runs(tmp_path / "a", tmp_path / "b")
    import shutil

    shutil.copytree(tmp_path / "a", tmp_path / "a_again")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        compare_runs(tmp_path / "a", tmp_path / "a_again")  # the same start: nothing to say


def test_a_run_compared_with_itself_or_with_other_physics_is_warned_about(runs, tmp_path):
    # all zeros, or a radius of 8 against 10 read as the methods' difference, without a word
    with pytest.warns(UserWarning, match="is compared with itself: every difference is 0"):
        compare_runs(runs["fem"], runs["fem"])
    scene = tiny_scene()
    run_scene(scene_from_dict({**scene.to_dict(), "model": {**scene.to_dict()["model"], "radius": 9.0}}),
              tmp_path / "wider", progress=False)
    with pytest.warns(UserWarning, match=r"differ in more than the method: model\.radius: 8\.0 against 9\.0"):
        compare_runs(runs["fem"], tmp_path / "wider")
    with warnings.catch_warnings():  # FEM against FD of one scene: the method alone
        warnings.simplefilter("error")
        compare_runs(runs["fem"], runs["fd"])


def test_the_table_says_how_many_frames_matched_and_which_finals_are_earlier(runs, tmp_path):
    # 8 of 21 frames matched (float32 times) without a word, and a final value from an earlier
    # frame than the span's end was printed as the final one
    import shutil

    shutil.copytree(runs["fem_again"], tmp_path / "cut")
    lines = (tmp_path / "cut" / "global.csv").read_text().splitlines(keepends=True)
    (tmp_path / "cut" / "global.csv").write_text("".join(lines[:-1]))
    table = format_table(compare_runs(runs["fem"], tmp_path / "cut"))
    assert "4 common frames (of 4 in A and 4 in B)" in table
    assert "* final value of an earlier common frame: energy_total at t = 2" in table


def test_frame_times_a_long_clock_has_drifted_from_still_pair_up():
    # 9.6·10⁵ steps of 0.1 summed one by one end at 96000.0000011: against a run whose frame
    # times are exact the last frames went unmatched, and compare dropped them silently
    from femphase.io.reader import match_times, merge_times

    exact = np.arange(0.0, 96000.0 + 1.0, 400.0)
    drifted = exact + np.where(exact > 95000.0, 1.1e-6, 0.0)
    ia, ib = match_times(drifted, exact)
    assert ia.size == exact.size and np.array_equal(ia, ib)
    assert merge_times(exact, drifted).size == exact.size
    # frames one dt apart stay apart, however late
    late = np.array([1e6, 1e6 + 0.1])
    assert match_times(late[1:], late[:1])[0].size == 0 and merge_times(late).size == 2


def test_per_particle_fields_are_read_in_particle_order_beyond_1000():
    # a text sort put phi_1000 between phi_100 and phi_101: with N > 1000, grid data and the
    # per-particle differences paired the wrong particles
    from femphase.compare import particle_field_names

    names = [f"phi_{i:03d}" for i in range(1002)] + ["phi_sum", "phi_max", "label"]
    assert particle_field_names(sorted(names)) == [f"phi_{i:03d}" for i in range(1002)]


def test_a_damaged_field_frame_is_named_by_run_and_frame(runs, tmp_path):
    # "shape mismatch: value array of shape (100,) could not be broadcast …": which file?
    import shutil

    import h5py

    shutil.copytree(runs["fem_again"], tmp_path / "damaged")
    with h5py.File(tmp_path / "damaged" / "fields" / "frame_000002.h5", "r+") as frame:
        short = frame["phi_sum"][:100]
        del frame["phi_sum"]
        frame["phi_sum"] = short
    with pytest.raises(ValueError, match=r"damaged': its field frame 2 \(t = 2\) cannot be read .*damaged or missing"):
        compare_runs(runs["fem"], tmp_path / "damaged", fields=True)


def test_grid_data_with_the_periodic_copy_is_told_why_its_grid_differs(runs, tmp_path):
    data = grid_data_from_run(runs["fem"])
    h = data.x[1] - data.x[0]
    with_copy = GridData(data.time, np.append(data.x, data.x[-1] + h), data.y,
                         np.concatenate([data.phi, data.phi[..., :1]], axis=-1))
    save_grid_data(tmp_path / "copy.npz", with_copy)
    with pytest.raises(ValueError, match="grids differ.*the periodic copy x = Lx is no node"):
        compare_runs(runs["fem"], tmp_path / "copy.npz")
