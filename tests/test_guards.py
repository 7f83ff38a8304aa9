"""Accuracy guards: runs outside the envelope of benchmarks/stability.py warn (or, strict,
stop), naming the scene key and the value that brings them back; normal runs stay silent."""

import json
import warnings

import numpy as np
import pytest

from femphase.errors import FemphaseError, SceneError
from femphase.run.directory import RunDirectory
from femphase.run.guards import (
    SLOWDOWN_LIMIT,
    AccuracyError,
    AccuracyGuard,
    AccuracyWarning,
    advective_spread,
    area_ratios,
    relaxation_time,
    step_measures,
)
from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict

SLAB = {"domain": {"Lx": 70.0, "Ly": 24.0, "h": 1.0}, "particles": {"layout": "hexagonal", "N": 10}}
PAIR = {"domain": {"Lx": 40.0, "Ly": 30.0}, "particles": {"layout": "list", "centres": [[10.0, 15.0], [30.0, 15.0]]}}


def scene(tables, phases, **numerics):
    """A scene with the first-order scheme unless ``numerics`` names another: the saturation
    these guards watch is that scheme's stabilisation."""
    return scene_from_dict({"name": "guard", **tables, "numerics": {"scheme": "euler", **numerics},
                            "output": {"fields": False}, "phases": phases})


def run(sc, guard=None, trackers=()):
    """Run ``sc`` with an AccuracyGuard; returns (guard, AccuracyWarnings raised)."""
    guard = guard or AccuracyGuard()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        Simulation(sc).run(sc.initial_state(), [*trackers, guard])
    return guard, [w for w in caught if issubclass(w.category, AccuracyWarning)]


def phase(duration, dt, every=None, **flow):
    out = {"duration": duration, "dt": dt, "frame_interval": every or duration}
    if flow:
        out["flow"] = flow
    return out


def test_measures_at_the_paper_parameters():
    sc = scene(PAIR, [phase(10.0, 10.0)])
    m = step_measures(sc, sc.phases[0], sc.radii)
    assert m.dt_star == pytest.approx(0.923, abs=1e-3)  # 2/(J0 L), several particles
    assert m.slowdown == pytest.approx(10.0 / m.dt_star)  # dt/dt* for the lumped "auto"
    assert m.explicit_fraction == pytest.approx(m.slowdown)
    assert m.accurate_dt == pytest.approx(SLOWDOWN_LIMIT * m.dt_star)
    single = step_measures(sc, sc.phases[0], np.array([8.0]))
    assert single.dt_star == pytest.approx(3.0, abs=1e-2)  # no repulsion curvature for one particle
    # the default dt = 1 is inside the envelope, the consistent mass at dt = 1 is not
    assert step_measures(sc, scene(PAIR, [phase(1.0, 1.0)]).phases[0], sc.radii).slowdown < SLOWDOWN_LIMIT
    consistent = scene(PAIR, [phase(1.0, 1.0)], mass="consistent")
    assert step_measures(consistent, consistent.phases[0], sc.radii).slowdown == pytest.approx(1.83, abs=0.01)
    fixed = scene(PAIR, [phase(1.0, 1.0)], stabilisation=0.5)
    assert step_measures(fixed, fixed.phases[0], sc.radii).slowdown == pytest.approx(1.25)


def test_the_stepper_uses_the_stabilisation_the_guard_measures():
    sc = scene(PAIR, [phase(10.0, 10.0)])
    simulation = Simulation(sc)
    scheme = simulation.stepper(sc.phases[0], sc.radii).scheme
    m = step_measures(sc, sc.phases[0], sc.radii)
    assert scheme.stabilisation == pytest.approx(m.stabilisation)
    assert scheme.relaxation_slowdown == pytest.approx(m.slowdown)
    assert scheme.stability_step == pytest.approx(m.dt_star)


def test_saturation_warns_at_dt_10_and_not_at_dt_half():
    guard, caught = run(scene(PAIR, [phase(20.0, 10.0, 10.0)]))
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "phases.0.dt" in message and "10.8" in message  # the factor dt/dt*
    assert "phases.0.dt ≤ 1" in message  # the value back inside the envelope: 1.1 dt*
    assert [(i.kind, i.key, i.step) for i in guard.issues] == [("saturation", "phases.0.dt", 0)]
    guard, caught = run(scene(PAIR, [phase(5.0, 0.5, 2.5)]))
    assert caught == [] and guard.issues == []


def test_each_warning_once_per_phase():
    sc = scene(PAIR, [phase(40.0, 10.0, 10.0), phase(40.0, 10.0, 10.0)])
    guard, caught = run(sc)
    assert [(i.kind, i.phase) for i in guard.issues] == [("saturation", 0), ("saturation", 1)]
    assert len(caught) == 2 and "phases.1.dt" in str(caught[1].message)


def test_strict_turns_the_warning_into_an_error_before_the_bad_phase_steps():
    sc = scene(PAIR, [phase(2.0, 0.5), phase(20.0, 10.0)], strict=True)
    state = sc.initial_state()
    with pytest.raises(AccuracyError) as info:
        Simulation(sc).run(state, [AccuracyGuard()])
    error = info.value
    assert isinstance(error, FemphaseError)
    assert (error.step, error.time) == (4, 2.0) and state.step == 4  # phase 1 never stepped
    assert "step 4 (t = 2)" in str(error) and "phases.1.dt" in str(error)
    # an explicit argument overrides the scene
    _guard, caught = run(sc, AccuracyGuard(strict=False))
    assert len(caught) == 1


def test_strict_run_directory_records_the_failure(tmp_path):
    sc = scene(PAIR, [phase(20.0, 10.0)], strict=True)
    with pytest.raises(AccuracyError):
        Simulation(sc).run(sc.initial_state(), [RunDirectory(tmp_path / "run"), AccuracyGuard()])
    status = json.loads((tmp_path / "run" / "run.json").read_text())
    assert status["status"] == "failed" and "phases.0.dt" in status["message"]


def test_strict_must_be_a_boolean():
    with pytest.raises(SceneError, match="numerics.strict"):
        scene(PAIR, [phase(1.0, 1.0)], strict="yes")


def test_a_stiff_repulsion_warns_and_names_kappa():
    sc = scene({**PAIR, "model": {"kappa": 1e5}}, [phase(20.0, 10.0, 10.0)])
    guard, caught = run(sc)
    message = str(caught[0].message)
    assert "phases.0.dt" in message and "model.kappa" in message
    assert guard.issues[0].kind == "saturation"


def test_saturated_relaxation_also_fails_the_area_check_after_the_relaxation_time():
    sc = scene({**PAIR, "model": {"kappa": 1e5}}, [phase(150.0, 10.0, 50.0)])
    assert relaxation_time(sc) == pytest.approx(40 * np.pi * 64 / (8 * 0.5 * 20))  # 100.5 time units
    guard, _ = run(sc)
    area = [i for i in guard.issues if i.kind == "area"]
    assert len(area) == 1 and area[0].time == 150.0 and area[0].key == "phases.0.dt"


def test_a_normal_run_of_the_paper_parameters_is_silent():
    # relaxation, then the paper's shear, past the start of the area check, at the default dt = 1
    sc = scene(SLAB, [phase(120.0, 1.0, 40.0), phase(60.0, 1.0, 20.0, type="shear", rate=0.1487)])
    recorder = FrameRecorder()
    guard, caught = run(sc, trackers=[recorder])
    assert caught == [] and guard.issues == []
    assert 0.8 < area_ratios(recorder.frames[-1].state).min() < 1.0


def test_a_flow_beyond_the_measured_strain_rates_warns_on_the_areas_and_names_its_rate():
    sc = scene(SLAB, [phase(100.0, 1.0, 50.0),
                      phase(50.0, 0.5, 25.0, type="shear", rate=0.2, scale="shear_rate")])
    guard, caught = run(sc)
    assert [(i.kind, i.key) for i in guard.issues] == [("area", "phases.1.flow.rate")]
    assert "phases.1.flow.rate ≤ 0.04" in str(caught[0].message)


def test_advection_beyond_the_window_margin_warns():
    single = {"domain": {"Lx": 40.0, "Ly": 40.0}, "particles": {"layout": "single", "initial_radius": 8.0}}
    sc = scene(single, [phase(4.0, 2.0, 2.0, type="shear", rate=0.2, scale="shear_rate")])
    state = sc.initial_state()
    velocity = np.stack([0.2 * sc.domain.coordinates[1], 0 * sc.domain.coordinates[1]])
    spread = advective_spread(state, velocity, 2.0, 0.01)[0]
    assert spread == pytest.approx(2.0 * 0.2 * (8 + 2 * np.arctanh(0.98)), rel=0.1)  # dt · G · reach
    guard, caught = run(sc)
    assert [(i.kind, i.key, i.step) for i in guard.issues] == [("advection", "phases.0.dt", 0)]
    assert "numerics.margin" in str(caught[0].message)
    guard, caught = run(scene(single, [phase(4.0, 1.0, 2.0, type="shear", rate=0.2, scale="shear_rate")]))
    assert guard.issues == []


def test_loose_tolerances_below_h_half_warn_and_name_the_tolerance():
    fine = scene({"domain": {"Lx": 30.0, "Ly": 30.0, "h": 0.4}, "particles": {"layout": "single"}},
                 [phase(10.0, 10.0), phase(10.0, 10.0, type="shear", rate=0.1)], scheme="adaptive")
    guard, caught = run(fine)
    assert [issue.kind for issue in guard.issues] == ["fine grid"] and guard.issues[0].key == "numerics.tolerance_t"
    assert guard.issues[0].phase == 1  # the still phase does not warn
    assert "numerics.tolerance_t ≤ 0.01" in str(caught[0].message)
    coarse = scene({"domain": {"Lx": 30.0, "Ly": 30.0, "h": 0.5}, "particles": {"layout": "single"}},
                   [phase(10.0, 10.0, type="shear", rate=0.1)], scheme="adaptive")
    tight = scene({"domain": {"Lx": 30.0, "Ly": 30.0, "h": 0.4}, "particles": {"layout": "single"}},
                  [phase(10.0, 10.0, type="shear", rate=0.1)], scheme="adaptive", tolerance_t=0.01)
    assert not run(coarse)[0].issues and not run(tight)[0].issues


def test_a_mesh_is_judged_fine_by_its_node_density_not_its_longer_edges(tmp_path):
    """A Delaunay mesh made for h = 0.475 has the grid's node density at 0.475 but edges of
    about 0.51: the fine-grid check (below h = 0.5), like the resolution check, counts its nodes."""
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing

    write_domain(tmp_path / "fine.vtu", *delaunay_channel(20.0, edge_for_spacing(0.475), lambda x: 0 * x,
                                                         lambda x: 0 * x + 20.0, seed=1))
    fine = scene_from_dict({"domain": {"kind": "mesh", "mesh": "fine.vtu"}, "particles": {"layout": "single"},
                            "model": {"R": 5.0}, "output": {"fields": False},
                            "phases": [phase(10.0, 10.0, type="shear", rate=0.1)]}, tmp_path)
    assert fine.domain.spacing > 0.5 > fine.domain.resolution
    guard, _ = run(fine)
    assert [issue.kind for issue in guard.issues] == ["fine grid"]


def test_a_vanishing_particle_warns_once_and_names_the_area_term():
    # μ = 0: a disc of R = 3 shrinks by its curvature and is gone (area < 1e-29) by t = 300
    single = {"domain": {"Lx": 40.0, "Ly": 40.0}, "particles": {"layout": "single"},
              "model": {"radius": 3.0, "mu": 0.0}}
    sc = scene(single, [phase(400.0, 10.0, 50.0)], scheme="adaptive")
    recorder = FrameRecorder()
    guard, caught = run(sc, trackers=[recorder])
    vanished = [i for i in guard.issues if i.kind == "vanished"]
    area = recorder.series("area")[:, 0] / (np.pi * 9.0)
    first = recorder.times[np.argmax(area < 0.01)]
    assert len(vanished) == 1 and len(caught) == 1 and vanished[0].time == first and vanished[0].key == "model.mu"
    assert "particle 0 has vanished" in str(caught[0].message) and "model.mu = 0" in str(caught[0].message)


def test_a_vanishing_particle_stops_a_strict_run():
    single = {"domain": {"Lx": 40.0, "Ly": 40.0}, "particles": {"layout": "single"},
              "model": {"radius": 3.0, "mu": 0.0}}
    sc = scene(single, [phase(400.0, 10.0, 50.0)], scheme="adaptive", strict=True)
    with pytest.raises(AccuracyError, match="vanished"):
        Simulation(sc).run(sc.initial_state(), [AccuracyGuard()])


def test_saturation_warns_at_1_15_dt_star():
    # pins SLOWDOWN_LIMIT = 1.1: the other tests' dt/dt* was far above it, and their message
    # check 'phases.0.dt ≤ 1' matched a limit of 1.2's '≤ 1.1' as well
    base = scene(PAIR, [phase(1.0, 1.0)])
    dt_star = step_measures(base, base.phases[0], base.radii).dt_star
    dt = 1.15 * dt_star  # slowdown dt/dt* = 1.15 > 1.1
    guard, caught = run(scene(PAIR, [phase(3 * dt, dt)]))
    assert [i.kind for i in guard.issues] == ["saturation"]


def test_the_strain_rate_remedy_names_the_envelope_value():
    # pins STRAIN_RATE_ENVELOPE = 10/240: 'rate ≤ 0.04' matched the messages of 0.041 and 0.049
    sc = scene(SLAB, [phase(100.0, 1.0, 50.0), phase(50.0, 0.5, 25.0, type="shear", rate=0.2, scale="shear_rate")])
    guard, caught = run(sc)
    assert "exceeds the strongest measured one, 0.0417" in str(caught[0].message)  # 10/240 = 0.041666…


def test_a_vanishing_particle_is_reported_at_the_first_frame_below_a_hundredth():
    # pins VANISHED_RATIO = 0.01: frames 50 apart jumped from above 0.01 to below 1e-29
    single = {"domain": {"Lx": 40.0, "Ly": 40.0}, "particles": {"layout": "single"}, "model": {"radius": 3.0, "mu": 0.0}}
    recorder = FrameRecorder()
    guard, caught = run(scene(single, [phase(400.0, 1.0, 1.0)], scheme="adaptive"), trackers=[recorder])
    area = recorder.series("area")[:, 0] / (np.pi * 9.0)
    below = np.flatnonzero(area < 0.01)
    assert area[below[0]] > 0.001  # a frame between the two thresholds exists
    vanished = [i for i in guard.issues if i.kind == "vanished"]
    assert vanished[0].time == recorder.times[below[0]]
