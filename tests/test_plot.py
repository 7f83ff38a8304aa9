"""`femphase plot`: every figure of a tiny run is written; bad directories give clear errors."""

from pathlib import Path

import pytest

from femphase.cli import main
from femphase.plot import FIGURES, load_run, plot_run
from femphase.scene import scene_from_dict
from femphase.simulation import run_scene

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
    copy = tmp_path / "copy"
    copy.mkdir()
    for path in tiny_run.iterdir():
        if path.name != "checkpoint.npz":
            (copy / path.name).write_bytes(path.read_bytes())
    _written(plot_run(copy))
    assert (copy / "figures" / "snapshot.png").is_file()


def test_order_is_computed_when_the_run_did_not_write_it(tmp_path):
    data = {**TINY, "output": {"fields": False}}
    run_scene(scene_from_dict(data), tmp_path / "run", progress=False)
    run = load_run(tmp_path / "run")
    assert "Psi6" not in run.globals
    _written(plot_run(tmp_path / "run"))


def test_missing_directory_is_a_clear_error(tmp_path, capsys):
    assert main(["plot", str(tmp_path / "nowhere")]) == 2
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_run(tmp_path / "nowhere")


def test_directory_that_is_not_a_run_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "scene.toml").write_text('name = "x"\n')
    assert main(["plot", str(tmp_path)]) == 2
    assert "not a femphase run directory" in capsys.readouterr().err
    assert "particles.csv" in str(pytest.raises(FileNotFoundError, load_run, tmp_path).value)


def test_bad_ode_rate_is_rejected(tiny_run, tmp_path, capsys):
    assert main(["plot", str(tiny_run), "-o", str(tmp_path), "--ode-rate", "-1"]) == 2
    assert "--ode-rate" in capsys.readouterr().err


def test_run_without_flow(tmp_path):
    data = {**TINY, "output": {"fields": False}, "phases": TINY["phases"][:1]}
    run_scene(scene_from_dict(data), tmp_path / "run", progress=False)
    assert load_run(tmp_path / "run").shear_rate is None
    _written(plot_run(tmp_path / "run", tmp_path / "plain"))  # no ODE
    _written(plot_run(tmp_path / "run", tmp_path / "ode", ode_rate=0.2))  # the ODE from the first frame
