"""Every bad input to ``femphase run`` gets one message naming the key: exit code 2, no
traceback, nothing in the run directory changed, over the systematic inputs of
:mod:`femphase.testing.fuzzing`; and a valid layout without inclined bonds runs the "order" observable."""

import math
import time

import numpy as np
import pytest

from femphase.analysis.lattice import frame_order, lattice_angle
from femphase.cli import main
from femphase.io.files import read_csv
from femphase.testing.fuzzing import BASE_SCENE, BadInput, bad_inputs, check_bad_input, make_run_directory, to_toml


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def template(workdir):
    return make_run_directory(workdir / "template")


@pytest.fixture(scope="module")
def inputs():
    return bad_inputs()


@pytest.fixture(scope="module")
def checks(inputs, workdir, template):
    start = time.perf_counter()
    out = [(item, check_bad_input(item, workdir, template=template)) for item in inputs]
    return out, time.perf_counter() - start


def failures(results, condition):
    return [f"{item.description}: exit {c.exit_code}, {c.message[-300:]!r}" for item, c in results if not condition(c)]


def test_at_least_200_distinct_deterministic_inputs(inputs):
    assert len(inputs) >= 200
    assert len({item.description for item in inputs}) == len(inputs)
    assert all(item.key for item in inputs)
    assert [i.description for i in bad_inputs()] == [i.description for i in inputs]
    sample = bad_inputs(seed=1, count=50)
    assert len(sample) == 50 and [i.description for i in sample] == [i.description for i in bad_inputs(1, 50)]
    more = bad_inputs(seed=5, count=len(inputs) + 30)
    assert len(more) == len(inputs) + 30 and len({i.description for i in more}) == len(more)


def test_every_bad_input_exits_2(checks):
    results, _ = checks
    assert not failures(results, lambda c: c.exit_code == 2)


def test_every_message_names_its_key(checks):
    results, _ = checks
    assert not failures(results, lambda c: c.names_key)


def test_no_tracebacks(checks):
    results, _ = checks
    assert not failures(results, lambda c: not c.traceback)
    assert not failures(results, lambda c: "internal error" not in c.message)


def test_nothing_written(checks):
    results, _ = checks
    assert not failures(results, lambda c: c.untouched)


def test_rejected_before_stepping(checks):
    results, seconds = checks
    assert seconds < 60, f"{len(results)} inputs took {seconds:.0f} s"
    assert max(c.seconds for _, c in results) < 10


def test_a_run_directory_given_with_resume_is_untouched(inputs, workdir, template):
    """Every scene-level bad input, given a finished run directory and --resume (or the run
    directory as it is): refused with the same key, every byte of the run kept."""
    scene_level = [item for item in inputs if item.target == "new" and not item.options]
    assert len(scene_level) >= 200
    bad = []
    for k, item in enumerate(scene_level):
        check = check_bad_input(item, workdir, target="run", resume=k % 4 != 0, template=template)
        if not check.clean:
            bad.append(f"{item.description}: {check}")
    assert not bad


def test_the_checker_sees_failures(workdir, template, monkeypatch):
    """A valid input is not 'rejected', and an internal error is counted as one."""
    good = check_bad_input(BadInput("valid", BASE_SCENE, key="model.mu"), workdir, template=template)
    assert good.exit_code == 0 and not good.clean and not good.untouched
    import femphase.scene

    def broken(*args, **kwargs):
        raise TypeError("a bug")

    monkeypatch.setattr(femphase.scene, "scene_from_dict", broken)
    check = check_bad_input(BadInput("bug", BASE_SCENE, key="scene"), workdir, template=template)
    assert check.exit_code == 1 and not check.clean


# -- checks made by run_scene before it touches the run directory ---------------------------

PENDING = [
    BadInput("--method fd with dt above the explicit limit", BASE_SCENE, key="phases.0.dt",
             options=("--method", "fd")),
]


@pytest.mark.parametrize("item", PENDING, ids=lambda item: item.description)
def test_method_checks_come_before_any_write(item, workdir, template):
    assert check_bad_input(item, workdir, template=template).clean


# -- the "order" observable on a layout without inclined bonds -----------------------------

RECTANGLE = [[x, y] for y in (4.0, 20.0) for x in (3.0, 9.0, 15.0, 21.0)]


def test_lattice_angle_is_nan_without_inclined_bonds():
    centroids = np.array(RECTANGLE)
    with pytest.raises(ValueError, match="no inclined bonds"):
        lattice_angle(centroids, 24.0)
    order = frame_order(centroids, np.zeros(len(centroids)), 24.0)
    assert math.isnan(order["lattice_angle"])
    assert np.isfinite(order["Psi6"]) and np.isfinite(order["Psi2"])
    # one lane: every centroid on a line (a flat triangulation)
    lane = np.array([[3.0, 12.0], [11.0, 12.0], [19.0, 12.0]])
    order = frame_order(lane, np.zeros(3), 24.0)
    assert math.isnan(order["lattice_angle"]) and order["Psi6"] == pytest.approx(1.0)


@pytest.mark.parametrize("centres", [RECTANGLE, [[3.0, 12.0], [11.0, 12.0], [19.0, 12.0]]],
                         ids=["rectangle", "one lane"])
def test_order_observable_runs_a_rectangular_layout(tmp_path, capsys, centres):
    scene = {
        "name": "rectangle", "model": {"R": 3.0},
        "domain": {"Lx": 24.0, "Ly": 24.0, "h": 1.0},
        "particles": {"layout": "list", "centres": centres, "initial_radius": 1.5},
        "output": {"fields": False, "observables": ["order"]},
        "phases": [{"name": "relax", "duration": 1.0, "dt": 1.0, "frame_interval": 1.0}],
    }
    path = tmp_path / "scene.toml"
    path.write_text(to_toml(scene))
    code = main(["run", str(path), "-o", str(tmp_path / "run"), "-q"])
    assert code == 0, capsys.readouterr().err
    rows = read_csv(tmp_path / "run" / "global.csv")
    assert rows["time"][0] == 0 and math.isnan(rows["lattice_angle"][0])
