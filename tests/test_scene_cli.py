"""Scenes, their errors, and the command line: run, resume, blow-up."""

import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from femphase.cli import main
from femphase.errors import SceneError
from femphase.io.checkpoints import load_checkpoint
from femphase.io.files import read_csv
from femphase.io.rundir import CHECKPOINT
from femphase.placement import hexagonal_centres
from femphase.run.runner import run_scene
from femphase.run.simulation import Simulation, Tracker
from femphase.scene import load_scene, scene_from_dict

SMALL = {
    "name": "tiny",
    "domain": {"Lx": 30.0, "Ly": 30.0, "h": 1.0},
    "particles": {"layout": "list", "centres": [[10.0, 15.0], [21.0, 15.0]], "initial_radius": 5.0},
    "output": {"fields": True},
    "phases": [
        {"name": "relax", "duration": 20.0, "dt": 1.0, "frame_interval": 5.0},
        {"name": "shear", "duration": 30.0, "dt": 1.0, "frame_interval": 5.0, "flow": {"type": "shear", "rate": 0.5}},
    ],
}


def write_scene(path: Path, data: dict = SMALL) -> Path:
    from femphase.tomlio import to_toml

    path.write_text(to_toml(data))
    return path


@pytest.mark.parametrize(
    "assignment, key",
    [
        ("model.R=-1", "model.radius"),  # named as model.lambda=0 is, "(given as model.R)"
        ("model.lambda=0", "model.interface_width"),
        ("model.colour=3", "model.colour"),
        ("domain.h=3", "domain.h"),
        ("domain.Lx=31.5", "domain.Lx"),
        ("particles.layout='grid'", "particles.layout"),
        ("phases.1.dt=0.7", "phases.1.duration"),
        ("phases.1.flow.type='vortex'", "phases.1.flow.type"),
        ("numerics.mass='heavy'", "numerics.mass"),
        ("numerics.tolerance=2", "numerics.tolerance"),  # a relative residual: below 1
        ("particles.N=5", "particles.N"),  # two centres: N = 5 was ignored, and recorded
    ],
)
def test_invalid_scene_values_name_the_key(tmp_path, assignment, key):
    path = write_scene(tmp_path / "scene.toml")
    with pytest.raises(SceneError) as info:
        load_scene(path, [assignment])
    assert info.value.key == key
    assert "invalid" in str(info.value)


def test_a_flow_without_its_type_is_named_with_the_types(tmp_path):
    data = {**SMALL, "phases": [SMALL["phases"][0], {**SMALL["phases"][1], "flow": {"kind": "shear", "rate": 0.5}}]}
    with pytest.raises(SceneError, match=r"flow\.type is not given, so there is no flow; types: .*'shear'") as info:
        scene_from_dict(data)
    assert info.value.key == "phases.1.flow.kind"


def test_a_bad_option_is_named_as_an_option_and_a_bad_key_as_a_scene_key(tmp_path):
    path = write_scene(tmp_path / "scene.toml")
    with pytest.raises(SceneError, match=r"^option '--set' = 'model\.mu' is invalid"):
        load_scene(path, ["model.mu"])
    with pytest.raises(SceneError, match=r"^scene key 'model\.colour' = 3 is invalid"):
        load_scene(path, ["model.colour=3"])


def test_too_many_particles_is_refused_with_the_limit():
    data = {**SMALL, "particles": {"layout": "random", "N": 40}}
    with pytest.raises(SceneError, match="at most") as info:
        scene_from_dict(data)
    assert info.value.key == "particles.N"


@pytest.mark.parametrize("particles, key", [({"layout": "single"}, "model.radius"),
                                             ({**SMALL["particles"], "radii": [16.0, 16.0]}, "particles.radii")])
def test_too_large_particles_of_fixed_count_name_their_radius_not_n(particles, key):
    """A single or listed layout has no N to lower: the message names the radius and its largest value."""
    data = {**SMALL, "model": {"R": 40.0} if key == "model.radius" else {}, "particles": particles}
    with pytest.raises(SceneError, match=r"at most 1\.5 fits \(a root-mean-square radius ≤ ") as info:
        scene_from_dict(data)
    assert info.value.key == key
    # and the domain's size, which a mesh drawn in other units gets wrong
    assert "× the domain's (30 × 30 lattice units, area 900)" in str(info.value)
    # the largest radius the message gives is accepted
    largest = float(str(info.value).split("radius ≤ ")[1].split()[0])
    fits = {**data, "model": {"R": largest}, "particles": {**particles, "radii": None}}
    fits["particles"].pop("radii")
    scene_from_dict(fits)


@pytest.mark.parametrize("scheme", ["adaptive", "sav2"])
def test_a_consistent_mass_under_a_lumped_only_scheme_is_refused_on_loading(tmp_path, scheme):
    """Refused with the scene, before a run directory is touched, and naming the scheme that has it."""
    path = write_scene(tmp_path / "scene.toml")
    refusal = f'"lumped" with numerics.scheme = "{scheme}" .*"euler" for the consistent'
    with pytest.raises(SceneError, match=refusal) as info:
        load_scene(path, ["numerics.mass='consistent'", f"numerics.scheme='{scheme}'"])
    assert info.value.key == "numerics.mass"
    assert main(["run", str(path), "-o", str(tmp_path / "run"), "--set", "numerics.mass='consistent'"]) == 2
    assert not (tmp_path / "run").exists()
    load_scene(path, ["numerics.mass='consistent'", "numerics.scheme='euler'"])


@pytest.mark.parametrize("centres, apart", [([[10.0, 12.0], [10.0, 12.0]], "0 apart"),
                                             ([[0.2, 12.0], [SMALL["domain"]["Lx"] - 0.1, 12.0]], "0.3 apart")])
def test_listed_centres_within_one_spacing_are_refused(centres, apart):
    data = {**SMALL, "particles": {"layout": "list", "centres": centres, "initial_radius": 3.0}}
    with pytest.raises(SceneError, match=f"particles 0 and 1 are {apart}, less than the spacing h"):
        scene_from_dict(data)
    scene_from_dict({**data, "particles": {**data["particles"], "centres": [centres[0], [centres[0][0] + 1.5, 12.0]]}})


def test_the_cli_prints_one_message_and_no_traceback(tmp_path):
    path = write_scene(tmp_path / "scene.toml")
    result = subprocess.run(
        [sys.executable, "-m", "femphase.cli", "run", str(path), "-o", str(tmp_path / "out"), "--set", "model.mu=-3"],
        capture_output=True, text=True,
    )
    assert result.returncode == 2
    assert "model.area_stiffness" in result.stderr or "model.mu" in result.stderr
    assert "Traceback" not in result.stderr


def test_hexagonal_layout_is_the_papers_lattice():
    centres = hexagonal_centres(100, 70.0, 240.0)
    assert centres.shape == (100, 2)
    assert np.allclose(np.diff(np.unique(centres[:, 1])), 12.0)  # 20 rows
    row = np.sort(centres[centres[:, 1] == 6.0, 0])
    assert np.allclose(np.diff(row), 14.0)  # 5 per row


def test_run_directory_holds_every_output(tmp_path):
    path = write_scene(tmp_path / "scene.toml")
    assert main(["run", str(path), "-o", str(tmp_path / "run"), "-q"]) == 0
    run = tmp_path / "run"
    for name in ("scene.toml", "fields.xdmf", "fields/mesh.h5", "fields/frame_000000.h5", "particles.csv",
                 "global.csv", CHECKPOINT, "run.json"):
        assert (run / name).exists(), name
    particles = read_csv(run / "particles.csv")
    assert set(particles) >= {"time", "id", "x", "y", "area", "elongation", "orientation"}
    assert len(particles["time"]) == 2 * 11  # two particles, frames at 0, 5, …, 50
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "completed" and info["steps"] == 50
    # the resolved scene is itself a valid scene that reproduces the settings
    assert load_scene(run / "scene.toml").to_dict()["phases"] == load_scene(path).to_dict()["phases"]


class StopAt(Tracker):
    def __init__(self, step):
        self.stop = step

    def after_step(self, state):  # the adaptive default's calls take several steps
        if state.step >= self.stop:
            raise KeyboardInterrupt


def test_resume_continues_to_the_same_state_as_an_uninterrupted_run(tmp_path):
    scene = load_scene(write_scene(tmp_path / "scene.toml"))
    straight = run_scene(scene, tmp_path / "straight", progress=False)
    from femphase.run.directory import RunDirectory

    interrupted_dir = tmp_path / "interrupted"
    with pytest.raises(KeyboardInterrupt):
        Simulation(scene).run(scene.initial_state(), [RunDirectory(interrupted_dir), StopAt(33)])
    assert json.loads((interrupted_dir / "run.json").read_text())["status"] == "interrupted"
    assert load_checkpoint(interrupted_dir / CHECKPOINT, scene.domain)[0].step == 30  # last frame
    resumed = run_scene(scene, interrupted_dir, resume=True, progress=False)
    assert resumed.step == straight.step
    assert np.allclose(resumed.global_fields(), straight.global_fields(), atol=1e-12)
    a, b = read_csv(tmp_path / "straight" / "global.csv"), read_csv(interrupted_dir / "global.csv")
    assert np.allclose(a["time"], b["time"]) and np.allclose(a["free_energy"], b["free_energy"])


def test_a_blow_up_names_the_step_and_keeps_the_last_good_checkpoint(tmp_path):
    path = write_scene(tmp_path / "scene.toml")
    run = tmp_path / "run"
    # an explicit area term 250× stiffer than the paper's, unstabilised: unstable at dt = 1
    code = main(["run", str(path), "-o", str(run), "-q", "--set", "model.mu=5000", "--set", "numerics.stabilisation=0",
                 "--set", 'numerics.scheme="euler"'])
    assert code == 3
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "failed" and "step" in info["message"]
    checkpoint, _ = load_checkpoint(run / CHECKPOINT, load_scene(run / "scene.toml").domain)
    assert all(np.isfinite(f).all() for f in checkpoint.fields)
    assert checkpoint.step < info["steps"] + 1


def _sheared_nine(t1_interval: float = 10.0, merged_steps: int = 8):
    from femphase.scene import scene_from_dict

    # 9 particles, 3 per row, sheared fast: rows slide past each other with T1s every ~5 frames
    return scene_from_dict({
        "name": "t1", "domain": {"Lx": 42.0, "Ly": 36.0, "h": 1.0},
        "particles": {"layout": "hexagonal", "N": 9, "per_row": 3},
        "output": {"fields": False, "observables": ["shape", "order"], "t1_interval": t1_interval},
        "numerics": {"merged_steps": merged_steps},
        "phases": [{"name": "relax", "duration": 20.0, "dt": 1.0, "frame_interval": 10.0},
                   {"name": "shear", "duration": 180.0, "dt": 1.0, "frame_interval": 10.0,
                    "flow": {"type": "shear", "rate": 2.0}}]})


@pytest.mark.parametrize("t1_interval", [10.0, 2.0])
def test_resume_continues_the_t1_count(tmp_path, t1_interval):
    from femphase.run.directory import RunDirectory

    scene = _sheared_nine(t1_interval)
    run_scene(scene, tmp_path / "straight", progress=False)
    with pytest.raises(KeyboardInterrupt):
        Simulation(scene).run(scene.initial_state(), [RunDirectory(tmp_path / "cut"), StopAt(125)])
    before = read_csv(tmp_path / "cut" / "global.csv")["t1_count"][-1]
    run_scene(scene, tmp_path / "cut", resume=True, progress=False)
    straight, resumed = (read_csv(tmp_path / d / "global.csv") for d in ("straight", "cut"))
    assert before > 0 and straight["t1_count"][-1] > before  # events on both sides of the cut
    assert np.array_equal(straight["t1_count"], resumed["t1_count"])


class Centroids(Tracker):
    """The centroids (the shape observable's rule) after every step, and at the first frame."""

    def __init__(self):
        self.times, self.centroids = [], []

    def record(self, state):
        layout, phi = state.flat()
        self.times.append(state.time)
        self.centroids.append(state.domain.centroids(layout, phi))

    def start(self, simulation, state):
        self.record(state)

    def after_step(self, state):
        self.record(state)


def test_the_t1_count_looks_between_frames_at_its_interval():
    from femphase.analysis.lattice import t1_event_times
    from femphase.run.trackers import FrameRecorder

    scene = _sheared_nine(t1_interval=5.0, merged_steps=1)  # a call per step: Centroids sees every step
    centroids, frames = Centroids(), FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [centroids, frames])
    times = np.array(centroids.times)

    def events(stride):
        return t1_event_times(centroids.centroids[::stride], times[::stride], 42.0).size

    # the counter looks at every 5th step (t = 5, 10, …; the frames, every 10th, among them),
    # and in this run that finds flips the frames alone miss (60 against 54 when written)
    assert frames.series("t1_count", "global")[-1] == events(5) != events(10)


@pytest.mark.parametrize("mu, numerics, warns", [(3000.0, {}, "at least 398 substeps"), (200.0, {}, ""),
                                                  (3000.0, {"area_implicit": True}, "below 4/c = 0.067 time units"),
                                                  (1000.0, {"area_implicit": True}, ""),
                                                  (3000.0, {"scheme": "sav2"}, "steps past 1.5/c = 0.0251"),
                                                  (20.0, {"scheme": "sav2", "area_implicit": True}, ""),
                                                  (1000.0, {"scheme": "sav2", "area_implicit": True},
                                                   "period-2 oscillation")])
def test_an_area_constraint_that_caps_the_substep_far_below_dt_warns(mu, numerics, warns):
    from femphase.errors import StiffnessWarning

    table = {"model": {"area_stiffness": mu}, "domain": {"Lx": 40.0, "Ly": 40.0}, "particles": {"layout": "single"},
             "numerics": numerics, "phases": [{"duration": 10.0, "dt": 10.0, "frame_interval": 10.0}]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene_from_dict(table)
    stiff = [w for w in caught if issubclass(w.category, StiffnessWarning)]
    # c = 0.5·8·3000/(π 8²) = 59.7 per time unit: the ceiling 1.5/c = 0.0251, 398 substeps of dt = 10,
    # with the area mode implicit 4/c = 0.067, 149 (sav2 takes that step at dt = 10, without the
    # ceiling: warned as a step past it; at μ = 20 with the mode implicit dt = 10 is inside 4/c)
    assert bool(stiff) == bool(warns)
    if warns:
        assert warns in str(stiff[0].message)


@pytest.mark.parametrize("kappa, particles, flow, numerics, warns", [
    (5.0, 2, "shear", {"scheme": "sav2"}, "c·dt = 50"), (0.5, 2, "shear", {"scheme": "sav2"}, ""),
    (5.0, 2, "none", {"scheme": "sav2"}, ""), (5.0, 1, "shear", {"scheme": "sav2"}, ""),
    (5.0, 2, "shear", {}, ""), (1000.0, 2, "shear", {}, "at least 1000 substeps per step")])
def test_a_stiff_split_repulsion_under_flow_warns(kappa, particles, flow, numerics, warns):
    # κ = 5 under shear: the split decay's error, which the estimate does not contain, left two
    # pressed discs' repulsion energy 12 % off at dt = 10 with tolerance_t 0.01 changing nothing;
    # sav2 is told the dt, the adaptive scheme keeps c·h ≤ 10 and warns only where that costs
    # more than 64 substeps per dt
    from femphase.errors import StiffnessWarning

    centres = [[10.0, 20.0], [26.0, 20.0]][:particles]
    table = {"model": {"kappa": kappa}, "domain": {"Lx": 40.0, "Ly": 40.0}, "numerics": numerics,
             "particles": {"layout": "list", "centres": centres},
             "phases": [{"duration": 10.0, "dt": 10.0, "frame_interval": 10.0, "flow": {"type": flow, "rate": 1.0}
                         if flow != "none" else {"type": "none"}}]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene_from_dict(table)
    stiff = [str(w.message) for w in caught if issubclass(w.category, StiffnessWarning) and "κ" in str(w.message)]
    assert bool(stiff) == bool(warns)
    if warns:
        assert warns in stiff[0]


@pytest.mark.parametrize("particles, named", [
    ({"layout": "single"}, "'particles.initial_radius' = 4.0 is invalid: initial discs that fit between the walls "
                           "and within the period: a radius < 3 (half the width Ly = 40 and half the period Lx = 6); "
                           "unset, it is half of each particle's target radius (model.radius = 8 at most)"),
    ({"layout": "single", "initial_radius": 3.5}, "'particles.initial_radius' = 3.5 is invalid"),
])
def test_an_initial_disc_wider_than_the_period_names_the_initial_radius(particles, named):
    # unset, the initial radius is R/2 = 4: the refusal named model.radius = 4.0, which was 8
    table = {"domain": {"Lx": 6.0, "Ly": 40.0}, "particles": particles,
             "phases": [{"duration": 10.0, "dt": 10.0, "frame_interval": 10.0}]}
    with pytest.raises(SceneError) as caught:
        scene_from_dict(table)
    assert named in str(caught.value)


@pytest.mark.parametrize("particles, warns", [({"layout": "single"}, False),
                                              ({"layout": "list", "centres": [[10.0, 20.0], [30.0, 20.0]],
                                                "radii": [8.0, 2.5]}, True)])
def test_a_particle_smaller_than_one_and_a_half_interface_widths_warns(particles, warns):
    from femphase.errors import ModelWarning

    table = {"domain": {"Lx": 40.0, "Ly": 40.0}, "particles": particles,
             "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0}]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene_from_dict(table)
    model = [str(w.message) for w in caught if issubclass(w.category, ModelWarning)]
    assert bool(model) == warns
    if warns:  # λ = 2: the bound is 3, and the key is the one that set the small radius
        assert model[0].startswith("particles.radii: a target radius R = 2.5 below 1.5λ = 3")


def test_h_equal_to_the_interface_width_warns_about_pinned_interfaces():
    from femphase.errors import ResolutionWarning
    from femphase.scene import scene_from_dict

    table = {"domain": {"Lx": 40.0, "Ly": 40.0, "h": 2.0}, "particles": {"layout": "single"},
             "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0}]}
    with pytest.warns(ResolutionWarning, match="h = 2 .*λ/h = 1"):
        scene_from_dict(table)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene_from_dict({**table, "domain": {"Lx": 40.0, "Ly": 40.0, "h": 1.0}})


@pytest.mark.parametrize("spacing, outcome", [(1.0, None), (1.5, "warns"), (2.5, "refused")])
def test_a_mesh_is_judged_by_its_node_density_like_the_grid_by_h(tmp_path, spacing, outcome):
    """A Delaunay mesh made for h (edges 1.07 h) holds as many nodes per area as the grid at
    h, so it is judged as that grid would be, not by its longer edges."""
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing
    from femphase.errors import ResolutionWarning

    write_domain(tmp_path / "channel.vtu", *delaunay_channel(40.0, edge_for_spacing(spacing), lambda x: 0 * x,
                                                            lambda x: 0 * x + 40.0, seed=1))
    table = {"domain": {"kind": "mesh", "mesh": "channel.vtu"}, "particles": {"layout": "single"},
             "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0}]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if outcome == "refused":
            with pytest.raises(SceneError, match=r"needs h ≤ λ \(the mesh's effective spacing √\(area/dofs\) is 2\.[45]"):
                scene_from_dict(table, tmp_path)
            return
        scene = scene_from_dict(table, tmp_path)
    assert scene.domain.effective_spacing == pytest.approx(spacing, rel=0.05)
    assert scene.domain.median_edge > 1.03 * scene.domain.effective_spacing
    resolution = [w for w in caught if issubclass(w.category, ResolutionWarning)]
    assert bool(resolution) == (outcome == "warns")
    if resolution:
        assert "the mesh's effective spacing √(area/dofs) = 1.49" in str(resolution[0].message)


def test_a_nominal_h_cannot_make_a_mesh_finer_than_its_nodes(tmp_path):
    """A nominal h finer than the mesh's node density leaves the resolution check to the
    density; one beyond a factor 2 of it describes another mesh and is refused."""
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing

    write_domain(tmp_path / "coarse.vtu", *delaunay_channel(40.0, edge_for_spacing(2.5), lambda x: 0 * x,
                                                           lambda x: 0 * x + 40.0, seed=1))
    table = {"domain": {"kind": "mesh", "mesh": "coarse.vtu", "h": 1.3}, "particles": {"layout": "single"},
             "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0}]}
    with pytest.raises(SceneError, match=r"needs h ≤ λ \(the mesh's effective spacing") as info:
        scene_from_dict(table, tmp_path)
    assert info.value.key == "domain.mesh"
    table["domain"]["h"] = 1.0
    refusal = r"within a factor 2 of the mesh's effective spacing √\(area/dofs\) = 2\.[45]"
    with pytest.raises(SceneError, match=refusal) as info:
        scene_from_dict(table, tmp_path)
    assert info.value.key == "domain.h"


def test_a_mesh_runs_scene_toml_is_the_scene_that_ran(tmp_path):
    """scene.toml wrote a mesh's median edge as domain.h, a nominal h that judges the mesh
    where it is coarser than the nodes: the run's own scene.toml was refused ("needs h ≤ λ")
    for a mesh of effective spacing 1.9 and median edge 2.04, and described a coarser
    resolution for every Delaunay mesh (1.07 for 1.0)."""
    import h5py

    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing

    write_domain(tmp_path / "channel.vtu", *delaunay_channel(40.0, edge_for_spacing(1.9), lambda x: 0 * x,
                                                            lambda x: 0 * x + 40.0, seed=1))
    table = {"domain": {"kind": "mesh", "mesh": "channel.vtu"}, "particles": {"layout": "single"},
             "phases": [{"duration": 2.0, "dt": 1.0, "frame_interval": 1.0}]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the resolution warning of h = 1.9
        scene = scene_from_dict(table, tmp_path)
        assert scene.domain.median_edge > 2.0 > scene.domain.resolution  # λ = 2 between them
        again = scene_from_dict(scene.to_dict(), tmp_path)
        assert again.domain.resolution == scene.domain.resolution and "h" not in again.to_dict()["domain"]
        assert main(["run", str(write_scene(tmp_path / "scene.toml", table)), "-o", str(tmp_path / "run"), "-q"]) == 0
        # a checkpoint written with the median edge as domain.h (femphase ≤ 0.2.0) resumes
        with h5py.File(tmp_path / "run" / CHECKPOINT, "a") as handle:
            saved = json.loads(handle.attrs["meta_scene"])
            saved["domain"]["h"] = scene.domain.median_edge
            handle.attrs["meta_scene"] = json.dumps(saved)
        assert main(["run", str(tmp_path / "run" / "scene.toml"), "-o", str(tmp_path / "run"), "--resume", "-q",
                     "--set", "phases.0.duration=3.0"]) == 0


def test_resuming_on_an_edited_mesh_file_names_the_file(tmp_path, capsys):
    # the refusal named '--resume' and the checkpoint's mesh_checksum, not the file
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import structured_channel

    write_domain(tmp_path / "channel.vtu", *structured_channel(20.0, 20.0, 1.0))
    table = {"domain": {"kind": "mesh", "mesh": "channel.vtu"}, "particles": {"layout": "single"},
             "phases": [{"duration": 2.0, "dt": 1.0, "frame_interval": 1.0}]}
    path = write_scene(tmp_path / "scene.toml", table)
    assert main(["run", str(path), "-o", str(tmp_path / "run"), "-q"]) == 0
    write_domain(tmp_path / "channel.vtu", *structured_channel(20.0, 20.0, 0.5))
    capsys.readouterr()
    assert main(["run", str(path), "-o", str(tmp_path / "run"), "-q", "--resume",
                 "--set", "phases.0.duration=3.0"]) == 2
    message = capsys.readouterr().err
    assert "scene key 'domain.mesh'" in message and "channel.vtu" in message
    assert "the file's content differs: mesh_checksum" in message


def test_a_layout_off_the_fluid_names_the_layout_and_a_cut_disc_is_warned(tmp_path):
    # the hexagonal layout's centre in an obstacle was refused as 'particles.centres' (never
    # set) "y between the walls" (it was); its discs over an obstacle started cut, silently
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing
    from femphase.errors import ModelWarning

    write_domain(tmp_path / "c.vtu", *delaunay_channel(40.0, edge_for_spacing(1.0), lambda x: 0 * x,
                                                      lambda x: 0 * x + 40.0, obstacles=[(25.0, 10.0, 3.0)], seed=1))
    table = {"domain": {"kind": "mesh", "mesh": "c.vtu"}, "particles": {"layout": "hexagonal", "N": 4, "per_row": 2},
             "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0}]}
    centres = hexagonal_centres(4, 40.0, 40.0, 2)
    assert np.hypot(*(centres - [25.0, 10.0]).T).min() < 1e-9  # one centre in the obstacle
    with pytest.raises(SceneError, match=r"the hexagonal layout puts 1 of its centres outside, e\.g\. \(25, 10\)") as info:
        scene_from_dict(table, tmp_path)
    assert info.value.key == "particles.layout" and "not in an obstacle" in str(info.value)
    table["domain"]["mesh"] = "d.vtu"
    write_domain(tmp_path / "d.vtu", *delaunay_channel(40.0, edge_for_spacing(1.0), lambda x: 0 * x,
                                                      lambda x: 0 * x + 40.0, obstacles=[(25.0, 15.0, 2.5)], seed=1))
    with pytest.warns(ModelWarning, match=r"starts 1 of 4 particles cut by a wall or obstacle, e\.g\. particle 1 at "
                                          r"\(25, 10\), whose initial disc of radius 4 has a wall node 2\.[5-7]"):
        scene_from_dict(table, tmp_path)  # the obstacle's edge is 2.5 from (25, 10)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene_from_dict({**table, "domain": {"kind": "grid", "Lx": 40.0, "Ly": 40.0}})


def test_numerics_of_the_structured_channel_are_refused_on_a_mesh(tmp_path):
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import structured_channel
    from femphase.scene import check_numerics

    write_domain(tmp_path / "channel.vtu", *structured_channel(20.0, 20.0, 1.0))
    table = {"domain": {"kind": "mesh", "mesh": "channel.vtu"}, "particles": {"layout": "single"},
             "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0}]}
    with pytest.raises(SceneError, match=r'"right" \(the default\) on a mesh') as info:
        check_numerics(scene_from_dict({**table, "numerics": {"diagonals": "left"}}, tmp_path))
    assert info.value.key == "numerics.diagonals"
    with pytest.raises(SceneError, match=r'"auto", "direct", "amg" or "batched": the tensor solver needs'):
        check_numerics(scene_from_dict({**table, "numerics": {"solver": "tensor"}}, tmp_path))


def test_a_periodic_pair_in_the_wrong_order_or_of_walls_names_the_pair(tmp_path):
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import structured_channel

    write_domain(tmp_path / "channel.vtu", *structured_channel(20.0, 10.0, 1.0))
    table = {"domain": {"kind": "mesh", "mesh": "channel.vtu"},
             "particles": {"layout": "single", "initial_radius": 2.0}, "model": {"R": 3.0},
             "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0}]}
    for pair, reason in ((["right", "left"], "'left' \\(at x = 0\\) must lie at larger x than 'right'"),
                         (["bottom", "top"], "'bottom' is not a straight side x = const")):
        with pytest.raises(SceneError, match=reason) as info:
            scene_from_dict({**table, "domain": {**table["domain"], "periodic": pair}}, tmp_path)
        assert info.value.key == "domain.periodic"


def test_resume_of_a_mesh_run_continues_to_the_same_rows_as_an_uninterrupted_run(tmp_path):
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing
    from femphase.run.directory import RunDirectory

    # a Delaunay channel, relaxed then driven by a Stokes flow, with the T1 counter running
    mesh, boundaries = delaunay_channel(36.0, edge_for_spacing(1.0), lambda x: 0 * x, lambda x: 0 * x + 24.0, seed=3)
    write_domain(tmp_path / "channel.vtu", mesh, boundaries)
    data = {
        "name": "mesh resume",
        "domain": {"kind": "mesh", "mesh": "channel.vtu", "h": 1.0},
        "particles": {"layout": "hexagonal", "N": 6, "per_row": 3},
        "output": {"fields": True, "observables": ["shape", "order"]},
        "phases": [
            {"name": "relax", "duration": 10.0, "dt": 1.0, "frame_interval": 5.0},
            {"name": "flow", "duration": 20.0, "dt": 1.0, "frame_interval": 5.0,
             "flow": {"type": "stokes", "max_velocity": 0.5}},
        ],
    }
    path = write_scene(tmp_path / "scene.toml", data)
    assert main(["run", str(path), "-o", str(tmp_path / "straight"), "-q"]) == 0
    scene = load_scene(path)
    cut = tmp_path / "cut"
    with pytest.raises(KeyboardInterrupt):
        Simulation(scene).run(scene.initial_state(), [RunDirectory(cut), StopAt(18)])
    assert json.loads((cut / "run.json").read_text())["status"] == "interrupted"
    assert load_checkpoint(cut / CHECKPOINT, scene.domain)[0].step == 15  # last frame, in the flow phase
    assert main(["run", str(path), "-o", str(cut), "--resume", "-q"]) == 0
    info = json.loads((cut / "run.json").read_text())
    segment = info["segments"][-1]
    assert len(info["segments"]) == 2 and segment["resumed"] and segment["from_step"] == 15  # continued from 15
    assert info["steps"] == 30 and info["steps_this_segment"] == 15
    # bitwise: the checkpoint holds the complete state, and the resumed run steps it exactly
    # as the uninterrupted one did (CSVs hold floats by repr)
    for name in ("particles.csv", "global.csv"):
        straight, resumed = (tmp_path / "straight" / name).read_text(), (cut / name).read_text()
        assert len(resumed.splitlines()) == len(straight.splitlines()) == 1 + (7 if name == "global.csv" else 42)
        assert resumed == straight, name
    assert read_csv(cut / "global.csv")["time"][-1] == 30.0
    a, _ = load_checkpoint(tmp_path / "straight" / CHECKPOINT, scene.domain)
    b, _ = load_checkpoint(cut / CHECKPOINT, scene.domain)
    assert b.step == a.step == 30 and b.windows == a.windows
    assert np.array_equal(b.global_fields(), a.global_fields())


@pytest.mark.parametrize("command", ["run", "ode", "compare", "plot", "sweep", "converge"])
def test_an_empty_output_directory_is_refused_before_anything_is_written(tmp_path, monkeypatch, capsys, command):
    """-o "" (an unset shell variable) would otherwise become "." and fill the working
    directory (with --overwrite, replace a run there)."""
    scene = Path(__file__).resolve().parents[1] / "examples" / "single.toml"
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'[sweep]\nscene = "{scene}"\n[axes]\n"model.mu" = [10.0, 20.0]\n')
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    argv = {"run": ["run", str(scene)], "ode": ["ode", "--rate", "0.1"], "compare": ["compare", "a", "b"],
            "plot": ["plot", "a"], "sweep": ["sweep", str(sweep)], "converge": ["converge", str(scene), "--h", "1,0.5"]}
    assert main([*argv[command], "-o", ""]) == 2
    assert "option '-o' = '' is invalid: a directory path (it is empty)" in capsys.readouterr().err
    assert not any(work.iterdir())


def test_a_flow_through_the_walls_or_across_the_seam_warns_on_loading(tmp_path, monkeypatch):
    """The walls take no boundary condition in the advection, so a flow through them carries
    φ out; a flow that is not periodic jumps at the seam. Built-in row flows on flat walls
    are neither; on an obstacle's wall they cross."""
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing
    from femphase.errors import FlowWarning

    (tmp_path / "userflows.py").write_text(
        "import numpy as np\n"
        "def upward(x, y):\n    return 0 * x, 0.1 + 0 * y\n"
        "def stretching(x, y):\n    return 0.01 * x, 0 * y\n"
        "def along(x, y):\n    return 0.1 * np.sin(2 * np.pi * x / 30) * y * (30 - y) / 225, 0 * y\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    write_domain(tmp_path / "obstacle.vtu", *delaunay_channel(30.0, edge_for_spacing(1.0), lambda x: 0 * x,
                                                             lambda x: 0 * x + 30.0, obstacles=[(15.0, 15.0, 3.0)],
                                                             seed=1))

    def caught(flow: dict, domain: dict | None = None) -> list[str]:
        data = {**SMALL, "domain": domain or SMALL["domain"],
                "phases": [SMALL["phases"][0], {**SMALL["phases"][1], "flow": flow}]}
        if domain:
            data["particles"] = {"layout": "list", "centres": [[5.0, 8.0], [25.0, 22.0]], "initial_radius": 3.0}
        with warnings.catch_warnings(record=True) as records:
            warnings.simplefilter("always")
            scene_from_dict(data, tmp_path)
        return [str(w.message) for w in records if issubclass(w.category, FlowWarning)]

    upward = caught({"type": "python", "function": "userflows:upward"})
    assert len(upward) == 1 and upward[0].startswith("phases.1.flow crosses the walls: its normal velocity "
                                                     "reaches 0.1 (its largest speed is 0.1)")
    stretching = caught({"type": "python", "function": "userflows:stretching"})
    assert len(stretching) == 1 and "is not periodic in x: v(x + 30, y) − v(x, y) reaches 0.3" in stretching[0]
    assert caught({"type": "python", "function": "userflows:along"}) == []
    for flow in ({"type": "shear", "rate": 0.5}, {"type": "poiseuille", "rate": 0.5},
                 {"type": "oscillating_shear", "rate": 0.5, "frequency": 0.1}):
        assert caught(flow) == []
        assert len(caught(flow, {"kind": "mesh", "mesh": "obstacle.vtu"})) == 1


def test_a_python_flow_that_fails_during_the_run_stops_it_naming_the_function_time_and_step(tmp_path, monkeypatch,
                                                                                             capsys):
    # the user's code, not femphase's: exit 3 with the function, the time and the last step
    # done, and the checkpoint of that step kept (it was "internal error … this is a bug")
    (tmp_path / "lateflows.py").write_text(
        "import numpy as np\n"
        "def late_nan(x, y, t):\n    return (np.nan if t > 32 else 0.01) + 0 * x, 0 * y\n"
        "def late_raise(x, y, t):\n    if t > 32:\n        raise RuntimeError('no data past t = 32')\n"
        "    return 0.01 + 0 * x, 0 * y\n"
        "def raise_on_many_points(x, y):\n    if x.size > 100:\n        raise RuntimeError('too many')\n"
        "    return 0 * x, 0 * y\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name, reason in (("late_nan", "it returned NaN or inf"), ("late_raise", "it raised RuntimeError: no data")):
        flow = {"type": "python", "function": f"lateflows:{name}", "steady": False}
        scene = write_scene(tmp_path / f"{name}.toml", {**SMALL, "phases": [SMALL["phases"][0],
                                                                           {**SMALL["phases"][1], "flow": flow}]})
        run = tmp_path / name
        assert main(["run", str(scene), "-o", str(run), "-q"]) == 3
        message = capsys.readouterr().err
        # t: where the scheme first asked for the flow past 32; step 30: the last step done (the
        # adaptive scheme runs the steps to the next frame in one call)
        found = re.search(rf"the flow function lateflows:{name} failed at t = ([0-9.]+), after step 30: {reason}",
                          message)
        assert found and 32 < float(found.group(1)) <= 35
        assert "this is a bug" not in message
        status = json.loads((run / "run.json").read_text())
        assert status["status"] == "failed" and status["time"] == 30.0  # the last frame's checkpoint
    # failing on the points of the loading checks: a bad scene key, nothing run
    flow = {"type": "python", "function": "lateflows:raise_on_many_points"}
    scene = write_scene(tmp_path / "many.toml", {**SMALL, "phases": [SMALL["phases"][0],
                                                                    {**SMALL["phases"][1], "flow": flow}]})
    assert main(["run", str(scene), "-o", str(tmp_path / "many"), "-q"]) == 2
    assert "'phases.1.flow.function' = 'lateflows:raise_on_many_points' is invalid" in capsys.readouterr().err
    assert not (tmp_path / "many").exists()


def test_the_fd_method_is_recorded_as_the_scheme_it_runs_and_says_so(tmp_path, capsys):
    # --method fd runs "fd-heun" whatever numerics.scheme says: scene.toml and run.json said
    # "adaptive" (or the "euler" the scene set, which did not run, without a word)
    phases = [{"name": "relax", "duration": 1.0, "dt": 0.1, "frame_interval": 0.5}]
    scene = write_scene(tmp_path / "fd.toml", {**SMALL, "phases": phases})
    assert main(["run", str(scene), "-o", str(tmp_path / "fd"), "-q", "--method", "fd"]) == 0
    resolved = load_scene(tmp_path / "fd" / "scene.toml")  # loads: its N is the list's two centres, not 100
    assert resolved.numerics.scheme == "fd-heun" and resolved.particles.N == 2
    assert json.loads((tmp_path / "fd" / "run.json").read_text())["settings"]["numerics"]["scheme"] == "fd-heun"
    assert main(["run", str(scene), "-o", str(tmp_path / "fd"), "-q", "--method", "fd", "--resume",
                 "--set", "phases.0.duration=2.0"]) == 0  # the recorded scheme is the one it resumes with
    capsys.readouterr()
    assert main(["run", str(scene), "-o", str(tmp_path / "euler"), "-q", "--method", "fd",
                 "--set", 'numerics.scheme="euler"']) == 0  # the same scene, cross-checked: said, and recorded
    assert "numerics.scheme = 'euler' is not used: --method fd runs the scheme 'fd-heun'" in capsys.readouterr().err
    assert load_scene(tmp_path / "euler" / "scene.toml").numerics.scheme == "fd-heun"


def test_the_fd_method_judges_the_time_mass_as_its_own(tmp_path, capsys):
    # the scene's scheme was checked instead: the consistent mass was refused with advice to
    # set numerics.scheme = "euler", which --method fd overrides
    phases = [{"name": "relax", "duration": 1.0, "dt": 0.1, "frame_interval": 0.5}]
    scene = write_scene(tmp_path / "fd.toml", {**SMALL, "numerics": {"mass": "consistent"}, "phases": phases})
    assert main(["run", str(scene), "-o", str(tmp_path / "fd"), "-q", "--method", "fd"]) == 2
    message = capsys.readouterr().err
    assert "'numerics.mass' = 'consistent'" in message and '"lumped" with --method fd' in message
    assert "euler" not in message and not (tmp_path / "fd").exists()


def test_a_resume_with_another_method_names_the_method_first(tmp_path, capsys):
    # the FD reference's dt limit was named first, and the changed method only after the
    # user had lowered dt for it
    phases = [{"name": "relax", "duration": 2.0, "dt": 1.0, "frame_interval": 1.0}]
    scene = write_scene(tmp_path / "fem.toml", {**SMALL, "phases": phases})
    assert main(["run", str(scene), "-o", str(tmp_path / "run"), "-q"]) == 0
    capsys.readouterr()
    assert main(["run", str(scene), "-o", str(tmp_path / "run"), "-q", "--resume", "--method", "fd",
                 "--set", "phases.0.duration=3.0"]) == 2
    assert "option '--method' = 'fd' is invalid: 'fem', the method the run was started with" in capsys.readouterr().err


def test_a_stabilisation_the_scheme_does_not_read_is_warned_about(tmp_path):
    # sav2 ran the same with and without it, and the blow-up advice recommended it
    from femphase.errors import ModelWarning

    path = write_scene(tmp_path / "scene.toml")
    with pytest.warns(ModelWarning, match=r"numerics.stabilisation = 5 is not used: .* numerics.scheme = 'sav2'"):
        load_scene(path, ["numerics.scheme=sav2", "numerics.stabilisation=5"])
    with warnings.catch_warnings(record=True) as records:
        warnings.simplefilter("always")
        load_scene(path, ["numerics.scheme=euler", "numerics.stabilisation=5"])
    assert not [w for w in records if "is not used" in str(w.message)]


def test_sav2_past_the_area_modes_step_bound_is_warned_about(tmp_path):
    # sav2 has no area-mode ceiling: examples/single.toml blew up at dt = 5 and ended 31 %
    # off in area at dt = 10, without a word; dt = 2.5 is below the bound 1.5/c ≈ 3.77
    from femphase.errors import StiffnessWarning

    path = write_scene(tmp_path / "scene.toml")
    with pytest.warns(StiffnessWarning, match=r'"sav2" at phases.0.dt = 5 steps past 1.5/c = 3.77'):
        load_scene(path, ["numerics.scheme=sav2", "phases.0.dt=5.0", "phases.0.frame_interval=5.0"])
    with warnings.catch_warnings(record=True) as records:
        warnings.simplefilter("always")
        load_scene(path, ["numerics.scheme=sav2", "phases.0.dt=2.5", "phases.0.frame_interval=5.0"])
    assert not [w for w in records if issubclass(w.category, StiffnessWarning)]


def test_a_grid_given_a_mesh_of_other_nodes_names_the_file(tmp_path):
    # the value named was "30824 nodes off the lattice", not the file
    mesh = Path(__file__).parents[1] / "meshes" / "obstacle.vtu"
    with pytest.raises(SceneError, match=r"'domain.mesh' = '.*obstacle.vtu' is invalid: .*nodes off the lattice; "
                                         r'a mesh of other nodes is a domain of kind "mesh"'):
        load_scene(write_scene(tmp_path / "scene.toml"), [f'domain.mesh="{mesh}"'])


def test_extensions_reach_the_command_line_and_its_workers(tmp_path, monkeypatch, capsys):
    # a flow or observable registered in the user's module could not be used by any command:
    # 'output.observables' = 'top' is invalid: one of ('shape', 'energy', 'order')
    from femphase.analysis.observables import OBSERVABLES
    from femphase.flows import FLOWS
    from femphase.registry import EXTENSIONS_VARIABLE

    module = "femphase_test_extension"
    (tmp_path / f"{module}.py").write_text(
        "import numpy as np\n"
        "from femphase.analysis.observables import OBSERVABLES, Observable\n"
        "from femphase.flows import FLOWS, number, row_flow\n\n\n"
        "@FLOWS.register('test_plug')\n"
        "def plug(spec, domain):\n"
        "    velocity = number(spec, 'velocity', 'U')\n"
        "    return row_flow('test_plug', lambda y, t: velocity)\n\n\n"
        "@OBSERVABLES.register('test_top')\n"
        "class Top(Observable):\n"
        "    name = 'test_top'\n"
        "    particle_columns = ('phi_top',)\n\n"
        "    def __call__(self, state, values):\n"
        "        return {'phi_top': np.array([float(f.max()) for f in state.fields])}\n")
    table = {"domain": {"Lx": 40.0, "Ly": 40.0}, "particles": {"layout": "single"},
             "output": {"observables": ["shape", "test_top"]},
             "phases": [{"duration": 4.0, "dt": 1.0, "frame_interval": 2.0,
                         "flow": {"type": "test_plug", "velocity": 0.5}}]}
    path = write_scene(tmp_path / "scene.toml", table)
    monkeypatch.chdir(tmp_path)  # the module is in the working directory, not on sys.path
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(tmp_path))])
    monkeypatch.setenv(EXTENSIONS_VARIABLE, "")  # restored (unset) after the test, whatever main sets
    try:
        assert main(["run", str(path), "-o", "plain", "-q"]) == 2
        assert "femphase --import MODULE" in capsys.readouterr().err
        assert main(["--import", module, "run", str(path), "-o", "run", "-q"]) == 0
        assert "phi_top" in (tmp_path / "run" / "particles.csv").read_text().splitlines()[0]
        assert main(["run", str(path), "-o", "run", "-q", "--resume", "--set", "phases.0.duration=6.0"]) == 0
        assert main(["plot", "run"]) == 0  # the environment carries the module on
        assert main(["--import", "no_such_femphase_module", "run", str(path), "-o", "other", "-q"]) == 2
        assert "option '--import' = 'no_such_femphase_module' is invalid" in capsys.readouterr().err
    finally:
        OBSERVABLES.unregister("test_top")
        FLOWS.unregister("test_plug")
        sys.modules.pop(module, None)


def test_a_threshold_near_zero_places_its_discs(tmp_path):
    # below 1.1e-16, 1 − 2·threshold rounds to 1 and the initial window's reach came out as
    # arctanh(1) = inf: "internal error (OverflowError …)" for a value in the valid range
    for threshold in (1e-17, 1e-300):
        scene = scene_from_dict({**SMALL, "numerics": {"threshold": threshold}})
        state = scene.initial_state()
        assert all(np.isfinite(field).all() for field in state.fields)


def test_a_flow_that_moves_the_fields_beyond_their_digits_is_refused():
    # a shear rate of 1e200 ran to its end (exit 0) with overflowing squares, an elongation
    # of 40 and the advice "set phases.1.dt ≤ 0"
    flow = {"type": "shear", "rate": 1e200}
    phases = [{**SMALL["phases"][0]}, {**SMALL["phases"][1], "flow": flow}]
    with pytest.raises(SceneError) as refused:
        scene_from_dict({**SMALL, "phases": phases})
    assert refused.value.key == "phases.1.flow" and "one step of dt = 1 moves them 1e+200" in str(refused.value)
    scene_from_dict({**SMALL, "phases": [phases[0], {**phases[1], "flow": {"type": "shear", "rate": 1e5}}]})


def test_top_level_options_name_what_the_user_gave(tmp_path, capsys, monkeypatch):
    # FEMPHASE_IMPORT's module was refused as the option --import, which was not given;
    # --import "" was accepted without a word; --traceback, which internal errors ask for,
    # was refused after the command ("unrecognized arguments")
    monkeypatch.setenv("FEMPHASE_IMPORT", "femphase_no_such_module")
    scene = write_scene(tmp_path / "s.toml")
    assert main(["run", str(scene), "-o", str(tmp_path / "r"), "-q"]) == 2
    assert "the environment variable FEMPHASE_IMPORT = 'femphase_no_such_module'" in capsys.readouterr().err
    monkeypatch.delenv("FEMPHASE_IMPORT")
    assert main(["--import", " ", "run", str(scene), "-o", str(tmp_path / "r"), "-q"]) == 2
    assert "option '--import' = ' ' is invalid: the name of a module to import (it is empty)" in capsys.readouterr().err
    assert main(["run", str(scene), "-o", str(tmp_path / "r"), "-q"]) == 0
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "r"), str(tmp_path / "none.npz"), "--traceback"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and "none.npz' is neither a run directory nor a grid data file (it does not exist)" in err
