"""`femphase plot`: every figure of a tiny grid or mesh run is written; bad directories give clear errors."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from femphase.cli import main
from femphase.io.reader import open_run
from femphase.plot.run import FIGURES, plot_run
from femphase.run.runner import run_scene
from femphase.scene import scene_from_dict

TINY = {
    "name": "tiny lattice",
    "domain": {"Lx": 42.0, "Ly": 24.0, "h": 2.0},
    "particles": {"layout": "hexagonal", "N": 6, "per_row": 3},
    "output": {"fields": True, "observables": ["shape", "order"]},
    "phases": [
        {"name": "relax", "duration": 20.0, "dt": 1.0, "frame_interval": 10.0},
        {"name": "shear", "duration": 60.0, "dt": 1.0, "frame_interval": 5.0, "flow": {"type": "shear", "rate": 0.3}},
    ],
}


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("run")
    run_scene(scene_from_dict(TINY), directory, progress=False)
    return directory


def _written(paths: dict) -> None:
    assert set(paths) == set(FIGURES)
    for path in paths.values():
        assert path.is_file() and path.stat().st_size > 1000, path


def test_every_figure_is_written(tiny_run, tmp_path):
    _written(plot_run(tiny_run, tmp_path / "figures"))


def test_cli_writes_figures_with_an_explicit_ode_rate(tiny_run, tmp_path, capsys):
    assert main(["plot", str(tiny_run), "-o", str(tmp_path), "--ode-rate", "0.1", "--format", "svg"]) == 0
    printed = capsys.readouterr().out.split()
    assert len(printed) == len(FIGURES) and all(p.endswith(".svg") for p in printed)
    for name in FIGURES:
        assert (tmp_path / f"{name}.svg").stat().st_size > 1000


def test_snapshot_from_fields_xdmf_without_checkpoint(tiny_run, tmp_path):
    copy = _copy_run(tiny_run, tmp_path / "copy", ("checkpoint.h5",))
    _written(plot_run(copy))
    assert (copy / "figures" / "snapshot.png").is_file()


def test_order_is_computed_when_the_run_did_not_write_it(tmp_path):
    data = {**TINY, "output": {"fields": False}}
    run_scene(scene_from_dict(data), tmp_path / "run", progress=False)
    run = open_run(tmp_path / "run").complete()
    assert "Psi6" not in run.globals
    _written(plot_run(tmp_path / "run"))


def test_missing_directory_is_a_clear_error(tmp_path, capsys):
    assert main(["plot", str(tmp_path / "nowhere")]) == 2
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(FileNotFoundError, match="does not exist"):
        open_run(tmp_path / "nowhere").complete()


def test_directory_that_is_not_a_run_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "scene.toml").write_text('name = "x"\n')
    assert main(["plot", str(tmp_path)]) == 2
    assert "not a femphase run directory" in capsys.readouterr().err
    assert "particles.csv" in str(pytest.raises(FileNotFoundError, open_run, tmp_path).value)


@pytest.mark.parametrize("option, value", [("--ode-rate", "-1"), ("--ode-k", "0")])
def test_a_bad_ode_option_is_named_and_no_figure_written(tiny_run, tmp_path, capsys, option, value):
    assert main(["plot", str(tiny_run), "-o", str(tmp_path / "figures"), option, value]) == 2
    assert f"option '{option}' = {float(value)!r} is invalid" in capsys.readouterr().err
    assert not (tmp_path / "figures").exists()


def test_the_ode_is_drawn_at_the_runs_shear_rate_in_the_papers_convention(tmp_path, capsys):
    # the run's "rate" was taken as it stood: a shear towards −x failed the whole plot
    # ("option '--rate' = -0.3 is invalid", exit 2), a scale = "shear_rate" flow of rate
    # 0.0125 on Ly = 24 (u = 0.3 y/Ly) drew the ODE at γ̇ = 0.0125, and Poiseuille runs
    # drew the ODE of simple shear at their rate
    runs = {}
    for name, flow in (("towards_minus_x", {"type": "shear", "rate": -0.3}),
                       ("gradient", {"type": "shear", "rate": 0.0125, "scale": "shear_rate"}),
                       ("poiseuille", {"type": "poiseuille", "rate": 0.3})):
        data = {**TINY, "output": {"fields": False}, "phases": [TINY["phases"][0], {**TINY["phases"][1], "flow": flow}]}
        run_scene(scene_from_dict(data), tmp_path / name, progress=False)
        runs[name] = open_run(tmp_path / name).complete()
    assert runs["towards_minus_x"].shear_rate == -0.3 and runs["poiseuille"].shear_rate is None
    assert runs["gradient"].shear_rate == pytest.approx(0.3)
    with pytest.warns(UserWarning, match=r"no minimal-model curve: .* γ̇ = -0\.3 .*--ode-rate 0\.3 draws that"):
        _written(plot_run(tmp_path / "towards_minus_x", tmp_path / "minus"))
    assert main(["plot", str(tmp_path / "towards_minus_x"), "-o", str(tmp_path / "cli")]) == 0


def test_run_without_flow(tmp_path):
    data = {**TINY, "output": {"fields": False}, "phases": TINY["phases"][:1]}
    run_scene(scene_from_dict(data), tmp_path / "run", progress=False)
    assert open_run(tmp_path / "run").complete().shear_rate is None
    _written(plot_run(tmp_path / "run", tmp_path / "plain"))  # no ODE
    _written(plot_run(tmp_path / "run", tmp_path / "ode", ode_rate=0.2))  # the ODE from the first frame


# -- meshed runs ----------------------------------------------------------------------------

OBSTACLE = (18.0, 8.0, 3.0)
MESH = {
    "name": "tiny mesh",
    "domain": {"kind": "mesh", "mesh": "channel.vtu", "h": 1.0},
    "particles": {"layout": "random", "N": 4, "seed": 1, "initial_radius": 4.0},
    "output": {"fields": True},
    "phases": [
        {"name": "relax", "duration": 10.0, "dt": 1.0, "frame_interval": 5.0},
        {"name": "flow", "duration": 20.0, "dt": 1.0, "frame_interval": 5.0,
         "flow": {"type": "stokes", "max_velocity": 0.3}},
    ],
}


@pytest.fixture(scope="module")
def mesh_run(tmp_path_factory) -> Path:
    """A run on a Delaunay channel between walls at y = −4 and y = 20, around an obstacle."""
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing

    root = tmp_path_factory.mktemp("mesh")
    mesh, boundaries = delaunay_channel(36.0, edge_for_spacing(1.0), lambda x: 0 * x - 4.0, lambda x: 0 * x + 20.0,
                                        obstacles=[OBSTACLE], seed=2)
    write_domain(root / "channel.vtu", mesh, boundaries)
    run_scene(scene_from_dict(MESH, root), root / "run", progress=False)
    return root / "run"


def _copy_run(run: Path, to: Path, without: tuple = ()) -> Path:
    """A copy of a run directory without the files or folders named in ``without``."""
    shutil.copytree(run, to, ignore=lambda folder, names: [n for n in names if Path(folder) == run and n in without])
    return to


def test_plot_of_a_mesh_run_writes_every_figure(mesh_run, capsys):
    assert main(["plot", str(mesh_run)]) == 0
    printed = capsys.readouterr().out.split()
    assert len(printed) == len(FIGURES)
    for name in FIGURES:
        assert (mesh_run / "figures" / f"{name}.png").stat().st_size > 1000
    run = open_run(mesh_run).complete()
    assert run.kind == "mesh" and run.shear_rate is None  # a stokes flow has no rate: no ODE
    assert run.extent == pytest.approx((0.0, 36.0, -4.0, 20.0))


def test_mesh_snapshot_is_drawn_on_the_mesh_and_masks_the_obstacle(mesh_run):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from femphase.plot.run import draw_snapshot

    fig, ax = plt.subplots()
    draw_snapshot(ax, open_run(mesh_run).complete())
    phi_sum = ax.images[0].get_array()
    assert ax.images[0].get_extent() == pytest.approx([0.0, 36.0, -4.0, 20.0])
    rows, cols = phi_sum.shape
    pixel = lambda x, y: (int((y + 4.0) / 24.0 * rows), int(x / 36.0 * cols))  # noqa: E731
    assert np.ma.is_masked(phi_sum[pixel(*OBSTACLE[:2])])  # no mesh inside the obstacle
    assert not np.ma.getmaskarray(phi_sum)[pixel(2.0, 18.0)]
    assert 0.0 <= phi_sum.min() and phi_sum.max() > 0.9  # the particles' plateaus
    plt.close(fig)


@pytest.mark.parametrize("without", [("checkpoint.h5",), ("fields.xdmf", "fields")])
def test_mesh_snapshot_from_either_checkpoint_or_fields(mesh_run, tmp_path, without):
    copy = _copy_run(mesh_run, tmp_path / "copy", without)
    _written(plot_run(copy))


def test_mesh_run_whose_mesh_file_is_gone_is_drawn_from_its_fields(mesh_run, tmp_path):
    copy = _copy_run(mesh_run, tmp_path / "copy")
    scene = (copy / "scene.toml").read_text()
    mesh_line = next(line for line in scene.splitlines() if line.startswith("mesh = "))
    (copy / "scene.toml").write_text(scene.replace(mesh_line, f'mesh = "{tmp_path / "gone.vtu"}"'))
    _written(plot_run(copy))
    assert open_run(copy).complete().extent == pytest.approx((0.0, 36.0, -4.0, 20.0))  # from fields.xdmf's nodes


def test_a_run_without_fields_or_checkpoint_gets_the_tables_figures_and_a_warning(tiny_run, tmp_path):
    # output.fields = false and output.checkpoint = false: plot wrote no figure at all
    run = _copy_run(tiny_run, tmp_path / "run", without=("checkpoint.h5", "fields.xdmf", "fields"))
    with pytest.warns(UserWarning, match="no snapshot: .* has neither checkpoint.h5 nor fields.xdmf"):
        paths = plot_run(run, tmp_path / "figures")
    assert set(paths) == set(FIGURES) - {"snapshot"} and all(path.is_file() for path in paths.values())


def test_an_ode_rate_whose_solve_cannot_span_the_run_draws_the_figures_without_it(tiny_run, tmp_path):
    # γ̇ = 1e7 over the run's span is more than 10⁴ half periods: plot stopped after the
    # snapshot with an error about a '--t-end' option it does not have
    with pytest.warns(UserWarning, match=r"no minimal-model curve: at γ̇ = 1e\+07"):
        paths = plot_run(tiny_run, tmp_path / "figures", ode_rate=1e7)
    _written(paths)


def test_the_order_figure_counts_t1s_with_the_runs_own_counter(tiny_run, tmp_path, monkeypatch):
    # it counted from the frames alone: 190 where the run's counter, looking every 20 time
    # units, had 570 (γ̇ = 1, frames 400 apart)
    import femphase.plot.run as module

    figures = []
    monkeypatch.setattr(module, "save", lambda fig, path: figures.append(fig) or path)
    run = open_run(tiny_run).complete()
    module.plot_order(run, tmp_path / "order.png")
    counted = figures[0].axes[2].lines[0]
    np.testing.assert_array_equal(counted.get_xdata(), run.time)
    np.testing.assert_array_equal(counted.get_ydata(), run.globals["t1_count"])


def test_the_snapshot_draws_each_particles_axis_with_its_own_radius(tmp_path, monkeypatch):
    # the axis was R·r with the model's R for every particle, whatever particles.radii said
    import femphase.plot.run as module

    data = {**TINY, "particles": {"layout": "list", "centres": [[10.0, 12.0], [31.0, 12.0]], "radii": [5.0, 7.0]},
            "phases": TINY["phases"][:1]}
    run_scene(scene_from_dict(data), tmp_path / "run", progress=False)
    figures = []
    monkeypatch.setattr(module, "save", lambda fig, path: figures.append(fig) or path)
    run = open_run(tmp_path / "run").complete()
    module.plot_snapshot(run, tmp_path / "snapshot.png")
    segments = [line for line in figures[0].axes[0].lines if line.get_color() == "red"]
    lengths = [np.hypot(np.ptp(line.get_xdata()), np.ptp(line.get_ydata())) for line in segments]
    np.testing.assert_allclose(lengths, [5.0, 7.0] * run.elongation[-1], rtol=1e-9)


def test_figures_of_a_run_that_failed_after_one_frame_say_so_and_show_it(tmp_path, monkeypatch):
    # every curve was a single invisible point, and nothing said the run had failed
    import femphase.plot.run as module
    from femphase.cli import main as cli

    scene = tmp_path / "tiny.toml"
    from femphase.tomlio import to_toml

    scene.write_text(to_toml({**TINY, "numerics": {"blowup_margin": 1e-12}}))
    assert cli(["run", str(scene), "-o", str(tmp_path / "run"), "-q"]) == 3
    figures = []
    monkeypatch.setattr(module, "save", lambda fig, path: figures.append(fig) or path)
    with pytest.warns(UserWarning, match="run status 'failed'"):
        plot_run(tmp_path / "run", tmp_path / "figures")
    elongation = next(fig.axes[0] for fig in figures if fig.axes[0].get_ylabel().startswith("elongation"))
    assert "failed" in elongation.get_title()
    assert all(line.get_marker() == "o" for line in elongation.lines if len(line.get_xdata()) == 1)


def test_a_table_cut_since_the_run_is_said_and_its_axes_not_drawn_on_the_last_fields(tiny_run, tmp_path):
    # a particles.csv cut mid-row gave no word, and the snapshot of the checkpoint's t = 80
    # carried the elongation axes of the table's last complete frame
    copy = _copy_run(tiny_run, tmp_path / "copy")
    table = copy / "particles.csv"
    text = table.read_text()
    table.write_text(text[:text.index("\n40.0,")] + "\n40.0,0,12.")  # up to t = 35, and half a row
    with pytest.warns(UserWarning) as caught:
        _written(plot_run(copy))
    said = [str(w.message) for w in caught]
    assert any("complete frames end at t = 35, before the run's end at t = 80" in m for m in said), said
    assert any("no complete frame at the fields' t = 80 (its frames end at t = 35)" in m for m in said), said


def test_a_run_scene_that_no_longer_loads_is_named_by_its_file(tiny_run, tmp_path, capsys):
    # a run written with an extension, plotted or compared without it: the message named the
    # key but not which of compare's two runs
    copy = _copy_run(tiny_run, tmp_path / "copy")
    scene = copy / "scene.toml"
    text = scene.read_text()
    assert '"order"]' in text
    scene.write_text(text.replace('"order"]', '"mine"]'))
    assert main(["compare", str(tiny_run), str(copy), "-o", str(tmp_path / "compared")]) == 2
    err = capsys.readouterr().err
    assert "'mine' is invalid: one of" in err and f"(in {scene})" in err, err


def test_a_table_without_its_key_columns_and_an_output_it_cannot_make_are_named(tiny_run, tmp_path, capsys):
    # a particles.csv without an id column was "internal error (KeyError: 'id')"; a -o that
    # cannot be made a bare "[Errno 2] No such file or directory"
    copy = _copy_run(tiny_run, tmp_path / "copy")
    (copy / "particles.csv").write_text("a,b,c\n")
    assert main(["plot", str(copy)]) == 2
    assert "particles.csv' has no column 'time' (its columns: a, b, c): the file is damaged" in capsys.readouterr().err
    assert main(["plot", str(tiny_run), "-o", "/proc/femphase-nope"]) == 2
    assert "option '-o' = '/proc/femphase-nope' is invalid: a directory femphase can write to" in capsys.readouterr().err
