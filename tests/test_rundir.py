"""Run directories: refusals, compatible and incompatible resumes, bad paths.

Every refusal is checked to leave the directory byte for byte as it was."""

import errno
import json
import os
from pathlib import Path

import pytest

from femphase.cli import main
from femphase.errors import SceneError
from femphase.io.files import FileLock, read_csv
from femphase.io.rundir import LOCK, resume_position

SCENE = """
name = "tiny"
[domain]
Lx = 30.0
Ly = 30.0
[particles]
layout = "list"
centres = [[10.0, 15.0], [21.0, 15.0]]
[[phases]]
name = "relax"
duration = 20.0
dt = 1.0
frame_interval = 5.0
[[phases]]
name = "shear"
duration = 20.0
dt = 1.0
frame_interval = 5.0
flow = { type = "shear", rate = 0.3 }
"""


@pytest.fixture
def scene(tmp_path) -> Path:
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    return path


def _snapshot(directory: Path) -> dict:
    return {p.relative_to(directory): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def _run(scene, directory, *flags) -> int:
    return main(["run", str(scene), "-o", str(directory), "-q", *flags])


def test_an_existing_run_is_refused_without_resume_or_overwrite(scene, tmp_path, capsys):
    run = tmp_path / "run"
    assert _run(scene, run) == 0
    (run / "notes.txt").write_text("mine")
    before = _snapshot(run)
    capsys.readouterr()
    assert _run(scene, run) == 2
    message = capsys.readouterr().err
    assert "'-o'" in message and "--resume" in message and "--overwrite" in message and "Traceback" not in message
    assert _snapshot(run) == before
    assert _run(scene, run, "--overwrite", "--set", "phases.1.duration=10") == 0
    assert (run / "notes.txt").read_text() == "mine"  # only femphase's files are replaced
    assert read_csv(run / "global.csv")["time"][-1] == 30.0



def test_a_directory_another_process_runs_in_is_refused_and_left_alone(scene, tmp_path, capsys):
    # two resumes of one run appended every frame twice; an overwrite deleted the running
    # run's files. The holder here is a second open file description of the lock, which
    # flock treats as another process would be treated.
    run = tmp_path / "run"
    assert _run(scene, run) == 0
    holder = FileLock(run / LOCK)
    assert holder.acquire(blocking=False)
    before = _snapshot(run)
    try:
        for flags in (["--resume", "--set", "phases.1.duration=40"], ["--overwrite"]):
            capsys.readouterr()
            assert _run(scene, run, *flags) == 2
            message = capsys.readouterr().err
            assert "no other femphase process" in message and f"pid {os.getpid()}" in message
            assert _snapshot(run) == before
    finally:
        holder.release()
    assert _run(scene, run, "--resume", "--set", "phases.1.duration=40") == 0
    assert read_csv(run / "global.csv")["time"].max() == 60.0

@pytest.mark.parametrize("code, runs", [(errno.ENOLCK, True), (errno.EIO, False)])
def test_a_filesystem_without_locks_runs_with_a_warning_and_other_lock_errors_stop(scene, tmp_path, capsys,
                                                                                  monkeypatch, code, runs):
    # NFS without its lock daemon raises ENOLCK from flock: refusing there would stop every run
    def flock(handle, operation):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr("femphase.io.files.fcntl.flock", flock)
    run = tmp_path / "run"
    if runs:
        assert _run(scene, run) == 0
        assert "filesystem without locks" in capsys.readouterr().err
        assert json.loads((run / "run.json").read_text())["status"] == "completed"
    else:
        assert _run(scene, run) == 2
        message = capsys.readouterr().err
        assert "a directory femphase can lock (Input/output error)" in message and "bug" not in message


@pytest.mark.parametrize("target", ["file", "/proc/femphase-cannot-write-here"])
def test_an_unusable_output_path_is_one_clear_message(scene, tmp_path, capsys, target):
    path = tmp_path / "a-file" if target == "file" else Path(target)
    if target == "file":
        path.write_text("not a directory")
    assert _run(scene, path) == 2
    message = capsys.readouterr().err
    assert "'-o'" in message and "Traceback" not in message


@pytest.mark.parametrize("assignment, key", [
    ("model.mu=10", "model.area_stiffness (model.mu)"),  # the spelling typed, too
    ("domain.h=0.5", "domain.h"),
    ("domain.Lx=40", "domain.Lx"),
    ("particles.centres=[[10.0, 15.0], [21.0, 15.0], [15.0, 5.0]]", "particles.centres"),
    ("output.observables=[\"order\"]", "output.observables"),
    ("phases.0.duration=10", "phases.0.duration"),
    ("phases.1.duration=5", "phases.1.duration"),  # shorter than the 10 it has run
    ("phases.0.flow={type = \"shear\", rate = 0.1}", "phases.0.flow"),
])
def test_resume_refuses_incompatible_changes_naming_the_key(scene, tmp_path, capsys, assignment, key):
    run = tmp_path / "run"
    assert _run(scene, run, "--set", "phases.1.duration=10") == 0
    before = _snapshot(run)
    capsys.readouterr()
    assert _run(scene, run, "--resume", "--set", assignment) == 2
    message = capsys.readouterr().err
    assert f"'{key}'" in message and "Traceback" not in message, message
    assert _snapshot(run) == before


def test_the_phase_under_way_may_end_later_or_sooner_but_not_before_the_checkpoint():
    phase = {"dt": 10.0, "frame_interval": 10.0}
    saved = {"phases": [{**phase, "duration": 100.0}, {**phase, "duration": 100.0}]}

    def resumed(duration):
        return resume_position(saved, {"phases": [saved["phases"][0], {**phase, "duration": duration}]}, 150.0)

    assert resumed(60.0)[:2] == (1, 5) and resumed(50.0)[:2] == (2, 0)
    with pytest.raises(SceneError, match="at least 50: phase 1 has already run 50 time units"):
        resumed(40.0)
    # shortened with another frame interval: the shortening is the error to name (it said
    # the phase "ran with it until t = 200", to its old end, beyond the checkpoint)
    with pytest.raises(SceneError, match="phases.1.duration.*a run is not shortened"):
        resume_position(saved, {"phases": [saved["phases"][0], {**phase, "duration": 30.0, "frame_interval": 30.0}]},
                        150.0)


def test_a_resume_records_renamed_scenes_and_phases_among_its_changes():
    # run.json's changes listed nothing for a renamed scene, whose console line used the new name
    phase = {"name": "shear", "dt": 10.0, "frame_interval": 10.0, "duration": 100.0}
    saved = {"name": "a", "phases": [phase]}
    changes = resume_position(saved, {"name": "b", "phases": [{**phase, "name": "sheared"}]}, 50.0)[2]
    assert changes == ["name: 'a' → 'b'", "phases.0.name: 'shear' → 'sheared'"]


def _refused_resume(scene: Path, run: Path, capsys, assignment: str) -> str:
    """The error of resuming with phases.1.duration=20 a run started with ``assignment``."""
    assert _run(scene, run, "--set", "phases.1.duration=10", "--set", assignment) == 0
    capsys.readouterr()
    assert _run(scene, run, "--resume", "--set", "phases.1.duration=20") == 2
    return capsys.readouterr().err


def test_a_refused_resume_points_to_the_runs_earlier_assignments(scene, tmp_path, capsys):
    # the README's "--resume --set phases.1.duration=…" is refused after a run started with
    # other --set values, and the message did not say where they are
    error = _refused_resume(scene, tmp_path / "run", capsys, "phases.0.frame_interval=10")
    assert "the run's earlier ones are in its run.json (each segment's \"set\")" in error


def test_a_run_without_checkpoints_cannot_resume_and_is_told_why(scene, tmp_path, capsys):
    error = _refused_resume(scene, tmp_path / "run", capsys, "output.checkpoint=false")
    assert "written with output.checkpoint = false, so it cannot be continued" in error
    assert _run(scene, tmp_path / "new", "--resume") == 2
    assert "holds checkpoint.h5 (it does not exist: start the run without --resume)" in capsys.readouterr().err


def test_the_steps_of_a_phase_that_will_not_run_again_cannot_change():
    """A done phase's dt or frame interval changed on resume would make scene.toml describe
    steps the run never took; the phase under way, or one extended, may change them."""
    phase = {"dt": 10.0, "frame_interval": 10.0, "duration": 100.0}
    saved = {"phases": [phase, phase]}
    for k, key, time in ((0, "dt", 150.0), (0, "frame_interval", 150.0), (1, "dt", 200.0)):
        phases = [dict(phase), dict(phase)]
        phases[k][key] = 5.0
        with pytest.raises(SceneError, match=f"10 as in the checkpoint: phase {k} ran with it until t = "):
            resume_position(saved, {"phases": phases}, time)
    assert resume_position(saved, {"phases": [phase, {**phase, "dt": 5.0}]}, 150.0)[:2] == (1, 10)
    assert resume_position(saved, {"phases": [phase, {**phase, "dt": 5.0, "duration": 150.0}]}, 200.0)[:2] == (1, 20)


def test_a_resume_over_an_unreadable_run_json_warns_and_writes_a_new_one(scene, tmp_path, capsys):
    run = tmp_path / "run"
    assert _run(scene, run, "--set", "phases.1.duration=10") == 0
    (run / "run.json").write_text("not json")
    assert _run(scene, run, "--resume", "--set", "phases.1.duration=20") == 0
    assert "run.json is missing or not JSON" in capsys.readouterr().err
    status = json.loads((run / "run.json").read_text())
    assert status["status"] == "completed" and [s["resumed"] for s in status["segments"]] == [True]


def test_extending_a_finished_run_equals_running_it_longer_at_once(scene, tmp_path):
    straight, extended = tmp_path / "straight", tmp_path / "extended"
    assert _run(scene, straight, "--set", "phases.1.duration=30") == 0
    assert _run(scene, extended) == 0
    assert _run(scene, extended, "--resume", "--set", "phases.1.duration=30") == 0
    for name in ("particles.csv", "global.csv", "fields.xdmf"):
        assert (straight / name).read_bytes() == (extended / name).read_bytes(), name
    segments = json.loads((extended / "run.json").read_text())["segments"]
    assert len(segments) == 2 and segments[1]["from_time"] == 40.0
    assert "phases.1.duration: 20.0 → 30.0" in segments[1]["changes"]


def test_a_new_dt_in_the_phase_under_way_ends_the_phase_on_time(scene, tmp_path):
    run = tmp_path / "run"
    assert _run(scene, run, "--set", "phases.1.duration=10") == 0  # stopped at t = 30, in phase 1
    assert _run(scene, run, "--resume", "--set", "phases.1.dt=0.5") == 0
    times = read_csv(run / "global.csv")["time"]
    assert times[-1] == 40.0
    assert list(times) == [5.0 * k for k in range(9)]  # frames stay on the 5-unit grid
    assert "phases.1.dt: 1.0 → 0.5" in json.loads((run / "run.json").read_text())["segments"][1]["changes"]


def test_a_dt_that_does_not_divide_the_time_spent_is_refused(scene, tmp_path, capsys):
    run = tmp_path / "run"
    assert _run(scene, run, "--set", "phases.1.duration=7") == 0
    capsys.readouterr()
    assert _run(scene, run, "--resume", "--set", "phases.1.dt=2.0", "--set", "phases.1.frame_interval=10") == 2
    assert "'phases.1.dt'" in capsys.readouterr().err


def test_a_truncated_checkpoint_is_one_message_and_nothing_is_touched(scene, tmp_path, capsys):
    run = tmp_path / "run"
    assert _run(scene, run) == 0
    checkpoint = run / "checkpoint.h5"
    checkpoint.write_bytes(checkpoint.read_bytes()[:500])
    before = _snapshot(run)
    capsys.readouterr()
    assert _run(scene, run, "--resume") == 2
    message = capsys.readouterr().err
    assert "'--resume'" in message and "Traceback" not in message
    assert _snapshot(run) == before


def test_resume_needs_a_checkpoint(scene, tmp_path, capsys):
    assert _run(scene, tmp_path / "empty", "--resume") == 2
    assert "checkpoint.h5" in capsys.readouterr().err


MESH_SCENE = """
name = "tiny mesh"
[domain]
kind = "mesh"
mesh = "a/c.vtu"
[particles]
layout = "list"
centres = [[10.0, 10.0]]
initial_radius = 5.0
[[phases]]
name = "relax"
duration = 20.0
dt = 2.0
frame_interval = 10.0
"""


def _channel_mesh(path: Path, seed: int) -> None:
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing

    path.parent.mkdir(parents=True, exist_ok=True)
    write_domain(path, *delaunay_channel(20.0, edge_for_spacing(1.0), lambda x: 0.0 * x, lambda x: 0.0 * x + 20.0,
                                         seed=seed))


def _renumbered(source: Path, target: Path) -> None:
    """``source``'s mesh with its nodes in reverse order (cells and tagged facets renumbered)."""
    import meshio
    import numpy as np

    mesh = meshio.read(source)
    order = np.arange(len(mesh.points))[::-1]
    new_index = np.empty_like(order)
    new_index[order] = np.arange(order.size)
    cells = [meshio.CellBlock(block.type, new_index[block.data]) for block in mesh.cells]
    target.parent.mkdir(parents=True, exist_ok=True)
    meshio.write(target, meshio.Mesh(mesh.points[order], cells, cell_data=mesh.cell_data))


def test_a_moved_mesh_file_resumes_and_another_mesh_is_refused(tmp_path, capsys):
    # the mesh's path may change on resume (a run directory or sweep moved); its content may
    # not: the checkpoint's mesh checksum refuses another mesh
    scene = tmp_path / "scene.toml"
    scene.write_text(MESH_SCENE)
    _channel_mesh(tmp_path / "a" / "c.vtu", seed=1)
    run = tmp_path / "run"
    assert _run(scene, run, "--set", "phases.0.duration=10") == 0
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "c.vtu").write_bytes((tmp_path / "a" / "c.vtu").read_bytes())
    (tmp_path / "a" / "c.vtu").unlink()
    _renumbered(tmp_path / "b" / "c.vtu", tmp_path / "other" / "c.vtu")  # the same h, Lx, Ly: only the checksum differs
    before = _snapshot(run)
    capsys.readouterr()
    assert _run(scene, run, "--resume", "--set", "domain.mesh=\"other/c.vtu\"") == 2
    message = capsys.readouterr().err
    assert "mesh_checksum" in message and "Traceback" not in message, message
    assert _snapshot(run) == before
    assert _run(scene, run, "--resume", "--set", "domain.mesh=\"b/c.vtu\"") == 0
    assert read_csv(run / "global.csv")["time"][-1] == 20.0
    changes = json.loads((run / "run.json").read_text())["segments"][1]["changes"]
    assert any(change.startswith("domain.mesh: ") and change.endswith("b/c.vtu'") for change in changes), changes


def test_a_resume_that_changes_numerics_says_so_on_the_console_and_in_the_log(scene, tmp_path, capsys):
    # a resume takes the scene and --set given now: an earlier --set of numerics not given
    # again was dropped, recorded only in run.json's segment
    run = tmp_path / "run"
    assert _run(scene, run, "--set", "numerics.tolerance_t=0.01") == 0
    capsys.readouterr()
    assert _run(scene, run, "--resume", "--set", "phases.1.duration=40") == 0
    warning = "resumed with numerics other than the checkpoint's: numerics.tolerance_t: 0.01 → 0.1"
    assert warning in capsys.readouterr().err
    log = (run / "run.log").read_text()
    assert warning in log and "resumed with changes: phases.1.duration: 20.0 → 40.0" in log


def test_overwrite_deletes_the_replaced_runs_figures_and_comparisons_but_not_other_files(scene, tmp_path):
    # figures/ and compare/ (plot's and compare's default outputs) described the old run
    run = tmp_path / "run"
    assert _run(scene, run) == 0
    for name in ("figures/elongation.png", "compare/compare.csv", "notes.txt"):
        (run / name).parent.mkdir(exist_ok=True)
        (run / name).write_text("old")
    assert _run(scene, run, "--overwrite") == 0
    assert not (run / "figures").exists() and not (run / "compare").exists()
    assert (run / "notes.txt").read_text() == "old"


def test_overwrite_keeps_the_users_files_in_femphases_folders(scene, tmp_path, capsys):
    # figures/ and compare/ were deleted whole and fields/ emptied: a user's paper.png in
    # figures/ went with them; a folder in fields/ stopped the overwrite with an internal
    # error after particles.csv was gone
    run = tmp_path / "run"
    assert _run(scene, run) == 0
    assert main(["plot", str(run)]) == 0
    mine = ("figures/paper.png", "compare/notes.txt", "fields/extra.h5")
    for name in (*mine, "compare/compare.csv"):
        (run / name).parent.mkdir(exist_ok=True)
        (run / name).write_text("mine")
    assert _run(scene, run, "--overwrite") == 0
    assert all((run / name).read_text() == "mine" for name in mine)
    assert sorted(p.name for p in (run / "figures").iterdir()) == ["paper.png"]  # plot's figures went
    assert not (run / "compare" / "compare.csv").exists()
    (run / "fields" / "frame_000000.h5").unlink()
    (run / "fields" / "frame_000000.h5").mkdir()
    capsys.readouterr()
    assert _run(scene, run, "--overwrite") == 2
    assert "fields/frame_000000.h5 is not one (nothing was deleted)" in capsys.readouterr().err
    assert (run / "particles.csv").is_file()


def test_overwrite_deletes_the_partial_files_a_killed_run_leaves(scene, tmp_path):
    # a kill between writing and renaming leaves each output's partial file; --overwrite
    # deleted only the field mesh's, and a fields/ holding one more was never removed
    from femphase.io.files import partial_path

    run = tmp_path / "run"
    assert _run(scene, run, "--set", "output.fields=false") == 0
    partial = [partial_path(run / name) for name in ("run.json", "scene.toml", "checkpoint.h5", "fields.xdmf",
                                                      "fields/mesh.h5", "fields/frame_000003.h5")]
    for path in partial:
        path.parent.mkdir(exist_ok=True)
        path.write_text("partial")
    assert _run(scene, run, "--overwrite", "--set", "output.fields=false") == 0
    assert not [path for path in partial if path.exists()]
    assert not (run / "fields").exists()


def test_a_resume_leaves_other_files_in_the_field_folder_alone(scene, tmp_path):
    # cutting the frames after the checkpoint read every frame_*.h5 as a frame number
    run = tmp_path / "run"
    assert _run(scene, run) == 0
    (run / "fields" / "frame_notes.h5").write_text("mine")
    assert _run(scene, run, "--resume", "--set", "phases.1.duration=40") == 0
    assert (run / "fields" / "frame_notes.h5").read_text() == "mine"


def test_a_sweep_directory_is_not_taken_for_a_run(scene, tmp_path, capsys):
    # a run's files written among a sweep's index and runs/ were read as neither
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "sweep.json").write_text("{}")
    for flags in ((), ("--overwrite",)):
        assert _run(scene, sweep, *flags) == 2
        assert "it holds sweep.json" in capsys.readouterr().err
    assert sorted(p.name for p in sweep.iterdir()) == ["sweep.json"]


def test_a_run_without_checkpoints_does_not_claim_one_when_it_stops(scene, tmp_path, capsys):
    # "The last good checkpoint is kept" was printed where output.checkpoint = false wrote none
    from femphase.cli import _report

    assert _run(scene, tmp_path / "run", "--set", "output.checkpoint=false", "--set", "numerics.blowup_margin=1e-9") == 3
    message = capsys.readouterr().err
    assert "the run blew up at step 1" in message and "checkpoint is kept" not in message
    assert "it writes no checkpoint (output.checkpoint = false) and cannot be continued" in message
    assert not (tmp_path / "run" / "checkpoint.h5").exists()
    assert _run(scene, tmp_path / "kept", "--set", "numerics.blowup_margin=1e-9") == 3
    assert "The last good checkpoint is kept." in capsys.readouterr().err
    interrupt = KeyboardInterrupt()
    interrupt.kept = "frames"
    assert _report(interrupt) == (130, "interrupted; its frames so far are kept; it writes no checkpoint "
                                       "(output.checkpoint = false) and cannot be continued")


def test_a_stop_claims_a_checkpoint_only_where_one_was_written(capsys):
    # Ctrl-C before the run directory existed (and in plot, compare, ode) printed "the last
    # checkpoint is kept (continue with --resume)"; so did a run stopped before its first
    from femphase.cli import _report
    from femphase.errors import BlowUpError

    assert _report(KeyboardInterrupt()) == (130, "interrupted")
    interrupt = KeyboardInterrupt()
    interrupt.kept = "nothing"
    assert _report(interrupt) == (130, "interrupted; it stopped before its first checkpoint and cannot be "
                                       "continued: rerun it with --overwrite")
    interrupt.kept = "checkpoint"
    assert _report(interrupt) == (130, "interrupted; the last checkpoint is kept (continue with --resume)")
    blowup = BlowUpError(3, 30.0, "φ is not finite")
    blowup.kept = "nothing"
    assert _report(blowup)[1] == ("error: the run blew up at step 3 (t = 30): φ is not finite. It stopped before its "
                                  "first checkpoint and cannot be continued: rerun it with --overwrite.")


def test_a_directory_stopped_before_its_first_checkpoint_is_told_to_be_replaced(scene, tmp_path, capsys):
    # "continue it with --resume", which then refused; and a checkpoint.h5 that is a folder
    # was "a run directory that holds checkpoint.h5 (it has …, checkpoint.h5, …)"
    run = tmp_path / "run"
    assert _run(scene, run) == 0
    (run / "checkpoint.h5").unlink()
    capsys.readouterr()
    assert _run(scene, run) == 2
    assert "replace it with --overwrite (it has no checkpoint.h5 to continue from" in capsys.readouterr().err
    assert _run(scene, run, "--resume") == 2
    assert "a run stopped before its first checkpoint is replaced with --overwrite" in capsys.readouterr().err
    (run / "checkpoint.h5").mkdir()
    assert _run(scene, run, "--resume") == 2
    assert "(checkpoint.h5 there is not a file)" in capsys.readouterr().err


def test_a_run_with_an_energy_term_of_its_own_resumes_with_it(scene, tmp_path):
    # run_scene took no energy: such a run could not be written by it, and resuming one
    # without the term was refused as if output.observables had changed
    from dataclasses import dataclass
    from typing import ClassVar

    import numpy as np

    from femphase.model.energy import EnergyTerm, FreeEnergy
    from femphase.run.runner import run_scene
    from femphase.scene import load_scene

    @dataclass(frozen=True)
    class Weight(EnergyTerm):
        strength: float
        name: ClassVar[str] = "weight"

        def energy(self, fields):
            return self.strength * fields.integral(fields.squares)

        def explicit_derivative(self, fields):
            return 2.0 * self.strength * fields.phi

        def curvature_bound(self, smallest_radius, pairs):
            return 2.0 * self.strength

    loaded = load_scene(scene)
    energy = FreeEnergy(list(FreeEnergy.paper(loaded.model).terms) + [Weight(1e-4)])
    run_scene(loaded, tmp_path / "run", progress=False, energy=energy)
    header = (tmp_path / "run" / "global.csv").read_text().splitlines()[0].split(",")
    assert "weight" in header
    longer = load_scene(scene, ["phases.1.duration=30.0"])
    with pytest.raises(SceneError, match=r"the file lacks \[\] and has \['weight'\] besides"):
        run_scene(longer, tmp_path / "run", resume=True, progress=False)
    run_scene(longer, tmp_path / "run", resume=True, progress=False, energy=energy)
    times = np.loadtxt(tmp_path / "run" / "global.csv", delimiter=",", skiprows=1)[:, 0]
    assert times[-1] == 50.0


def test_a_resume_goes_on_without_a_lost_field_frame(scene, tmp_path, capsys):
    # a deleted or cut frame file stopped the resume with "internal error (FileNotFoundError
    # …)", exit 1, when fields.xdmf was rewritten from the frames' files
    run = tmp_path / "run"
    assert _run(scene, run) == 0
    (run / "fields" / "frame_000002.h5").unlink()
    cut = run / "fields" / "frame_000003.h5"
    cut.write_bytes(cut.read_bytes()[:500])
    capsys.readouterr()
    assert _run(scene, run, "--resume", "--set", "phases.1.duration=30.0") == 0
    err = capsys.readouterr().err
    assert "frame_000002.h5 (t = 10) is missing; the run goes on, and fields.xdmf leaves that frame out" in err
    assert "frame_000003.h5 (t = 15) cannot be read as HDF5" in err
    xdmf = (run / "fields.xdmf").read_text()
    assert "frame_000002.h5" not in xdmf and "frame_000003.h5" not in xdmf and "frame_000010.h5" in xdmf


def test_a_full_device_stops_the_run_before_a_write_and_keeps_its_checkpoint(scene, tmp_path, capsys, monkeypatch):
    # a field frame or checkpoint that failed mid-write was "internal error (OSError: [Errno 28]
    # …)", exit 1, after h5py's tracebacks, and the process crashed at exit (139)
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    real = shutil.disk_usage
    writes = []

    def filling(path):  # room for the first frames only
        writes.append(path)
        return usage(1 << 40, 0, (1 << 30) if len(writes) < 6 else 1 << 20)

    run = tmp_path / "run"
    monkeypatch.setattr(shutil, "disk_usage", filling)
    assert _run(scene, run) == 3
    err = capsys.readouterr().err
    assert "MiB free, and" in err and "free space there and continue with --resume. The last checkpoint is kept." in err
    assert json.loads((run / "run.json").read_text())["status"] == "failed"
    monkeypatch.setattr(shutil, "disk_usage", real)
    assert _run(scene, run, "--resume") == 0
    from femphase.cli import _report  # a write that fails all the same (a quota) is no bug either

    full = OSError(errno.ENOSPC, "No space left on device", "particles.csv")
    full.kept = "checkpoint"
    assert _report(full) == (3, "error: cannot write particles.csv: No space left on device. The last checkpoint is "
                                "kept (free space and continue with --resume).")
