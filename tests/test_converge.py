"""femphase converge: Richardson analysis on manufactured values, and a real study end to end."""

import math
import subprocess
import sys
import warnings

import numpy as np
import pytest

from femphase.converge import ConvergenceError, richardson, run_convergence

DISC = """
name = "disc relaxing from R/2"
[domain]
Lx = 40.0
Ly = 40.0
h = 1.0
[particles]
layout = "list"
centres = [[20.0, 20.0]]
initial_radius = 4.0
[output]
fields = false
[[phases]]
name = "relax"
duration = 20.0
dt = 1.0
frame_interval = 10.0
"""


def test_richardson_recovers_a_manufactured_limit_and_order():
    h = [1.0, 0.5, 0.25]
    f = [3.0 + 0.5 * x**2 + 0.1 * x**3 for x in h]
    estimate = richardson(h, f)
    assert estimate.order_observed and 2.0 < estimate.order < 2.3
    assert abs(estimate.limit - 3.0) < estimate.error_bar  # the bar holds the true limit
    assert estimate.error_bar < 0.05  # 1.25 × the finest difference over (2^p − 1)
    np.testing.assert_allclose(estimate.errors, np.array(f) - estimate.limit)
    # the order is that of the refined quantity whatever the levels' order in the input
    assert richardson(h[::-1], f[::-1]).limit == pytest.approx(estimate.limit)


def test_an_order_above_the_formal_one_is_not_used_to_shrink_the_bar():
    # the finest levels converge at 2; the coarsest is pre-asymptotic, inflating the observed order
    estimate = richardson([2.0, 1.0, 0.5], [1.0, 2.9, 2.95])
    assert estimate.order > 5 and estimate.order_used == 2.0 and "formal" in estimate.note
    assert estimate.limit == pytest.approx(2.95 + 0.05 / 3)
    assert estimate.error_bar == pytest.approx(1.25 * 0.05 / 3)


def test_two_levels_assume_the_order_with_a_wider_bar():
    observed = richardson([1.0, 0.5, 0.25], [3.5, 3.125, 3.03125])
    assumed = richardson([0.5, 0.25], [3.125, 3.03125], expected_order=2.0)
    assert not assumed.order_observed and assumed.order == 2.0
    assert assumed.limit == pytest.approx(3.0) and observed.limit == pytest.approx(3.0)
    assert assumed.error_bar == pytest.approx(observed.error_bar * 3 / 1.25)


def test_oscillating_or_diverging_levels_give_no_limit_and_say_why():
    oscillating = richardson([1.0, 0.5, 0.25], [3.0, 3.1, 3.05])
    assert math.isnan(oscillating.limit) and "change sign" in oscillating.note
    diverging = richardson([1.0, 0.5, 0.25], [3.0, 3.1, 3.3])
    assert math.isnan(diverging.limit) and "divergent" in diverging.note


def test_levels_at_any_ratios_give_the_order_of_the_manufactured_values():
    h = [1.0, 0.7, 0.45]  # as the effective spacings of unstructured meshes come
    estimate = richardson(h, [3.0 + 0.5 * x**2 for x in h])
    assert estimate.order == pytest.approx(2.0, abs=1e-9) and estimate.limit == pytest.approx(3.0, abs=1e-12)
    with pytest.raises(ConvergenceError, match="different values"):
        richardson([1.0, 0.5, 0.5], [1.0, 2.0, 3.0])
    with pytest.raises(ConvergenceError, match="at least two"):
        richardson([1.0], [1.0])


@pytest.mark.parametrize("spacings, order", [([1.0, 0.25, 0.2], -0.5), ([1.0, 0.25, 0.2], 3.0),
                                             ([1.0, 0.9, 0.1], 1.0), ([1.0, 0.9, 0.1], 30.0)])
def test_uneven_levels_give_the_order_of_the_manufactured_values_whatever_its_sign(spacings, order):
    # at [1, 0.25, 0.2], f = s^−0.5 (growing without bound) came back as order 6.47 with a
    # limit of 2.656 ± 0.525: the constant-ratio formula where the bracket [1e-3, 20] missed
    estimate = richardson(spacings, [3.0 + s**order for s in spacings], expected_order=2.0)
    assert estimate.order == pytest.approx(order, rel=1e-9)
    if order < 0:
        assert math.isnan(estimate.limit) and "divergent" in estimate.note


def test_equal_finest_values_give_their_value_and_each_run_its_own_error():
    # the coarsest level, 1.5 off, was reported with error 0 and order_used inf
    estimate = richardson([2.0, 1.0, 0.5, 0.25], [3.0, 1.5, 1.5, 1.5])
    assert estimate.limit == 1.5 and estimate.error_bar == 0.0 and estimate.order_used == 2.0
    assert estimate.errors == (1.5, 0.0, 0.0, 0.0)
    stalled = richardson([1.0, 0.5, 0.25], [2.0, 2.0, 1.5])
    assert math.isnan(stalled.limit) and "change sign" not in stalled.note and "asymptotic" in stalled.note


def test_a_measured_uncertainty_widens_the_bar_and_noise_is_named():
    # periods from a few cycles: ±41.5 on one level, against a level difference of 12, made a
    # bar of 16.8 with no word that the difference was the measurement's noise
    values, spacings = [1850.0, 1838.0], [1.0, 0.5]
    exact = richardson(spacings, values)
    noisy = richardson(spacings, values, uncertainties=[5.0, 41.5])
    assert noisy.limit == exact.limit and "not resolved" not in exact.note
    limit_sigma = np.hypot(41.5 * 4 / 3, 5.0 / 3)  # r = 2, q = 2: (u₃ r^q ⊕ u₂)/(r^q − 1)
    assert noisy.error_bar == pytest.approx(np.hypot(exact.error_bar, 2 * limit_sigma))
    assert "less than twice their measurement uncertainty" in noisy.note and "1838 ± 42" in noisy.note
    resolved = richardson(spacings, values, uncertainties=[1.0, 1.0])
    assert "not resolved" not in resolved.note
    assert resolved.error_bar < 1.01 * np.hypot(exact.error_bar, 2 * np.hypot(4 / 3, 1 / 3))


def test_noise_is_looked_for_in_both_differences_of_the_finest_three():
    # only two-level studies tested it, where the finest pair is the only pair: a check of
    # the finest pair alone passed. Here the coarser difference (4) is within twice its
    # uncertainty (2 √(1.5² + 1.5²) = 4.24) and the finer (3.5) above its own
    # (2 √(1.5² + 0.1²) = 3.007)
    estimate = richardson([1.0, 0.5, 0.25], [10.0, 14.0, 17.5], uncertainties=[1.5, 1.5, 0.1])
    assert "less than twice their measurement uncertainty (10 ± 1.5 and 14 ± 1.5)" in estimate.note, estimate.note
    assert "17.5 ±" not in estimate.note


def test_coarse_levels_that_do_not_converge_with_the_finest_three_are_named():
    quiet = richardson([4.0, 2.0, 1.0, 0.5], [3.0 + 0.5 * h**2 for h in (4.0, 2.0, 1.0, 0.5)])
    assert "coarser than the finest three" not in quiet.note
    wild = richardson([4.0, 2.0, 1.0, 0.5], [0.0, 5.0, 3.5, 3.125])
    assert wild.limit == pytest.approx(3.0) and "coarser than the finest three" in wild.note
    assert "from 4 to 2 the difference has the other sign" in wild.note  # which levels


def test_levels_far_apart_give_an_order_not_an_overflow():
    # expm1(50 ln(1e7)) overflowed after every run had finished
    estimate = richardson([1.0, 0.1, 1e-8], [1.1, 1.01, 1.001], 1.0)
    assert estimate.order == pytest.approx(1.04, abs=0.01) and estimate.limit == pytest.approx(1.001, abs=1e-6)


def test_the_formal_order_in_dt_is_the_schemes():
    from femphase.converge import formal_order

    def settings(scheme):
        return {"numerics": {"scheme": scheme}}

    assert formal_order("dt", settings("euler")) == 1.0  # was 2 whatever the scheme
    assert formal_order("dt", settings("sav2")) == 2.0 and formal_order("dt", settings("adaptive")) == 2.0
    assert formal_order("dt", settings("euler"), method="fd") == 2.0  # the FD reference's Heun step
    assert formal_order("h", settings("euler")) == 2.0 and formal_order("tolerance_t", settings("adaptive")) == 1.0


def test_sigterm_interrupts_as_ctrl_c_and_is_recorded():
    import os
    import signal

    from femphase.cli.interrupts import sigterm_as_interrupt

    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt):
        with sigterm_as_interrupt() as terminated:
            os.kill(os.getpid(), signal.SIGTERM)  # the handler runs before the next statement
            pytest.fail("SIGTERM did not interrupt")
    assert terminated == [signal.SIGTERM] and signal.getsignal(signal.SIGTERM) is before


def test_sigint_interrupts_where_the_process_started_with_it_ignored():
    # a script's background job inherits SIGINT ignored: a sweep ran on to exit 0 through it,
    # where femphase run stopped (exit 130)
    import os
    import signal

    from femphase.cli.interrupts import sigterm_as_interrupt

    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with pytest.raises(KeyboardInterrupt):
            with sigterm_as_interrupt() as terminated:
                os.kill(os.getpid(), signal.SIGINT)
                pytest.fail("SIGINT did not interrupt")
        assert terminated == [] and signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


def test_the_notes_under_a_figure_leave_its_axes_clear(tmp_path, monkeypatch):
    # save() laid the figure out again over the whole of it: six lines of notes covered the
    # x-axis labels
    from femphase import converge
    from femphase.plot import figures

    gaps = []

    def laid_out(fig, path, rect=(0.0, 0.0, 1.0, 1.0)):
        fig.tight_layout(rect=rect)
        renderer = fig.canvas.get_renderer()
        notes_top = max(text.get_window_extent(renderer).y1 for text in fig.texts)
        gaps.append(min(ax.get_tightbbox(renderer).y0 for ax in fig.axes) - notes_top)

    monkeypatch.setattr(figures, "save", laid_out)
    levels = [{"s": s, "cpu_s": 1.0} for s in (1.0, 0.5, 0.25)]
    reason = "a long reason that wraps over two lines of the note " * 4
    estimates = {f"observable{k}": converge._without_limit(richardson([1.0, 0.5, 0.25], [1.0, 2.0, 1.5]), reason)
                 for k in range(3)}
    converge._plot(tmp_path / "convergence.png", "h", levels, estimates)
    assert gaps and gaps[0] > 0


def test_a_figure_names_the_observables_it_cannot_draw(tmp_path, monkeypatch):
    # a study with no limit wrote a blank figure, and one with some dropped the others silently
    from femphase import converge
    from femphase.plot import figures

    drawn = []
    monkeypatch.setattr(figures, "save", lambda fig, path, **layout: drawn.append(fig))
    levels = [{"s": s, "cpu_s": 1.0} for s in (1.0, 0.5, 0.25)]
    estimates = {"area": richardson([1.0, 0.5, 0.25], [3.0 + s**2 for s in (1.0, 0.5, 0.25)]),
                 "period": richardson([1.0, 0.5, 0.25], [1.0, 2.0, 1.5])}
    converge._plot(tmp_path / "convergence.png", "h", levels, estimates)
    texts = " ".join(text.get_text() for text in drawn[0].texts)
    assert "not drawn, period: the differences change sign" in texts and "area" not in texts


def test_levels_that_agree_to_1e9_are_refused_before_any_run(tmp_path):
    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    with pytest.raises(ConvergenceError, match="two agree to 1e-9"):
        run_convergence(scene, tmp_path / "study", "h", [1.0, 0.5, 0.50000000001], ["area"], workers=1,
                        log=lambda line: None)
    assert not (tmp_path / "study").exists()


def test_a_period_study_of_a_scene_without_flow_is_refused_before_any_run(tmp_path):
    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    with pytest.raises(ConvergenceError, match=r"'--observable' = 'period' is invalid: .*no phase of it has one"):
        run_convergence(scene, tmp_path / "study", "h", [1.0, 0.5], ["period"], workers=1, log=lambda line: None)
    assert not (tmp_path / "study").exists()


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    root = tmp_path_factory.mktemp("converge")
    scene = root / "disc.toml"
    scene.write_text(DISC)
    result = run_convergence(scene, root / "study", "h", [2.0, 1.0, 0.5], ["area"], workers=1, log=lambda line: None)
    return root, result


def test_a_spatial_study_of_a_relaxing_disc_converges(study):
    _, result = study
    area = result["estimates"]["area"]
    errors = np.abs(area.errors)
    assert errors[0] > errors[1] > errors[2]  # h = 2, 1, 0.5
    assert 1.5 < area.order < 4.5  # P1: second order, with the profile's pinning at h = λ on top
    values = [level["area"] for level in result["levels"]]
    assert abs(area.limit - values[-1]) < abs(values[-1] - values[-2])


def test_the_tables_hold_what_the_analysis_found_and_a_rerun_continues(study):
    import xarray as xr

    root, result = study
    rows = (root / "study" / "convergence.csv").read_text().splitlines()
    assert rows[0].startswith("observable,unit,h,run,value,uncertainty,error,cpu_s,substeps,rejected,capped,"
                              "mean_substep,order")
    assert len(rows) == 1 + 3 + 1
    # every number reads back as one: numpy's repr wrote values as "np.float64(…)"
    table = [dict(zip(rows[0].split(","), row.split(","))) for row in rows[1:]]
    assert [float(row["value"]) for row in table[:3]] == [level["area"] for level in result["levels"]]
    assert float(table[3]["limit"]) == result["estimates"]["area"].limit
    dataset = xr.open_dataset(root / "study" / "convergence.nc", engine="h5netcdf")
    np.testing.assert_allclose(dataset["limit"].sel(observable="area"), result["estimates"]["area"].limit)
    np.testing.assert_allclose(dataset["h"], [2.0, 1.0, 0.5])
    assert (root / "study" / "convergence.png").stat().st_size > 1000
    lines = []
    again = run_convergence(root / "disc.toml", root / "study", "h", [2.0, 1.0, 0.5], ["area"], workers=1,
                            log=lines.append)
    assert "3 done, 0 to run" in lines[0]
    assert again["estimates"]["area"].limit == result["estimates"]["area"].limit


# a disc of R at rest, relaxed at the default dt, then sheared: 100 time units at γ̇ = 1
SHEARED_DISC = DISC.replace("initial_radius = 4.0", "initial_radius = 8.0").replace("dt = 1.0", "dt = 10.0") + """
[[phases]]
name = "shear"
duration = 100.0
dt = 10.0
frame_interval = 50.0
flow = { type = "shear", rate = 1.0 }
"""


def test_a_tolerance_study_names_the_levels_whose_substeps_the_tolerance_did_not_set(tmp_path):
    import json

    from femphase.io.checkpoints import load_checkpoint
    from femphase.scene import load_scene

    scene = tmp_path / "sheared.toml"
    scene.write_text(SHEARED_DISC)
    result = run_convergence(scene, tmp_path / "study", "tolerance_t", [0.1, 0.03, 1e-3], ["area"], workers=1,
                             log=lambda line: None)
    levels = result["levels"]
    for level in levels:  # the counts are the run's own, per phase, and add up to the scheme's total
        directory = tmp_path / "study" / "runs" / level["run"]
        phases = json.loads((directory / "run.json").read_text())["substeps"]
        assert [record["name"] for record in phases] == ["relax", "shear"]
        assert (level["substeps"], level["rejected"]) == (phases[1]["accepted"], phases[1]["rejected"])
        assert level["mean_substep"] == pytest.approx(100.0 / phases[1]["accepted"])
        state, _ = load_checkpoint(directory / "checkpoint.h5", load_scene(scene).domain)
        assert state.memory["adaptive_counts"].tolist() == [sum(r["accepted"] for r in phases),
                                                            sum(r["rejected"] for r in phases)]
    # under shear the area-mode ceiling sets the substep at 0.1 and 0.03; 1e-3 refines it
    assert levels[0]["substeps"] == levels[1]["substeps"] < levels[2]["substeps"]
    note = result["estimates"]["area"].note
    assert "tolerance_t = 0.1 and 0.03 took the same substeps" in note and "start the study below 0.03" in note
    # a pair among the finest three: their difference is no time error, so no order and no
    # limit (with the finest two equal the study reported a limit ± 0, 0.011 off)
    assert math.isnan(result["estimates"]["area"].limit) and note.startswith("no limit: ")
    assert all(0 <= level["capped"] <= level["substeps"] for level in levels)
    header = (tmp_path / "study" / "convergence.csv").read_text().splitlines()[0]
    assert "substeps,rejected,capped,mean_substep" in header
    # an observable measured in no run says so first: the note gave the substeps alone
    from femphase.converge import analyse

    period = analyse(tmp_path / "study", "tolerance_t", ["period"])["estimates"]["period"]
    assert period.note.startswith("no limit: not measured in 3 of the 3 runs; tolerance_t = 0.1 and 0.03"), period.note


def test_a_plateau_level_among_the_finest_three_leaves_no_limit():
    # tolerance_t 0.1, 0.01, 1e-3, 3e-4: 0.1 and 0.01 took the same substeps, 0.01 is among the
    # finest three, and the limit they gave lay 0.004 from the time-converged value (order 0.34)
    from femphase.converge import plateau_among_finest

    def levels(*substeps):
        return [{"s": s, "substeps": n, "rejected": 0, "capped": 0, "mean_substep": 100.0 / n}
                for s, n in zip((0.1, 0.01, 1e-3, 3e-4, 1e-4), substeps)]

    assert plateau_among_finest(levels(451, 451, 863, 1500))
    assert plateau_among_finest(levels(300, 451, 451, 863))
    assert not plateau_among_finest(levels(451, 451, 863, 1500, 2600))  # the pair is coarser than the three
    assert not plateau_among_finest(levels(300, 451, 863, 1500))


def test_levels_with_different_substeps_get_no_note():
    from femphase.converge import same_substeps

    def level(s, substeps, rejected=0, capped=0):
        return {"s": s, "substeps": substeps, "rejected": rejected, "capped": capped, "mean_substep": 100.0 / substeps}

    assert same_substeps([level(0.1, 30), level(0.01, 31), level(1e-3, 80)]) == ""
    assert same_substeps([level(0.1, 30, 1), level(0.01, 30, 0)]) == ""  # a rejection is a different step sequence
    assert same_substeps([level(0.1, math.nan), level(0.01, math.nan)]) == ""  # schemes that do not count
    assert "0.1 and 0.01" in same_substeps([level(0.1, 30), level(0.01, 30), level(1e-3, 80)])
    assert "; a ceiling capped 12 at 0.1)" in same_substeps([level(0.1, 30, capped=12), level(0.01, 30), level(1e-3, 80)])


def test_the_command_refuses_bad_levels_and_observables_before_any_run(tmp_path):
    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    command = [sys.executable, "-m", "femphase.cli", "converge", str(scene), "-o", str(tmp_path / "s")]
    both = subprocess.run(command + ["--h", "1,0.5", "--dt", "1,0.5"], capture_output=True, text=True)
    assert both.returncode == 2 and "exactly one option with two or more values" in both.stderr
    assert "'--h 1,0.5 --dt 1,0.5'" in both.stderr
    one = subprocess.run(command + ["--h", "1"], capture_output=True, text=True)  # nothing refined: name what was given
    assert one.returncode == 2 and "'--h 1' is invalid" in one.stderr
    unknown = subprocess.run(command + ["--h", "1,0.5", "--observable", "volume"], capture_output=True, text=True)
    assert unknown.returncode == 2 and "volume" in unknown.stderr and "separation" in unknown.stderr
    twice = subprocess.run(command + ["--h", "1,0.5,1"], capture_output=True, text=True)
    assert twice.returncode == 2 and "'--h' = [1.0, 0.5, 1.0]" in twice.stderr and "distinct" in twice.stderr
    lone = subprocess.run(command + ["--h", "1,0.5", "--observable", "separation"], capture_output=True, text=True)
    assert lone.returncode == 2 and "a two-particle scene (this one has 1)" in lone.stderr
    idle = subprocess.run(command + ["--h", "1,0.5", "--workers", "0"], capture_output=True, text=True)
    assert idle.returncode == 2 and "'--workers' = 0" in idle.stderr
    gap = subprocess.run(command + ["--h", "1,,0.5"], capture_output=True, text=True)  # was read as 1,0.5
    assert gap.returncode == 2 and "'1,,0.5' has an empty entry" in gap.stderr
    assert not (tmp_path / "s" / "runs").exists()


@pytest.mark.parametrize("parameter, values, options, refusal", [
    ("h", [1.0, 0.7], {}, r"'--h' = 0\.7 is invalid: a level every run's scene accepts \(scene key 'domain\.Lx'"),
    ("dt", [1.0, 0.3], {}, r"'--dt' = 0\.3 is invalid: .*'phases\.0\.duration' = 20\.0"),
    ("h", [1.0, 0.5], {"expected_order": 0.0}, r"'--order' = 0\.0 is invalid: a finite number > 0"),
    ("h", [1.0, 0.5], {"expected_order": math.nan}, r"'--order' = nan is invalid"),
    ("tolerance_t", [0.1, 0.01], {"assignments": ["numerics.scheme='sav2'"]},
     r"the scene's numerics.scheme is \"sav2\", whose steps the tolerance does not set"),
])
def test_a_study_that_cannot_be_run_is_refused_by_its_option_before_any_run(tmp_path, parameter, values, options,
                                                                           refusal):
    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    with pytest.raises(ConvergenceError, match=refusal):
        run_convergence(scene, tmp_path / "s", parameter, values, ["area"], workers=1, log=lambda line: None,
                        **options)
    assert not (tmp_path / "s").exists()


def test_a_mesh_scene_is_refined_by_its_mesh_files(tmp_path):
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing

    files = []
    for h in (1.0, 0.7071, 0.5):
        files.append(tmp_path / f"channel_{h}.vtu")
        write_domain(files[-1], *delaunay_channel(40.0, edge_for_spacing(h), lambda x: 0 * x, lambda x: 0 * x + 40.0,
                                                  seed=1))
    scene = tmp_path / "disc.toml"
    scene.write_text(DISC.replace("Lx = 40.0\nLy = 40.0\nh = 1.0", f'kind = "mesh"\nmesh = "{files[0].name}"'))
    for levels in ([1.0, 0.5], [1.0, 0.25]):  # 0.25 is no nominal h of this mesh: named as the wrong option first
        with pytest.raises(ConvergenceError, match="--mesh FILE1"):
            run_convergence(scene, tmp_path / "wrong", "h", levels, ["area"], workers=1, log=lambda line: None)
    result = run_convergence(scene, tmp_path / "study", "mesh", [str(f) for f in files], ["area"], workers=1,
                             log=lambda line: None)
    spacings = [level["s"] for level in result["levels"]]
    np.testing.assert_allclose(spacings, [1.0, 0.7071, 0.5], rtol=0.05)  # √(area / dofs) of each mesh
    area = result["estimates"]["area"]
    assert area.order_observed and 1.0 < area.order < 3.5
    assert abs(area.errors[2]) < abs(area.errors[0])
    # a mesh file replaced after its run: the run's spacing was read from the new file
    # (order 1.90 → 6.45, no word); run.json's mesh digest refuses it
    from femphase.converge import analyse

    write_domain(files[1], *delaunay_channel(40.0, edge_for_spacing(0.85), lambda x: 0 * x, lambda x: 0 * x + 40.0,
                                             seed=1))
    with pytest.raises(ConvergenceError, match=r"'--mesh' = .*channel_0\.7071\.vtu.* it has changed since.*"
                                               r"convergence\.csv, \.nc and \.png there, if any, are an analysis from "
                                               r"before the change"):
        analyse(tmp_path / "study", "mesh", ["area"])
    # two files of one mesh: refused before any run, not after all of them
    twin = tmp_path / "twin.vtu"
    twin.write_bytes(files[0].read_bytes())
    with pytest.raises(ConvergenceError, match="one level twice"):
        run_convergence(scene, tmp_path / "twins", "mesh", [str(files[0]), str(twin)], ["area"], workers=1,
                        log=lambda line: None)
    assert not (tmp_path / "twins" / "runs").exists()


def test_the_command_prints_each_levels_substeps_for_the_adaptive_scheme(tmp_path, capsys):
    from femphase.cli import main

    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    assert main(["converge", str(scene), "--h", "2,1", "--observable", "area", "-o", str(tmp_path / "s"),
                 "--workers", "1"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("substeps in the last phase")]
    assert len(lines) == 1 and lines[0].count(";") == 3  # (mean size; capped) at h = 2 and 1
    assert main(["converge", str(scene), "--h", "2,1", "--observable", "area", "-o", str(tmp_path / "f"),
                 "--workers", "1", "--set", 'numerics.scheme="sav2"']) == 0
    assert "substeps in the last phase" not in capsys.readouterr().out  # a fixed-step scheme counts none


def test_a_dt_study_warns_under_the_adaptive_scheme_only(tmp_path):
    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    quick = ["phases.0.duration=2.0", "phases.0.frame_interval=2.0"]
    with pytest.warns(UserWarning, match="--dt with the adaptive scheme refines the outer step only"):
        run_convergence(scene, tmp_path / "adaptive", "dt", [1.0, 0.5], ["area"], quick, workers=1, log=lambda line: None)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        run_convergence(scene, tmp_path / "sav2", "dt", [1.0, 0.5], ["area"], [*quick, 'numerics.scheme="sav2"'],
                        workers=1, log=lambda line: None)


def test_a_study_whose_runs_fail_lists_them_and_exits_4(tmp_path, capsys):
    # every run blows up at its first step: the message named "scene key 'runs'" and said to
    # rerun the command, which failed the same way
    from femphase.cli import main

    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    assert main(["converge", str(scene), "-o", str(tmp_path / "s"), "--h", "1,0.5", "--workers", "1",
                 "--set", "numerics.blowup_margin=1e-9"]) == 4
    message = capsys.readouterr().err
    assert "2 of 2 runs of the study did not finish" in message and "h=1.0 failed (the run blew up" in message
    assert "start the study in a new directory" in message and "scene key" not in message


def test_a_changed_study_is_refused_in_the_terms_of_its_options(tmp_path):
    # the sweep underneath named its own keys: "sweep key 'set.phases.0.dt'" for a changed --dt
    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    quick = ["phases.0.duration=2.0", "phases.0.frame_interval=2.0"]
    run_convergence(scene, tmp_path / "study", "h", [1.0, 0.5], ["area"], [*quick, "phases.0.dt=1.0"], workers=1,
                    log=lambda line: None)
    with pytest.raises(ConvergenceError,
                       match=r"option '--dt \(or --set phases\.0\.dt\)' = 0\.5 is invalid: 1\.0 as in the study of"):
        run_convergence(scene, tmp_path / "study", "h", [1.0, 0.5], ["area"], [*quick, "phases.0.dt=0.5"],
                        workers=1, log=lambda line: None)
    # another refined option: the sweep's axis keys were shown as the value given
    with pytest.raises(ConvergenceError, match=r"option '--tolerance-t' = \[0\.1, 0\.01\] is invalid: levels of --h, "
                                               r"the option refined, as in the study of"):
        run_convergence(scene, tmp_path / "study", "tolerance_t", [0.1, 0.01], ["area"],
                        [*quick, "phases.0.dt=1.0"], workers=1, log=lambda line: None)
    # a --set of a key the study left alone: "unset as in the study"
    with pytest.raises(ConvergenceError, match=r"option '--tolerance-t \(or --set numerics\.tolerance_t\)' = 0\.01 "
                                               r"is invalid: not given \(the scene's own value\) as in the study of"):
        run_convergence(scene, tmp_path / "study", "h", [1.0, 0.5], ["area"],
                        [*quick, "phases.0.dt=1.0", "numerics.tolerance_t=0.01"], workers=1, log=lambda line: None)
    with pytest.raises(ConvergenceError,
                       match=r"option '--h' = \[1\.0, 0\.25\] is invalid: .*accepts added levels only"):
        run_convergence(scene, tmp_path / "study", "h", [1.0, 0.25], ["area"], [*quick, "phases.0.dt=1.0"],
                        workers=1, log=lambda line: None)
    # --h into a --dt study of two phases (dt zipped): "scene key 'sweep.mode' = 'product'", a key no study writes
    from femphase.converge import _study_error
    from femphase.sweep import SweepError

    mode = SweepError("sweep.mode", "product", f"'zip' as in the sweep of {tmp_path}, which accepts added values only "
                                               "(start a new directory for another sweep)")
    assert str(_study_error(mode, "--h", [1.0, 0.5])) == (
        f"option '--h' = [1.0, 0.5] is invalid: levels of the parameter the study of {tmp_path} refines, which is "
        "another; start a new directory for another study")
    # a study's directory given to femphase sweep: it named the sweep's mode and its keys
    from femphase.sweep import run_sweep

    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'[sweep]\nscene = "{scene}"\n[axes]\n"numerics.tolerance_t" = [0.1]\n')
    with pytest.raises(SweepError, match=r"option '-o' = .* is invalid: a new directory, or one of a sweep \(femphase "
                                         r"sweep\): it holds a convergence study \(femphase converge\)"):
        run_sweep(sweep, tmp_path / "study", workers=1, log=lambda line: None)


def test_a_negative_level_list_gets_the_options_own_message(tmp_path, capsys):
    # argparse read "-1,0.5" as an option: "argument --h: expected one argument" (exit 2)
    from femphase.cli import main

    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    with pytest.raises(SystemExit) as exited:
        main(["converge", str(scene), "-o", str(tmp_path / "s"), "--h", "-1,0.5"])
    assert exited.value.code == 2
    message = capsys.readouterr().err
    assert "argument --h: '-1,0.5': every value must be a finite number > 0" in message
    assert not (tmp_path / "s").exists()
    # a single bad value was refused only as a study of one level, never as a bad value
    with pytest.raises(SystemExit):
        main(["converge", str(scene), "-o", str(tmp_path / "s"), "--h", "0"])
    assert "argument --h: '0': every value must be a finite number > 0" in capsys.readouterr().err


def test_a_set_that_contradicts_a_fixed_option_is_refused(tmp_path, capsys):
    # --dt 1 --set phases.0.dt=0.5 ran at 0.5 without a word
    from femphase.cli import main

    scene = tmp_path / "disc.toml"
    scene.write_text(DISC)
    assert main(["converge", str(scene), "-o", str(tmp_path / "s"), "--h", "2,1", "--dt", "1",
                 "--set", "phases.0.dt=0.5"]) == 2
    assert ("option '--set' = 'phases.0.dt=0.5' is invalid: a key no option of the study sets: --dt sets "
            "phases.0.dt=1.0" in capsys.readouterr().err)
    assert not (tmp_path / "s").exists()
