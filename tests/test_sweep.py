"""femphase sweep: the schema's errors, runs on a Dask LocalCluster that loses a worker
mid-run, resuming, and shared relaxations, each against serial runs of the same scenes."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import pytest

from femphase.cli import main
from femphase.run.runner import run_scene
from femphase.scene import load_scene
from femphase.sweep import WORKER_ENV, SweepError, load_sweep, run_sweep

distributed = pytest.importorskip("distributed")

# two particles in a small channel: a relaxation, then shear; ~1.5 s per run
SCENE = """
name = "tiny"
[domain]
Lx = 40.0
Ly = 40.0
h = 1.0
[particles]
layout = "random"
N = 2
seed = 1
[[phases]]
name = "relax"
duration = 20.0
dt = 1.0
frame_interval = 10.0
[[phases]]
name = "shear"
duration = 300.0
dt = 1.0
frame_interval = 20.0
flow = { type = "shear", rate = 0.5 }
"""
SWEEP = """
[sweep]
scene = "tiny.toml"
[axes]
"phases.1.flow.rate" = [0.3, 1.0]
"particles.seed" = [1, 2]
"""
IDS = ["rate=0.3_seed=1", "rate=0.3_seed=2", "rate=1.0_seed=1", "rate=1.0_seed=2"]


def write(folder: Path, sweep: str = SWEEP) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "tiny.toml").write_text(SCENE)
    (folder / "sweep.toml").write_text(sweep)
    return folder / "sweep.toml"


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                       env=WORKER_ENV)
    with cluster, distributed.Client(cluster) as connected:
        yield connected


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    """Each run of SWEEP by plain run_scene (no sweep, no branching): run id → directory."""
    folder = tmp_path_factory.mktemp("serial")
    path = write(folder)
    out = {}
    for run in load_sweep(path).runs:
        scene = load_scene(folder / "tiny.toml", [f"{k}={v}" for k, v in run.values.items()])
        run_scene(scene, folder / run.id, progress=False)
        out[run.id] = folder / run.id
    return out


def assert_same_outputs(sweep_dir: Path, serial: dict) -> None:
    for run_id, reference in serial.items():
        for name in ("particles.csv", "global.csv"):
            assert (sweep_dir / "runs" / run_id / name).read_bytes() == (reference / name).read_bytes(), (run_id, name)


def segments(directory: Path) -> list[dict]:
    return json.loads((directory / "run.json").read_text())["segments"]


@pytest.mark.parametrize("text, key", [
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"particles.sed" = [1, 2]', "axes.particles.sed"),
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"phases.1.flow.rat" = [1.0]', "axes.phases.1.flow.rat"),
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"phases.5.dt" = [1.0]', "axes.phases.5.dt"),
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"particles.seed" = [1, -1]', "axes.particles.seed"),
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"particles.seed" = 3', "axes.particles.seed"),
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"particles.seed" = [1, 1]', "axes.particles.seed"),
    # 1 and 1.0 ran twice, then `femphase aggregate` refused the directory the sweep wrote
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"phases.1.flow.rate" = [1, 1.0]', "axes.phases.1.flow.rate"),
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"phases.1.flow.rate" = [0.0, -0.0]', "axes.phases.1.flow.rate"),
    # the axis' tables replaced the [set] key inside them without a word
    ('[sweep]\nscene = "tiny.toml"\n[set]\n"phases.1.flow.rate" = 0.7\n[axes]\n"phases.1.flow" = '
     '[{type = "shear", rate = 0.1}, {type = "poiseuille", rate = 0.2}]', "axes.phases.1.flow"),
    ('[sweep]\nscene = "tiny.toml"\n[set]\n"model.mu" = "x"\n[axes]\n"particles.seed" = [1]', "set.model.mu"),
    ('[sweep]\nscene = "tiny.toml"\nmode = "zip"\n[axes]\n"particles.seed" = [1, 2]\n"phases.1.dt" = [1.0]',
     "sweep.mode"),
    ('[sweep]\nscene = "tiny.toml"\nmode = "cartesian"\n[axes]\n"particles.seed" = [1]', "sweep.mode"),
    ('[sweep]\nscene = "missing.toml"\n[axes]\n"particles.seed" = [1]', "sweep.scene"),
    ('[sweep]\nscene = "tiny.toml"\n[axis]\n"particles.seed" = [1]', "axis"),
    ('[sweep]\nscene = "tiny.toml"\n', "axes"),
    ('[sweep]\nscene = "tiny.toml"\n[axes]\n"name" = ["a b", "a-b"]', "axes"),
])
def test_schema_errors_name_the_key_before_anything_runs(tmp_path, text, key):
    path = write(tmp_path, text)
    with pytest.raises(SweepError) as caught:
        run_sweep(path, tmp_path / "out")  # no client: it would start a cluster after validation
    assert caught.value.key == key
    assert f"'{key}'" in str(caught.value)
    assert not (tmp_path / "out").exists()


def test_a_scene_given_as_a_sweep_is_named_as_one(tmp_path):
    path = write(tmp_path, 'name = "tiny"\n[[phases]]\nduration = 10.0\ndt = 1.0\nframe_interval = 1.0')
    with pytest.raises(SweepError, match=r"looks like a scene: a sweep file names its scene in \[sweep\]") as caught:
        run_sweep(path, tmp_path / "out")
    assert caught.value.key == "name"


def test_cli_reports_bad_input_with_exit_code_2(tmp_path, capsys):
    path = write(tmp_path, SWEEP.replace("particles.seed", "particles.sed"))
    assert main(["sweep", str(path), "-o", str(tmp_path / "out")]) == 2
    assert "'axes.particles.sed'" in capsys.readouterr().err
    path = write(tmp_path)
    assert main(["sweep", str(path), "-o", str(tmp_path / "out"), "--workers", "0"]) == 2
    assert "'--workers'" in capsys.readouterr().err
    assert main(["sweep", str(path), "-o", str(tmp_path / "out"), "--set", "phases.1.flow.rate=2"]) == 2
    assert "axes.phases.1.flow.rate" in capsys.readouterr().err  # an axis is not also set
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("address, cause", [("tcp://127.0.0.1:1", "OSError"), ("nonsense", "ValueError")])
def test_a_scheduler_that_cannot_be_reached_is_named_as_the_option(tmp_path, address, cause):
    import dask

    before = dask.config.get("scheduler", None)
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}), pytest.raises(SweepError) as caught:
        run_sweep(write(tmp_path), tmp_path / "out", scheduler=address)
    assert (caught.value.key, caught.value.value) == ("--scheduler", address)
    assert f"connecting failed: {cause}" in str(caught.value)
    # the failed Client, alive while its exception is, is not left as Dask's default scheduler
    # (femphase converge's netCDF write in the same process then asked for it)
    assert dask.config.get("scheduler", None) == before
    # nothing ran, so nothing ties the directory to this sweep file (a corrected one was refused),
    # and a directory this call made is gone again (it left locks/sweep.lock)
    assert not (tmp_path / "out").exists()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("kept")
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}), pytest.raises(SweepError):
        run_sweep(write(tmp_path), tmp_path / "mine", scheduler=address)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "kept"  # a directory it did not make stays


def test_an_output_path_through_a_file_is_bad_input(tmp_path, capsys):
    # NotADirectoryError making locks/: "internal error …; this is a bug" (exit 1)
    (tmp_path / "afile").write_text("")
    assert main(["sweep", str(write(tmp_path)), "-o", str(tmp_path / "afile" / "sub")]) == 2
    assert "'-o' = " in (err := capsys.readouterr().err) and "afile is a file)" in err


def test_run_ids_labels_zip_and_sharing(tmp_path):
    product = load_sweep(write(tmp_path / "a"))
    assert [run.id for run in product.runs] == IDS
    # runs of one seed share its relaxation; different seeds do not
    shared = {run.id: run.shared for run in product.runs}
    assert shared["rate=0.3_seed=1"] == shared["rate=1.0_seed=1"] != shared["rate=0.3_seed=2"] is not None
    zipped = load_sweep(write(tmp_path / "b", '[sweep]\nscene = "tiny.toml"\nmode = "zip"\n[axes]\n'
                              '"phases.0.dt" = [1.0, 2.0]\n"phases.1.dt" = [1.0, 4.0]\n'))
    assert [run.id for run in zipped.runs] == ["0.dt=1.0_1.dt=1.0", "0.dt=2.0_1.dt=4.0"]
    assert all(run.shared is None for run in zipped.runs)  # their first phases differ


def test_a_shared_relaxation_on_a_mesh_is_named_by_the_meshs_content_not_its_path(tmp_path):
    from test_rundir import MESH_SCENE, _channel_mesh, _renumbered

    scene = MESH_SCENE + ('[[phases]]\nname = "shear"\nduration = 4.0\ndt = 2.0\nframe_interval = 2.0\n'
                          'flow = { type = "shear", rate = 0.1 }\n')
    sweep = '[sweep]\nscene = "mesh.toml"\n[axes]\n"phases.1.flow.rate" = [0.1, 0.2]\n'
    names = {}
    for folder in ("first", "moved", "renumbered"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "mesh.toml").write_text(scene)
        (tmp_path / folder / "sweep.toml").write_text(sweep)
    _channel_mesh(tmp_path / "first" / "a" / "c.vtu", seed=1)
    (tmp_path / "moved" / "a").mkdir()
    (tmp_path / "moved" / "a" / "c.vtu").write_bytes((tmp_path / "first" / "a" / "c.vtu").read_bytes())
    _renumbered(tmp_path / "first" / "a" / "c.vtu", tmp_path / "renumbered" / "a" / "c.vtu")
    for folder in ("first", "moved", "renumbered"):
        runs = load_sweep(tmp_path / folder / "sweep.toml").runs
        assert runs[0].shared == runs[1].shared is not None
        names[folder] = runs[0].shared
    assert names["first"] == names["moved"] != names["renumbered"]


def test_branched_runs_equal_serial_runs_and_a_rerun_skips_done_runs(tmp_path, client, serial):
    path, out = write(tmp_path), tmp_path / "out"
    index = run_sweep(path, out, client)
    assert index["format"] == "femphase-sweep" and index["version"] == 1 and index["mode"] == "product"
    assert index["axes"] == {"phases.1.flow.rate": [0.3, 1.0], "particles.seed": [1, 2]}
    assert [(r["id"], r["directory"], r["status"], r["error"]) for r in index["runs"]] == [
        (i, f"runs/{i}", "done", None) for i in IDS]
    assert json.loads((out / "sweep.json").read_text()) == index
    assert (out / "sweep.toml").read_text() == path.read_text()
    # two relaxations (one per seed), each computed once: one segment, phase 0 only
    relaxations = sorted((out / "shared").iterdir())
    assert len(relaxations) == 2
    for relaxation in relaxations:
        assert [s["step"] for s in segments(relaxation)] == [20]
    for run_id in IDS:  # each run: the copied relaxation, then its own shear
        assert [(s["resumed"], s["step"]) for s in segments(out / "runs" / run_id)] == [(False, 20), (True, 320)]
    assert_same_outputs(out, serial)

    # a rerun skips done runs (their files untouched) and reruns a failed one
    info = out / "runs" / IDS[1] / "run.json"
    failed = json.loads(info.read_text())
    info.write_text(json.dumps({**failed, "status": "failed", "message": "a test's failure"}))
    stamps = {i: (out / "runs" / i / "particles.csv").stat().st_mtime_ns for i in IDS}
    lines = []
    index = run_sweep(path, out, client, log=lines.append)
    assert all(r["status"] == "done" for r in index["runs"])
    assert "4 runs, 3 done, 1 to run" in lines[0]
    assert [i for i in IDS if (out / "runs" / i / "particles.csv").stat().st_mtime_ns != stamps[i]] == [IDS[1]]
    assert_same_outputs(out, serial)

    # a changed sweep is refused unless it only adds values
    with pytest.raises(SweepError, match="added values only"):
        run_sweep(write(tmp_path, SWEEP.replace("[1, 2]", "[1]")), out, client)
    # 1.0 written as 1: one value, another run id ("values that include those of" run
    # rate=1.0_seed=1, as if the value were gone)
    with pytest.raises(SweepError, match=r"the values spelled as before: run 'rate=1\.0_seed=1' .* would now be "
                                         r"named 'rate=1_seed=1'"):
        run_sweep(write(tmp_path, SWEEP.replace("[0.3, 1.0]", "[0.3, 1]")), out, client)
    with pytest.raises(SweepError, match="'set.phases.1.duration' = 100 is invalid: unset as in the sweep"):
        run_sweep(path, out, client, assignments=["phases.1.duration=100"])  # said "None as in the sweep"
    lines.clear()
    index = run_sweep(write(tmp_path, SWEEP.replace("[0.3, 1.0]", "[0.3, 1.0, 2.0]")), out, client, log=lines.append)
    assert "6 runs, 4 done, 2 to run" in lines[0]
    assert [r["id"] for r in index["runs"] if r["status"] == "done"] == IDS + ["rate=2.0_seed=1", "rate=2.0_seed=2"]
    assert [s["step"] for s in segments(out / "runs" / "rate=2.0_seed=1")] == [20, 320]  # the same relaxation
    assert len(list((out / "shared").iterdir())) == 2


def test_two_workers_asking_for_one_relaxation_compute_it_once(tmp_path):
    from femphase.sweep import _execute_shared

    sweep = load_sweep(write(tmp_path))
    run = sweep.runs[0]
    target = tmp_path / "out" / "shared" / run.shared
    outcomes = []
    threads = [threading.Thread(target=lambda: outcomes.append(_execute_shared(run.data, str(tmp_path), str(target))))
               for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert [o["status"] for o in outcomes] == ["done", "done"]
    assert [s["step"] for s in segments(target)] == [20]  # computed by one, skipped by the other


def test_a_task_leaves_no_cyclic_garbage_for_the_workers_next_task():
    # a run's domain and its caches reference each other; a worker must not carry one run's
    # cycle into the next (measured on the straight mesh: ~175 MB more resident per run)
    import gc
    import weakref

    from femphase.sweep import _outcome

    class Node:
        pass

    finalised = []

    def action():
        node = Node()
        node.self = node  # a cycle: only the cyclic collector frees it
        weakref.finalize(node, finalised.append, True)

    enabled = gc.isenabled()
    gc.disable()  # no automatic collection may free it instead
    try:
        assert _outcome(action)["status"] == "done"
        assert finalised == [True]
    finally:
        if enabled:
            gc.enable()


def test_runs_start_in_the_sweep_files_order(tmp_path):
    # one worker runs one task at a time: the runs finish in the order they started
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
                                       env=WORKER_ENV)
    lines = []
    with cluster, distributed.Client(cluster) as one_worker:
        run_sweep(write(tmp_path), tmp_path / "out", one_worker, log=lines.append)
    finished = [line.split("] ")[1].split(":")[0] for line in lines if line.startswith("femphase sweep: [")]
    assert finished == IDS


def test_a_worker_killed_mid_run_is_replaced_and_its_run_resumed(tmp_path, client, serial):
    path, out = write(tmp_path), tmp_path / "out"
    result: dict = {}
    thread = threading.Thread(target=lambda: result.update(index=run_sweep(path, out, client)))
    thread.start()
    pids = client.run(os.getpid)
    killed = None
    deadline = time.monotonic() + 60
    while killed is None and thread.is_alive() and time.monotonic() < deadline:
        # a run of phase 1 under way (past a checkpoint) on a worker: kill that worker
        for address, keys in client.processing().items():
            for key in keys:
                run_id = next((i for i in IDS if f"-{i}-" in str(key)), None)
                directory = out / "runs" / str(run_id)
                if run_id and (directory / "run.json").exists():
                    info = json.loads((directory / "run.json").read_text())
                    if info["status"] == "running" and 40 <= info["steps"] <= 220:
                        os.kill(pids[address], signal.SIGKILL)
                        killed = run_id
                        break
            if killed:
                break
        time.sleep(0.02)
    thread.join(timeout=120)
    assert killed is not None, "no run was caught under way"
    assert [r["status"] for r in result["index"]["runs"]] == ["done"] * 4
    steps = [(s["resumed"], s["step"]) for s in segments(out / "runs" / killed)]
    assert len(steps) == 3 and steps[-1] == (True, 320), steps  # relaxation, killed segment, resumed
    assert_same_outputs(out, serial)


def test_local_cluster_workers_start_without_dasks_malloc_trim_setting(client):
    """Dask's default MALLOC_TRIM_THRESHOLD_ made every run 2.5-3.5x slower (femphase.sweep.
    SLOW_MALLOC); femphase's LocalCluster drops it, and workers that have it are named."""
    from femphase.sweep import _check_workers, _client, _malloc_setting

    with pytest.warns(UserWarning) as caught:  # a warning, on stderr: it was a line of the sweep's progress on stdout
        _check_workers(client)  # this fixture's cluster is Dask's default
    assert set(client.run(_malloc_setting).values()) != {None}
    said = [str(w.message) for w in caught]
    assert len(said) == 1 and "2 of 2 workers" in said[0] and "pre-spawn-environ" in said[0]
    with _client(None, None, 1, lambda line: None) as ours:
        assert set(ours.run(_malloc_setting).values()) == {None}
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            _check_workers(ours)


def test_a_table_in_set_replaces_the_scenes_table_as_run_set_does(tmp_path):
    # it was merged key by key: a flow could not be switched off ({type = "none"} kept the
    # shear's rate and was refused), and {type = "poiseuille"} ran with the shear's rate
    off = load_sweep(write(tmp_path / "a", '[sweep]\nscene = "tiny.toml"\n[set]\n"phases.1.flow" = {type = "none"}\n'
                           '[axes]\n"particles.seed" = [1, 2]\n'))
    assert all(run.data["phases"][1]["flow"] == {"type": "none"} for run in off.runs)
    line = load_sweep(write(tmp_path / "b"), ["phases.1.flow={type = \"poiseuille\", rate = 0.2}"])
    # --set's table replaces the shear, and the axis then sets its rate
    assert [run.data["phases"][1]["flow"] for run in line.runs[::2]] == [{"type": "poiseuille", "rate": r}
                                                                        for r in (0.3, 1.0)]
    with pytest.raises(SweepError, match=r"sweep key 'set\.phases\.1\.flow'"):  # needs its rate, named as [set]'s
        load_sweep(write(tmp_path / "c", '[sweep]\nscene = "tiny.toml"\n[set]\n"phases.1.flow" = {type = "poiseuille"}\n'
                         '[axes]\n"particles.seed" = [1, 2]\n'))


def test_a_workers_run_warns_in_the_command_lines_one_line_form(capsys):
    # a Dask worker printed its runs' warnings in Python's form (file, line, the warn call)
    import warnings as stdlib_warnings

    from femphase.sweep import _outcome

    outcome = _outcome(lambda: stdlib_warnings.warn("the particle has vanished", UserWarning))
    assert outcome["status"] == "done"
    assert capsys.readouterr().err == "femphase: warning: the particle has vanished\n"


def test_a_run_finished_while_the_sweep_stopped_is_recorded_done(tmp_path, monkeypatch):
    # a SIGTERM late in a run: the index was written "interrupted", then the worker finished
    # the run while the cluster shut down, and `plot` left the finished run out
    import femphase.sweep as module

    path = write(tmp_path, SWEEP.replace("[0.3, 1.0]", "[0.3]").replace("[1, 2]", "[1]"))

    def finish_then_stop(sweep, directory, todo, statuses, client, log):
        run = todo[0]
        statuses[run.id] = ("interrupted", "the sweep was stopped during this run")
        module._write_index(directory, module._index(sweep, statuses))
        module._execute_run(run.data, str(sweep.base_dir), str(directory / "runs" / run.id))
        raise KeyboardInterrupt

    monkeypatch.setattr(module, "_submit", finish_then_stop)
    monkeypatch.setattr(module, "_check_workers", lambda client: None)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(path, tmp_path / "out", client=object(), log=lambda line: None)
    index = json.loads((tmp_path / "out" / "sweep.json").read_text())
    assert [run["status"] for run in index["runs"]] == ["done"]


def test_a_directory_given_as_a_file_is_named_as_the_argument(tmp_path, capsys):
    # "sweep key 'sweep' = 'DIR' is invalid: a TOML sweep file that exists": it exists
    assert main(["sweep", str(tmp_path), "-o", str(tmp_path / "out")]) == 2
    assert f"argument 'SWEEP' = '{tmp_path}' is invalid: a TOML sweep file (this path is a directory)" in \
        capsys.readouterr().err
    assert main(["run", str(tmp_path), "-o", str(tmp_path / "out")]) == 2
    assert f"argument 'SCENE' = '{tmp_path}' is invalid: a TOML scene file (this path is a directory)" in \
        capsys.readouterr().err
    sweep = write(tmp_path / "a", SWEEP.replace('scene = "tiny.toml"', 'scene = ".."'))
    assert main(["sweep", str(sweep), "-o", str(tmp_path / "out")]) == 2
    assert f"({tmp_path} is a directory)" in capsys.readouterr().err


def test_ctrl_c_in_a_terminal_stops_the_sweep_without_worker_tracebacks(tmp_path):
    # SIGINT reaches the whole process group: each local worker printed ~30 lines of
    # traceback from Dask's event loop before the sweep's own message
    path = write(tmp_path)
    process = subprocess.Popen([sys.executable, "-m", "femphase.cli", "sweep", str(path), "-o", str(tmp_path / "out"),
                                "--workers", "1"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # until the first run is done: the worker is busy with the next
        line = process.stdout.readline()
        lines.append(line)
        if "[1/4]" in line:
            break
    os.killpg(process.pid, signal.SIGINT)
    try:
        output = "".join(lines) + process.communicate(timeout=120)[0]
    except subprocess.TimeoutExpired:  # once in about 20 runs on a loaded machine: say where it stood
        os.killpg(process.pid, signal.SIGKILL)
        rest = process.communicate()[0]
        pytest.fail("the sweep did not stop within 120 s of SIGINT; its output until then:\n" + "".join(lines) + rest)
    assert process.returncode == 130, output
    assert "femphase sweep: interrupted" in output and "Traceback" not in output, output
