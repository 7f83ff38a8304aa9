"""docs/outputs.md documents every file and column a run writes; the wall-contact flag of the
shape observable on both domains."""

import re
from pathlib import Path

import numpy as np
import pytest

from femphase.analysis.observables import OBSERVABLES
from femphase.analysis.shape import shape_observables, wall_contact, wall_dofs
from femphase.config import Numerics
from femphase.domains.mesh.domain import MeshDomain
from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing
from femphase.io.files import read_csv
from femphase.io.rundir import OUTPUTS
from femphase.run.runner import run_scene
from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict
from femphase.state import discs_state

DOC = Path(__file__).resolve().parents[1] / "docs" / "outputs.md"


def section(text: str, title: str) -> str:
    """The text under the heading ``## title`` up to the next ``## `` heading."""
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, flags=re.S | re.M)
    assert match, f"docs/outputs.md has no section '## {title}'"
    return match.group(1)


def documented(block: str) -> set[str]:
    return set(re.findall(r"^\| `([^`]+)` \|", block, flags=re.M))


def small_scene(**output):
    return scene_from_dict({"name": "outputs", "domain": {"Lx": 40.0, "Ly": 40.0},
                            "particles": {"layout": "list", "centres": [[10.0, 5.0], [30.0, 20.0], [20.0, 34.0]]},
                            "output": {"fields": False, **output},
                            "phases": [{"duration": 2.0, "dt": 1.0, "frame_interval": 1.0}]})


def builtin_observables():
    return [name for name in OBSERVABLES.names() if OBSERVABLES.get(name).__module__ == "femphase.analysis.observables"]


def test_every_column_an_observable_can_produce_is_documented():
    text = DOC.read_text()
    particles, global_ = documented(section(text, "particles.csv")), documented(section(text, "global.csv"))
    simulation = Simulation(small_scene())
    names = builtin_observables()
    assert {"shape", "energy", "order"} <= set(names)
    produced_particle, produced_global = {"time", "id"}, {"time", "step"}
    for name in names:
        observable = simulation.observable(name)
        produced_particle |= set(observable.particle_columns)
        produced_global |= set(observable.global_columns)
    assert produced_particle - particles == set(), "undocumented particles.csv columns"
    assert produced_global - global_ == set(), "undocumented global.csv columns"
    assert "wall_contact" in produced_particle and "area" in produced_global


def test_the_columns_of_a_run_directory_are_the_documented_ones(tmp_path):
    run_scene(small_scene(observables=["shape", "order"]), tmp_path / "run", progress=False)
    text = DOC.read_text()
    header = (tmp_path / "run" / "particles.csv").read_text().splitlines()[0].split(",")
    assert set(header) == documented(section(text, "particles.csv"))
    header = (tmp_path / "run" / "global.csv").read_text().splitlines()[0].split(",")
    assert set(header) == documented(section(text, "global.csv"))
    table = read_csv(tmp_path / "run" / "particles.csv")
    assert set(np.unique(table["wall_contact"])) == {0.0, 1.0}


def test_every_file_of_a_run_directory_is_documented():
    files = section(DOC.read_text(), "Files")
    for name in OUTPUTS:
        assert f"`{name}" in files, name
    for name in ("fields/mesh.h5", "fields/frame_NNNNNN.h5", "phi_sum", "phi_max", "label"):
        assert name in files


def test_wall_contact_on_the_grid():
    sc = small_scene()
    state = sc.initial_state()  # discs of R/2 = 4: φ > 0.01 reaches 8.6 from the centre
    shape = shape_observables(state)
    assert shape.wall_contact.tolist() == [1, 0, 1]  # y = 5 and y = 34 touch, y = 20 does not
    mask = wall_dofs(sc.domain)
    assert set(np.unique(sc.domain.coordinates[1][mask])) == {0.0, 40.0}
    assert mask.sum() == 2 * 40  # two rows of the periodic lattice
    # the threshold is the window threshold: a higher one clears the faint contact of y = 34
    layout, phi = state.flat()
    assert wall_contact(sc.domain, layout, phi, threshold=0.2).tolist() == [1, 0, 0]  # φ_wall 0.27, 0.12


def test_shapes_of_single_precision_fields_are_those_of_the_same_values_in_double():
    # a single-precision flow step's fields were differenced in float32: each gradient
    # rounded to 1e-7 (relative), against the same values read back in double
    sc = small_scene()
    layout, phi = sc.initial_state().flat()
    rng = np.random.default_rng(0)
    single = (phi * (1 + 0.3 * rng.random(phi.size))).astype(np.float32)  # no longer symmetric
    for domain_moments, exact in zip(sc.domain.shape_moments(layout, single),
                                     sc.domain.shape_moments(layout, single.astype(np.float64))):
        np.testing.assert_array_equal(domain_moments, exact)


def test_a_particle_on_a_wall_has_a_biased_shape_tensor_and_is_flagged():
    # relaxed at full size 5 from the wall: wider than tall, yet its shape tensor (without
    # the interface along the wall) reports a vertical elongation axis (docs/outputs.md)
    sc = scene_from_dict({"name": "wall", "domain": {"Lx": 60.0, "Ly": 40.0},
                          "particles": {"layout": "list", "centres": [[30.0, 5.0]], "initial_radius": 8.0},
                          "output": {"fields": False},
                          "phases": [{"duration": 100.0, "dt": 1.0, "frame_interval": 100.0}]})
    recorder = FrameRecorder()
    Simulation(sc).run(sc.initial_state(), [recorder])
    state = recorder.frames[-1].state
    phi = state.global_field(0).reshape(41, 60) > 0.5
    width, height = np.ptp(np.flatnonzero(phi.any(0))) + 1, np.ptp(np.flatnonzero(phi.any(1))) + 1
    assert width > height + 3
    shape = shape_observables(state)
    assert shape.wall_contact[0] == 1
    assert shape.elongation[0] > 0.3 and abs(abs(shape.orientation[0]) - np.pi / 2) < 0.01


def test_wall_contact_on_a_mesh_with_a_curved_wall_and_an_obstacle():
    edge = edge_for_spacing(1.0)
    domain = MeshDomain.from_mesh(*delaunay_channel(
        40.0, edge, lambda x: 3.0 + 2.0 * np.sin(2 * np.pi * x / 40.0), lambda x: 0 * x + 60.0,
        obstacles=[(30.0, 40.0, 4.0)], seed=3))
    # near the curved bottom wall (at y = 5 below x = 10), mid-channel, next to the obstacle
    centres = np.array([[10.0, 10.0], [12.0, 28.0], [30.0, 51.0]])
    state = discs_state(domain, centres, np.full(3, 8.0), np.full(3, 4.0), 2.0, domain.window_policy(Numerics()))
    assert shape_observables(state).wall_contact.tolist() == [1, 0, 1]
    mask = wall_dofs(domain)
    x, y = domain.coordinates
    bottom = 3.0 + 2.0 * np.sin(2 * np.pi * x / 40.0)
    on_bottom, on_obstacle = np.isclose(y, bottom, atol=1e-6), np.isclose(np.hypot(x - 30, y - 40), 4.0)
    assert np.all(mask == (on_bottom | on_obstacle | (y == 60.0)))  # no dof of the periodic sides
    # far from every wall: no contact, with windows or without
    far = discs_state(domain, np.array([[12.0, 28.0]]), np.full(1, 8.0), np.full(1, 4.0), 2.0,
                      domain.window_policy(Numerics(windows=False)))
    assert shape_observables(far).wall_contact.tolist() == [0]


@pytest.mark.parametrize("threshold", [0.01, 0.2])
def test_the_shape_observable_uses_the_scene_threshold(threshold):
    sc = scene_from_dict({"name": "t", "domain": {"Lx": 40.0, "Ly": 40.0},
                          "particles": {"layout": "list", "centres": [[20.0, 11.0]], "initial_radius": 8.0},
                          "numerics": {"threshold": threshold}, "output": {"fields": False},
                          "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0}]})
    values = Simulation(sc).observable("shape")(sc.initial_state(), {})
    # the disc's tail reaches the wall with φ = (1 + tanh(−3/2))/2 ≈ 0.047
    assert values["wall_contact"].tolist() == [1 if threshold < 0.047 else 0]


@pytest.mark.parametrize("mesh", [False, True])
def test_frame_fields_hold_the_largest_field_and_its_particle_at_every_node(mesh):
    """phi_max and label of a field frame: at every dof max_i φ_i, φ_i zero outside its window
    (so the largest φ of the windows covering it, or 0 where some window misses it; ties: the
    later window in layout order); the label is that window's particle where phi_max > 0.5,
    else −1. Reference: the sort of all positions by (dof, φ), on overlapping windows with
    negative values and ties."""
    from femphase.domains.grid.domain import GridDomain
    from femphase.domains.grid.lattice import channel_grid
    from femphase.io.fields import point_data

    domain = (MeshDomain.from_mesh(*delaunay_channel(40.0, edge_for_spacing(1.5), lambda x: 0 * x,
                                                     lambda x: 0 * x + 40.0, seed=3)) if mesh
              else GridDomain(channel_grid(40.0, 40.0, 1.0)))
    centres = np.array([[10.0, 10.0], [14.0, 10.0], [12.0, 13.0], [30.0, 30.0]])
    state = discs_state(domain, centres, np.full(4, 8.0), np.full(4, 4.0), 2.0, domain.window_policy(Numerics()))
    rng = np.random.default_rng(3)
    state.fields = [rng.integers(-2, 5, field.size) / 4.0 for field in state.fields]  # many ties
    layout, phi = state.flat()
    order = np.lexsort((phi, layout.node_index))
    nodes = layout.node_index[order]
    last = np.append(nodes[1:] != nodes[:-1], True)
    top, best = np.zeros(state.domain.n_dofs), np.zeros(state.domain.n_dofs)
    top[nodes[last]], best[nodes[last]] = phi[order][last], layout.owner[order][last]
    covered = np.bincount(layout.node_index, minlength=state.domain.n_dofs)
    missed = covered < state.n_particles  # some window misses the dof, and its φ_i is 0 there
    assert (top[missed] < 0).any()  # the covering windows' maxima go negative there
    top[missed] = np.maximum(top[missed], 0.0)
    data = point_data(state, per_particle=False)
    assert np.array_equal(data["phi_max"], top[state.domain.dof_map])
    assert np.array_equal(data["label"], np.where(top > 0.5, best, -1.0)[state.domain.dof_map])
    assert set(np.unique(data["label"])) >= {-1.0, 0.0, 1.0, 2.0, 3.0}


def test_a_recorded_series_that_does_not_exist_names_the_recorded_ones():
    scene = small_scene()
    recorder = FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [recorder])
    assert recorder.series("elongation").shape == (len(recorder.frames), scene.n_particles)
    with pytest.raises(KeyError, match="no particle column 'free_energy'; recorded: area, .*kind='global'"):
        recorder.series("free_energy")
    with pytest.raises(KeyError, match="no global column 'elongtion'"):
        recorder.series("elongtion", "global")
    with pytest.raises(ValueError, match="kind = 'globals' is invalid"):
        recorder.series("area", "globals")


def test_a_simulation_takes_one_tracker_or_a_list_and_names_what_it_cannot_take():
    sc = small_scene()
    recorder = FrameRecorder()
    Simulation(sc).run(sc.initial_state(), recorder)  # one tracker, as py-pde takes it
    assert len(recorder.frames) == 3
    with pytest.raises(TypeError, match=r"trackers must be Tracker instances .*\['function'\]"):
        Simulation(sc).run(sc.initial_state(), [recorder, lambda state: None])
    with pytest.raises(TypeError, match="state must be a femphase State .* not NoneType"):
        Simulation(sc).run(None, [recorder])


def test_a_scene_takes_one_assignment_as_a_string(tmp_path):
    from femphase.scene import load_scene

    path = tmp_path / "scene.toml"
    path.write_text('[[phases]]\nduration = 2.0\ndt = 1.0\nframe_interval = 1.0\n')
    assert load_scene(path, "phases.0.duration=4").phases[0].duration == 4.0


def test_a_vanished_particle_has_no_centroid_or_shape_and_no_neighbours():
    import warnings

    from femphase.analysis.observables import Order
    from femphase.analysis.shape import present, shape_observables
    from femphase.scene import scene_from_dict

    scene = scene_from_dict({"name": "gone", "domain": {"Lx": 40.0, "Ly": 40.0},
                             "particles": {"layout": "list", "centres": [[10.0, 20.0], [30.0, 20.0], [20.0, 8.0],
                                                                         [20.0, 32.0]]},
                             "output": {"fields": False}, "phases": [{"duration": 10.0, "dt": 10.0,
                                                                      "frame_interval": 10.0}]})
    state = scene.initial_state()
    state.fields[1][:] = 0.0          # exactly zero: its weighted centroid is 0/0
    state.fields[2][:] *= 1e-40       # rounding noise: a centroid that could lie anywhere
    layout, phi = state.flat()
    assert present(layout, phi).tolist() == [True, False, False, True]
    # the level is the interface's, 1/2 (fields of 0 and 1e-40 did not pin it): a faded field
    # that peaks just below it has vanished, one just above has not
    faded = [field / max(field.max(), 1e-300) for field in state.fields]  # the zero field stays zero
    for peak, expected in ((0.49, False), (0.51, True)):
        layout, phi = type(state)(state.domain, state.windows, [peak * f for f in faded], state.radii).flat()
        assert present(layout, phi).tolist() == [expected, False, expected, expected]
    layout, phi = state.flat()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no divide-by-zero warnings on the way
        shape = shape_observables(state)
        order = Order(type("Run", (), {"domain": state.domain})())
        order.look(state)  # the counter starts from these centroids
        state.time += 10.0
        order.look(state)  # and updates with them
    assert np.isnan(shape.x[1:3]).all() and np.isnan(shape.elongation[1:3]).all()
    assert np.isfinite(shape.x[[0, 3]]).all() and shape.area[1] == 0.0 and shape.area[2] > 0.0
    assert order.t1.count == 0


def test_the_bulk_mean_elongation_is_over_the_particles_present(tmp_path, monkeypatch):
    # μ = 0: discs started at R/2 = 4 shrink by their curvature and vanish before t = 100
    import warnings

    from femphase.aggregate import summarise_run
    from femphase.io.reader import RunData, open_run
    from femphase.scene import scene_from_dict

    scene = scene_from_dict({"name": "vanishing", "domain": {"Lx": 60.0, "Ly": 40.0}, "model": {"mu": 0.0},
                             "particles": {"layout": "list", "centres": [[10.0, 20.0], [30.0, 20.0], [50.0, 20.0]]},
                             "output": {"fields": False},
                             "phases": [{"duration": 100.0, "dt": 10.0, "frame_interval": 50.0}]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the guard's "vanished" warning
        run_scene(scene, tmp_path / "run", progress=False)
    run = open_run(tmp_path / "run")
    assert np.isfinite(run.elongation[0]).all() and np.isnan(run.elongation[-1]).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "mean of empty slice" on the way
        assert np.isnan(run.bulk_elongation()[-1]) and np.isfinite(run.bulk_elongation()[0])
        assert np.isnan(summarise_run(run)["elongation_mean"])  # its window holds the last frame only
    # one of three present: the mean is that one's, not NaN and not a mean over noise
    monkeypatch.setattr(RunData, "elongation", property(lambda self: np.array([[0.1, 0.2, 0.3], [0.4, np.nan, np.nan]])))
    assert run.bulk_elongation().tolist() == pytest.approx([0.2, 0.4])


def test_runs_with_vanished_particles_keep_their_frames_in_comparisons_and_figures(tmp_path):
    # μ = 0: the discs vanish between t = 50 and 100; two time steps give two runs to compare
    import warnings

    from femphase.compare import compare_runs
    from femphase.io.reader import open_run
    from femphase.plot.run import plot_run
    from femphase.scene import scene_from_dict

    for name, dt in (("a", 10.0), ("b", 5.0)):
        scene = scene_from_dict({"name": "vanishing", "domain": {"Lx": 60.0, "Ly": 40.0}, "model": {"mu": 0.0},
                                 "particles": {"layout": "list", "centres": [[10.0, 20.0], [30.0, 20.0],
                                                                             [50.0, 20.0]]},
                                 "output": {"fields": False},
                                 "phases": [{"duration": 100.0, "dt": dt, "frame_interval": 10.0,
                                             "flow": {"type": "shear", "rate": 0.1}}]})
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the guard's "vanished" warning
            run_scene(scene, tmp_path / name, progress=False)
    run = open_run(tmp_path / "a")
    gone = np.isnan(run.x).all(axis=1)
    assert gone[-1] and not gone[0]
    assert run.complete().time.tolist() == run.time.tolist()  # every row is listed, NaN or not
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no all-NaN or empty-slice warnings on the way
        result = compare_runs(tmp_path / "a", tmp_path / "b")
        figures = plot_run(tmp_path / "a", tmp_path / "figures")
    assert result["time"].tolist() == run.time.tolist()
    x = result["series"]["x"]
    assert np.isfinite(x[~gone]).all() and np.isnan(x[gone]).all()
    assert np.isfinite(result["series"]["area"]).all()  # areas are compared whether a particle is present or not
    assert all(path.stat().st_size > 0 for path in figures.values())


def test_frame_times_are_written_as_the_multiples_of_dt_they_are(tmp_path):
    # the clock adds dt step by step: ten steps of 0.1 wrote 0.9999999999999999, and a filter
    # time == 1.0 found nothing; the outputs give the times to 12 significant digits
    import h5py

    scene = scene_from_dict({
        "name": "clock", "domain": {"Lx": 24.0, "Ly": 24.0, "h": 1.0},
        "particles": {"layout": "single", "initial_radius": 4.0},
        "phases": [{"name": "relax", "duration": 1.0, "dt": 0.1, "frame_interval": 0.3}]})
    run_scene(scene, tmp_path / "run", progress=False)
    expected = [0.0, 0.3, 0.6, 0.9, 1.0]
    assert read_csv(tmp_path / "run" / "global.csv")["time"].tolist() == expected
    assert sorted(set(read_csv(tmp_path / "run" / "particles.csv")["time"].tolist())) == expected
    with h5py.File(tmp_path / "run" / "fields" / "frame_000003.h5") as frame:
        assert float(frame.attrs["time"]) == 0.9


@pytest.mark.parametrize("kind", ["grid", "mesh"])
def test_the_centroid_of_a_lopsided_particle_across_the_seam_is_its_weighted_mean(kind):
    # the x column was the circular mean arg ∫φ e^{2πix/Lx}: 0.07–0.28 off ∫xφ/∫φ for ellipses
    # cut by a wall, and exactly Lx for a disc centred at x = 0
    from femphase.domains.grid.domain import GridDomain
    from femphase.domains.grid.lattice import channel_grid
    from femphase.state import State

    # a period twice the paper's, so that the tanh tails reach the opposite side of the seam
    # below 1e-9 and the mean about any point of the particle is the same
    length, width = 140.0, 40.0
    domain = (GridDomain(channel_grid(length, width, 1.0)) if kind == "grid"
              else MeshDomain.from_mesh(*delaunay_channel(length, edge_for_spacing(1.0), lambda x: 0 * x,
                                                          lambda x: 0 * x + width)))
    window = domain.full_window()
    x, y = domain.window_coordinates(window)
    mass = domain.operators.lumped_mass  # the full window holds every dof, in storage order

    def ellipse(cx, cy, a, b, angle):
        dx = np.mod(x - cx + length / 2, length) - length / 2
        along, across = np.cos(angle) * dx + np.sin(angle) * (y - cy), -np.sin(angle) * dx + np.cos(angle) * (y - cy)
        return 0.5 * (1 + np.tanh((1 - np.hypot(along / a, across / b)) * np.sqrt(a * b) / 2.0))

    shapes = [((139.0, 2.0), 20.0, 5.0, 0.2), ((0.5, 3.0), 16.0, 5.0, 0.4), ((0.0, 20.0), 8.0, 8.0, 0.0)]
    for centre, a, b, angle in shapes:
        phi = ellipse(*centre, a, b, angle)
        state = State(domain, [window], [phi], np.array([8.0]))
        dx = np.mod(x - centre[0] + length / 2, length) - length / 2
        expected = np.mod(centre[0] + np.sum(mass * phi * dx) / np.sum(mass * phi), length)
        measured = shape_observables(state).x[0]
        assert 0.0 <= measured < length
        assert min(abs(measured - expected), length - abs(measured - expected)) < 1e-9


@pytest.mark.parametrize("kind", ["grid", "mesh"])
def test_a_symmetric_field_whose_tail_reaches_half_a_period_is_centred(kind):
    # the tail half a period from the disc (no window cuts it) was counted on one side only:
    # a symmetric disc on the full mesh came out 5.7e-7 off its centre
    from femphase.domains.grid.domain import GridDomain
    from femphase.domains.grid.lattice import channel_grid
    from femphase.domains.mesh.generation import structured_channel
    from femphase.state import State

    domain = GridDomain(channel_grid(16.0, 16.0, 1.0))
    if kind == "mesh":
        domain = MeshDomain.from_mesh(*structured_channel(16.0, 16.0, 1.0))
    x, y = domain.window_coordinates(domain.full_window())
    period = domain.period
    dx = np.mod(x - 8.0 + 0.5 * period, period) - 0.5 * period
    phi = np.exp(-(dx**2 + (y - 8.0) ** 2) / 20.0)  # 0.04 half a period away
    state = State(domain, [domain.full_window()], [phi], np.array([8.0]))
    centre = domain.centroids(*state.flat())[0]
    assert abs(centre[0] - 8.0) < 1e-12 and abs(centre[1] - 8.0) < 1e-12


def test_a_frame_recorder_records_a_registered_observable_the_scene_asks_for():
    # its needs were fixed to shape, energy and order: a registered observable in
    # output.observables reached run directories but not the recorder (KeyError)
    from femphase.analysis.observables import OBSERVABLES, Observable

    class Highest(Observable):
        name = "highest"
        particle_columns = ("phi_highest",)

        def __call__(self, state, values):
            return {"phi_highest": np.array([float(np.max(f)) for f in state.fields])}

    OBSERVABLES.register("highest")(Highest)
    try:
        scene = small_scene(observables=["shape", "highest"])
        recorder = FrameRecorder()
        Simulation(scene).run(scene.initial_state(), recorder)
        assert recorder.series("phi_highest").shape == recorder.series("elongation").shape
        assert np.all(recorder.series("phi_highest") > 0.5)
    finally:
        OBSERVABLES.unregister("highest")
    with pytest.raises(KeyError, match="no frame recorded yet"):
        FrameRecorder().series("elongation")
    # Frame.shape carries the wall contact the frame computed (it was None)
    np.testing.assert_array_equal(recorder.frames[-1].shape.wall_contact, recorder.series("wall_contact")[-1])


def test_an_observables_mistakes_are_named_before_they_reach_the_outputs():
    # a column named like another's overwrote it (particles.csv with two x; global.csv's time
    # read back as -5), a missing column or a wrong shape failed far from its cause, a
    # requirement of itself recursed without end, and global values of a requirement could
    # not be read at all
    from contextlib import contextmanager

    from femphase.analysis.observables import Observable
    from femphase.errors import SceneError

    @contextmanager
    def registered(name, **body):
        cls = type(name.title(), (Observable,), {"name": name, **body})
        OBSERVABLES.register(name)(cls)
        try:
            yield
        finally:
            OBSERVABLES.unregister(name)

    def run(*observables):
        scene = small_scene(observables=["shape", *observables])
        recorder = FrameRecorder()
        Simulation(scene).run(scene.initial_state(), recorder)
        return recorder

    constant = {"__call__": lambda self, state, values: {"x": np.zeros(state.n_particles), "step": 1.0}}
    for columns, clash in ((dict(particle_columns=("x",)), "'x', which the observable 'shape' has already"),
                           (dict(global_columns=("step",)), "'step', which the table itself has already")):
        with registered("clash", **columns, **constant), pytest.raises(SceneError, match=clash):
            run("clash")
    returns = {"nothing": {}, "short": {"lonely": np.zeros(1)}, "text": {"lonely": np.array(["a", "b"])}}
    for case, value in returns.items():
        call = {"__call__": lambda self, state, values, value=value: value}
        message = r"'lonely' is missing" if case == "nothing" else r"one value per particle \(3,\)"
        with registered("wrong", particle_columns=("lonely",), **call), pytest.raises(SceneError, match=message):
            run("wrong")
    with registered("loop", requires=("loop",), **constant), pytest.raises(SceneError, match="loop → loop"):
        run("loop")
    with registered("needy", requires=("nosuch",), **constant), pytest.raises(SceneError, match="requires 'nosuch'"):
        run("needy")
    # the values so far hold the requirements' global values too; per particle first ("area")
    reads = {"__call__": lambda self, state, values: {"twice": 2 * values["free_energy"],
                                                      "area_sum": float(np.sum(values["area"]))}}
    with registered("reads", requires=("energy",), global_columns=("twice", "area_sum"), **reads):
        frame = run("energy", "reads").frames[-1]
    assert frame.globals["twice"] == 2 * frame.globals["free_energy"]
    assert frame.globals["area_sum"] == pytest.approx(float(np.sum(frame.particle["area"])))


def test_a_trackers_frame_without_its_observable_says_why():
    # a tracker that did not set needs found frame.particle empty: a bare KeyError 'elongation'
    from femphase.run.simulation import Tracker

    class Reads(Tracker):
        def frame(self, frame):
            frame.particle["elongation"]

    scene = small_scene(observables=["shape"])
    with pytest.raises(KeyError, match=r"the frame's particle columns are none; .*needs = frozenset\(\{'shape'\}\)"):
        Simulation(scene).run(scene.initial_state(), Reads())

    class ReadsGlobals(Tracker):  # the particle table has columns, the global one none
        needs = frozenset({"shape"})

        def frame(self, frame):
            frame.globals["free_energy"]

    with pytest.raises(KeyError, match=r"'free_energy': the frame's global columns are none"):
        Simulation(scene).run(scene.initial_state(), ReadsGlobals())

    class Misspelt(Tracker):  # its frames were empty without a word
        needs = frozenset({"shpae"})

    with pytest.raises(ValueError, match=r"the tracker Misspelt needs \['shpae'\], which name no observable"):
        Simulation(scene).run(scene.initial_state(), Misspelt())


def test_a_tracker_ends_a_run_early_and_the_run_continues_from_there(tmp_path):
    # py-pde's trackers can finish a simulation; here only an error could end one, and a
    # run directory then marked the run failed
    import json

    from femphase.run import RunDirectory, StopRun
    from femphase.run.simulation import Tracker

    class Enough(Tracker):
        needs = frozenset({"shape"})

        def __init__(self, frames):
            self.frames, self.seen = frames, 0

        def frame(self, frame):
            self.seen += 1
            if self.seen == self.frames:
                raise StopRun(f"{self.frames} frames")

    scene = small_scene(observables=["shape"])
    state = Simulation(scene).run(scene.initial_state(), [Enough(2), RunDirectory(tmp_path / "early")])
    assert state.step == 1 and state.time == 1.0  # the initial frame, then the first step's
    info = json.loads((tmp_path / "early" / "run.json").read_text())
    assert info["status"] == "interrupted" and info["message"] == "stopped by a tracker: 2 frames"
    run_scene(scene, tmp_path / "early", resume=True, progress=False)
    run_scene(scene, tmp_path / "whole", progress=False)
    for name in ("particles.csv", "global.csv"):
        assert (tmp_path / "early" / name).read_text() == (tmp_path / "whole" / name).read_text()


def test_a_stop_in_after_step_waits_for_the_steps_bookkeeping():
    # raised before the phase was closed, it would leave a state at the end of a phase that
    # no loop leaves
    from femphase.run import StopRun
    from femphase.run.simulation import Tracker

    class AtTheEnd(Tracker):
        def after_step(self, state):
            if state.phase_step == 2:
                raise StopRun("phase done")

    scene = small_scene(observables=["shape"])
    recorder = FrameRecorder()
    state = Simulation(scene).run(scene.initial_state(), [AtTheEnd(), recorder])
    assert (state.phase, state.phase_step, state.step) == (1, 0, 2)
    assert [frame.state.time for frame in recorder.frames] == [0.0, 1.0, 2.0]  # the last step's frame too


def test_recorded_frame_times_are_the_outputs_times():
    # ten steps of 0.1 were 0.9999999999999999 in FrameRecorder.times, 1 in particles.csv
    from femphase.run import FrameRecorder

    scene = small_scene(observables=["shape"])
    scene = scene_from_dict({**scene.to_dict(), "numerics": {"scheme": "euler"},
                             "phases": [{"name": "relax", "duration": 0.3, "dt": 0.1, "frame_interval": 0.1}]})
    recorder = FrameRecorder()
    Simulation(scene).run(scene.initial_state(), recorder)
    assert recorder.times.tolist() == [0.0, 0.1, 0.2, 0.3]
    assert recorder.frames[3].state.time != 0.3  # the clock itself keeps its last bit
