"""Run metadata and logging: run.json's provenance and times, run.log's
segment headers, status lines and errors, the console of ``femphase run``."""

import datetime
import importlib
import json
import logging
import os
import platform
import re
import socket
import subprocess
import sys
import time
import types
from importlib import metadata
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

import femphase
from femphase.cli import main
from femphase.io.provenance import DEPENDENCIES, PACKAGE_DIR, THREAD_VARIABLES, changed_since_import, git_commit
from femphase.run.directory import RunDirectory
from femphase.run.simulation import Simulation, Tracker
from femphase.run.trackers import StatusLog
from femphase.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "single.toml"
#: examples/single.toml cut to 20 + 10 steps of the first-order scheme (whose saturation
#: guard the error tests trigger), a frame every 5
SHORT = ["phases.0.duration=20", "phases.1.duration=10", "phases.0.frame_interval=5", "phases.1.frame_interval=5",
         'numerics.scheme="euler"', "phases.0.dt=1", "phases.1.dt=1"]
STATUS = re.compile(r" INFO (status|start|resume|phase \d+:\w+ (?:start|end)): t=(\S+) step=(\d+)/(\d+) phase=\d+:\w+ "
                    r"ms/step=\S+ (?:substep=\S+ rejected=\d+ )?windows=1 mean_dofs=\d+ rss=\d+MiB peak=\d+MiB eta=\S+$")


def _run(directory: Path, *flags: str, sets=SHORT) -> int:
    return main(["run", str(SCENE), "-o", str(directory), "-q", "--status-interval", "0", *flags,
                 *[item for assignment in sets for item in ("--set", assignment)]])


def _json(directory: Path) -> dict:
    return json.loads((directory / "run.json").read_text())


def _instant(text: str) -> datetime.datetime:
    value = datetime.datetime.fromisoformat(text)
    assert value.tzinfo is not None, text
    return value


def _status_lines(log: str) -> list[tuple[str, float, int]]:
    return [(m[1], float(m[2]), int(m[3])) for m in map(STATUS.search, log.splitlines()) if m]


def test_run_json_records_versions_host_threads_command_line_and_times(tmp_path):
    before = datetime.datetime.now().astimezone().replace(microsecond=0)
    assert _run(tmp_path / "run") == 0
    info = _json(tmp_path / "run")
    assert info["femphase_version"] == femphase.__version__
    assert info["status"] == "completed" and info["steps"] == 30
    (segment,) = info["segments"]
    assert segment["status"] == "completed" and segment["step"] == 30 and segment["time"] == 30.0
    assert segment["set"] == SHORT
    assert segment["argv"][:4] == ["run", str(SCENE), "-o", str(tmp_path / "run")]
    assert [segment["argv"][k + 1] for k, a in enumerate(segment["argv"]) if a == "--set"] == SHORT
    started, ended = _instant(info["started"]), _instant(info["ended"])
    assert before <= started <= ended <= datetime.datetime.now().astimezone()
    assert (segment["started"], segment["ended"]) == (info["started"], info["ended"])
    assert 0 < segment["wall_time_s"] < 60 and info["wall_time_s"] == segment["wall_time_s"]
    assert 0 < segment["cpu_time_s"] < 60 and info["cpu_time_s"] == segment["cpu_time_s"]

    origin = segment["provenance"]
    assert origin["femphase_version"] == femphase.__version__
    assert set(origin["dependencies"]) >= {"numpy", "scipy", "scikit-fem", "pyamg", "meshio", "h5py"}
    assert origin["dependencies"] == {name: metadata.version(name) for name in DEPENDENCIES}
    assert origin["python"] == platform.python_version() and origin["python_executable"] == sys.executable
    assert origin["host"] == socket.gethostname() and origin["platform"] == platform.platform()
    assert origin["pid"] == os.getpid() and origin["cwd"] == os.getcwd()
    threads = origin["threads"]
    assert {name: threads[name] for name in THREAD_VARIABLES} == {name: os.environ.get(name) for name in THREAD_VARIABLES}
    assert threads["OMP_NUM_THREADS"] == "1"  # tests/conftest.py
    assert threads["cpu_count"] == os.cpu_count()
    assert threads["cpus_available"] is None or 1 <= threads["cpus_available"] <= os.cpu_count()
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PACKAGE_DIR, capture_output=True, text=True)
    if head.returncode == 0:  # the tests run from a checkout
        assert re.fullmatch(head.stdout.strip() + "(-dirty)?", origin["git_commit"])


def _git(repo: Path, *args: str) -> None:
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=repo, check=True,
                   capture_output=True)


def test_git_commit_is_the_checkouts_dirty_when_changed_and_none_elsewhere(tmp_path, monkeypatch):
    repo = tmp_path / "repo"
    package = repo / "pkg"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    assert git_commit(package) is None  # not a checkout
    _git(repo, "init", "-q")
    assert git_commit(package) is None  # a checkout that does not track the package
    _git(repo, "add", "pkg/__init__.py")
    _git(repo, "commit", "-q", "-m", "x")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True).stdout.strip()
    assert git_commit(package) == head
    (repo / "notes.txt").write_text("outside the package")
    assert git_commit(package) == head
    (package / "__init__.py").write_text("x = 1\n")
    assert git_commit(package) == head + "-dirty"
    monkeypatch.setenv("PATH", str(tmp_path / "no-git-here"))
    assert git_commit(package) is None


def test_modules_edited_after_the_import_are_recorded(tmp_path, monkeypatch):
    """A sweep worker keeps the code it imported: run.json must say when the checkout that
    git_commit describes is no longer that code."""
    package = tmp_path / "editedpkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "solver.py").write_text("x = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.import_module("editedpkg.solver")
    imported = time.time()
    os.utime(package / "__init__.py", (imported - 60, imported - 60))
    os.utime(package / "solver.py", (imported - 60, imported - 60))
    assert changed_since_import(imported, "editedpkg") == []
    os.utime(package / "solver.py", (imported + 60, imported + 60))  # edited after the import
    assert changed_since_import(imported, "editedpkg") == ["editedpkg.solver"]
    (package / "__init__.py").unlink()
    assert changed_since_import(imported, "editedpkg") == ["editedpkg", "editedpkg.solver"]
    sys.modules.pop("editedpkg.solver"), sys.modules.pop("editedpkg")
    assert changed_since_import() == []  # this test process's own femphase is unchanged


def test_every_dependency_a_run_imports_is_recorded(tmp_path):
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    names = {re.split(r"[<>=!~;\[ ]", d, maxsplit=1)[0].lower() for d in declared}
    script = (f"import sys, json; from importlib import metadata; from femphase.cli import main; "
              f"main({['run', str(SCENE), '-o', str(tmp_path / 'run'), '-q', '--set', 'phases.0.duration=20', '--set', 'phases.1.duration=20']!r}); "
              "found = metadata.packages_distributions(); "
              "print(json.dumps(sorted({d.lower() for m in list(sys.modules) for d in found.get(m, [])})))")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, check=True)
    imported = set(json.loads(done.stdout.splitlines()[-1]))
    assert "numpy" in imported
    assert (names & imported) <= set(DEPENDENCIES), "record the new dependency in femphase.io.provenance.DEPENDENCIES"


def test_run_log_has_a_header_status_lines_and_the_end_of_each_segment_and_resume_appends(tmp_path):
    run = tmp_path / "run"
    assert _run(run) == 0
    first_log, first_info = (run / "run.log").read_text(), _json(run)
    lines = first_log.splitlines()
    assert re.search(r"INFO === segment 1: started at t = 0 \(step 0\); femphase \S+ \(git .*\), Python .*; argv: run ",
                     lines[0]), lines[0]
    assert "INFO === segment 1 completed after step 30 (t = 30)" in lines[-1]
    status = _status_lines(first_log)
    assert len(status) == len(lines) - 2  # every other line is a status line
    times = [t for _, t, _ in status]
    assert times[0] == 0.0 and times[-1] == 30.0 and all(a <= b for a, b in zip(times, times[1:]))
    assert len([e for e, _, _ in status if e == "status"]) >= 25  # interval 0: a line per step
    assert [e for e, _, _ in status if e.startswith("phase")] == ["phase 0:relax end", "phase 1:shear start",
                                                                  "phase 1:shear end"]

    assert _run(run, "--resume", sets=SHORT[:1] + ["phases.1.duration=20"] + SHORT[2:]) == 0
    log, info = (run / "run.log").read_text(), _json(run)
    assert log.startswith(first_log)  # appended; the first segment's lines kept
    second = log[len(first_log):].splitlines()
    assert "INFO === segment 2: resumed at t = 30 (step 30);" in second[0] and "--resume" in second[0]
    assert "INFO === segment 2 completed after step 40 (t = 40)" in second[-1]
    resumed = _status_lines("\n".join(second))
    assert resumed[0][:2] == ("resume", 30.0) and resumed[-1][1] == 40.0
    assert [t for _, t, _ in resumed] == sorted(t for _, t, _ in resumed)

    assert info["segments"][0] == first_info["segments"][0]  # provenance and times of segment 1 kept
    assert info["started"] == first_info["started"] and info["ended"] >= first_info["ended"]
    segment = info["segments"][1]
    assert segment["resumed"] and segment["from_step"] == 30 and "--resume" in segment["argv"]
    assert segment["set"][1] == "phases.1.duration=20" and segment["provenance"]["host"] == socket.gethostname()
    for key in ("wall_time_s", "cpu_time_s"):
        assert info[key] == pytest.approx(sum(s[key] for s in info["segments"]))


@pytest.mark.parametrize("sets, code, reason", [
    # an unstabilised area term 250× the paper's blows up at its first step
    (SHORT + ["model.mu=5000", "numerics.stabilisation=0"], 3, "the run blew up at step 1 (t = 1)"),
    # dt = 10 is outside the accuracy envelope, strict stops before phase 1: a run that had
    # written frames, so exit 3 as for a blow-up, not 2 as for input refused before any
    (SHORT + ["phases.1.dt=10", "phases.1.frame_interval=10", "numerics.strict=true"], 3, "the run left the accuracy envelope at step 20 (t = 20)"),
])
def test_a_failed_run_logs_its_error_with_step_and_time(tmp_path, capsys, sets, code, reason):
    run = tmp_path / "run"
    assert _run(run, sets=sets) == code
    last = (run / "run.log").read_text().splitlines()[-1]
    assert " ERROR === segment 1 failed after step " in last and reason in last, last
    assert last.endswith(_json(run)["message"] + " ===")
    err = capsys.readouterr().err
    assert err.count(reason) == 1, err  # on the console once: the CLI's message


class _CtrlC(Tracker):
    def after_step(self, state):
        if state.step == 7:
            raise KeyboardInterrupt


def test_an_interrupted_run_logs_where_it_stopped(tmp_path):
    scene = load_scene(SCENE, SHORT)
    with pytest.raises(KeyboardInterrupt):
        Simulation(scene).run(scene.initial_state(), [RunDirectory(tmp_path / "run"), StatusLog(0.0), _CtrlC()])
    last = (tmp_path / "run" / "run.log").read_text().splitlines()[-1]
    assert " WARNING === segment 1 interrupted after step 7 (t = 7)" in last, last
    info = _json(tmp_path / "run")
    assert info["status"] == info["segments"][0]["status"] == "interrupted" and info["segments"][0]["argv"] is None
    assert not [h for h in logging.getLogger("femphase").handlers if not isinstance(h, logging.NullHandler)]


def test_console_shows_status_lines_once_without_a_terminal_and_none_with_q_or_a_bar(tmp_path, capsys,
                                                                                   monkeypatch):
    # dt = 4 > dt* = 3 for one particle: an accuracy warning, on the console and in run.log
    sets = SHORT + ["phases.1.dt=4", "phases.1.duration=12", "phases.1.frame_interval=4"]
    args = ["run", str(SCENE), "-o", str(tmp_path / "loud"), "--status-interval", "0"]
    assert main(args + [item for a in sets for item in ("--set", a)]) == 0  # captured stderr: not a terminal
    err = capsys.readouterr().err.splitlines()
    log = (tmp_path / "loud" / "run.log").read_text().splitlines()
    console_status = [line.removeprefix("femphase: ") for line in err if STATUS.search(" INFO " + line[10:])]
    assert console_status and console_status == [line.split(" INFO ", 1)[1] for line in log if STATUS.search(line)]
    warned = [line for line in err if line.startswith("femphase: warning: ") and "phases.1.dt" in line]
    assert len(warned) == 1 and any(warned[0].removeprefix("femphase: warning: ") in line for line in log)

    for name, flags in (("quiet", ["-q"]), ("terminal", [])):  # the progress bar shows the progress
        if name == "terminal":
            monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
        args = ["run", str(SCENE), "-o", str(tmp_path / name), "--status-interval", "0", *flags]
        assert main(args + [item for a in sets for item in ("--set", a)]) == 0
        err = capsys.readouterr().err
        assert "status:" not in err and "start:" not in err and err.count("femphase: warning: ") == 1, name
        assert _status_lines((tmp_path / name / "run.log").read_text())


def test_the_library_configures_no_logging_and_the_cli_leaves_none_behind(tmp_path):
    logger = logging.getLogger("femphase")
    assert all(isinstance(h, logging.NullHandler) for h in logger.handlers) and logger.level == logging.NOTSET
    assert _run(tmp_path / "run") == 0
    assert all(isinstance(h, logging.NullHandler) for h in logger.handlers) and logger.level == logging.NOTSET


def test_status_log_from_python_logs_increasing_times(caplog):
    scene = load_scene(SCENE, SHORT)
    with caplog.at_level(logging.INFO, logger="femphase"):
        Simulation(scene).run(scene.initial_state(), [StatusLog(interval=0.0)])
    times = [float(re.search(r"t=(\S+)", r.getMessage())[1]) for r in caplog.records if r.name == "femphase"]
    assert times[0] == 0.0 and times[-1] == 30.0 and times == sorted(times) and len(times) >= 30
    with pytest.raises(ValueError, match="interval"):
        StatusLog(-1.0)


def test_status_lines_under_the_adaptive_scheme_count_its_substeps(caplog):
    scene = load_scene(SCENE, ["phases.0.duration=40", "phases.1.duration=40", "phases.0.frame_interval=20",
                               "phases.1.frame_interval=20"])  # the example's adaptive scheme, dt = 10
    state = scene.initial_state()
    with caplog.at_level(logging.INFO, logger="femphase"):
        Simulation(scene).run(state, [StatusLog(interval=0.0)])
    lines = [r.getMessage() for r in caplog.records if r.name == "femphase"]
    assert "substep=" not in lines[0]  # nothing counted before the first step
    accepted = rejected = 0
    previous = 0.0
    for line in lines[1:]:
        time, substep, rejects = re.search(r"t=(\S+) .*substep=(\S+) rejected=(\d+)", line).groups()
        if substep != "-":
            taken = (float(time) - previous) / float(substep)
            assert abs(taken - round(taken)) < 0.02 and 0 < float(substep) <= 10.0
            accepted += round(taken)
        rejected += int(rejects)
        previous = float(time)
    assert [accepted, rejected] == state.memory["adaptive_counts"].tolist()


def test_status_lines_come_every_interval_of_wall_time_with_the_rate_and_eta(caplog, monkeypatch):
    clock = types.SimpleNamespace(now=0.0)
    monkeypatch.setattr("femphase.run.trackers.wallclock", types.SimpleNamespace(monotonic=lambda: clock.now))

    class Tick(Tracker):  # every step takes 0.25 s of (fake) wall time
        def after_step(self, state):
            clock.now += 0.25

    scene = load_scene(SCENE, SHORT)
    with caplog.at_level(logging.INFO, logger="femphase"):
        Simulation(scene).run(scene.initial_state(), [Tick(), StatusLog(interval=1.0)])
    lines = [r.getMessage() for r in caplog.records if r.name == "femphase"]
    steps = [int(re.search(r"step=(\d+)/30", line)[1]) for line in lines if line.startswith("status:")]
    assert steps == [4, 8, 12, 16, 24, 28]  # a line per second; the phase ends at 20 and 30 reset the count
    assert [line.split(":")[0] for line in lines if not line.startswith("status:")] == [
        "start", "phase 0", "phase 1", "phase 1"]
    first = next(line for line in lines if line.startswith("status:"))
    assert "ms/step=250 " in first and first.endswith(" eta=6s")  # 26 steps to go at 0.25 s
