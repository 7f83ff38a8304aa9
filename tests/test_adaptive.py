"""The adaptive scheme: error-controlled sav2 substeps inside each step of a phase."""

import time

import numpy as np
import pytest
from helpers import small_system

from femphase.config import Numerics
from femphase.flows import linear_shear
from femphase.model.parameters import ModelParameters
from femphase.run.simulation import Simulation, Tracker
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict
from femphase.timestepping.adaptive import AdaptiveSAV2
from femphase.model.energy import WindowedFields
from femphase.timestepping.sav2 import RelaxedSAV2
from femphase.timestepping.stepper import Stepper


class SubstepCounts(Tracker):
    """Accepted and rejected substeps in every step (from the scheme's memory)."""

    def __init__(self) -> None:
        self.per_step, self._last = [], np.zeros(2, dtype=int)

    def after_step(self, state) -> None:
        counts = state.memory["adaptive_counts"]
        self.per_step.append(counts - self._last)
        self._last = counts.copy()


def _sheared_particle(scheme: str, dt: float, tolerance: float = 1e-3, trackers=()):
    scene = scene_from_dict({
        "domain": {"Lx": 60.0, "Ly": 40.0},
        "particles": {"layout": "single", "initial_radius": 4.0},
        "numerics": {"scheme": scheme, "tolerance_t": tolerance},
        "output": {"fields": False},
        "phases": [{"duration": 60.0, "dt": dt, "frame_interval": dt},
                   {"duration": 60.0, "dt": dt, "frame_interval": dt, "flow": {"type": "shear", "rate": 0.5}}],
    })
    recorder = FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [recorder, *trackers])
    return recorder


@pytest.fixture(scope="module")
def reference():
    """sav2 at dt = 0.05: its error (order 2) is far below the adaptive runs' tolerances."""
    return _sheared_particle("sav2", 0.05)


def test_the_error_follows_the_tolerance_and_frames_stay_at_exact_times(reference):
    errors = []
    for tolerance in (1e-2, 1e-3):
        recorder = _sheared_particle("adaptive", 10.0, tolerance)
        assert list(recorder.times) == [10.0 * k for k in range(13)]  # exact frame times
        r = recorder.series("elongation")[:, 0]
        r_ref = reference.series("elongation")[::200, 0]
        errors.append(np.max(np.abs(r - r_ref)) / np.max(r_ref))
    assert errors[1] < errors[0] / 3
    assert errors[1] < 2e-3


def test_substeps_are_small_while_the_particle_grows_and_large_once_it_is_quiet():
    counts = SubstepCounts()
    _sheared_particle("adaptive", 10.0, 1e-3, [counts])
    accepted = [int(c[0]) for c in counts.per_step]
    assert accepted[0] > 2 * accepted[5]  # growth from R/2 at first, relaxed by t = 60


def test_a_too_large_first_substep_is_rejected_and_redone(reference):
    counts = SubstepCounts()
    recorder = _sheared_particle("adaptive", 60.0, 1e-3, [counts])
    assert counts.per_step[0][1] > 0  # rejected substeps in the stiff start
    r, r_ref = recorder.series("elongation")[:, 0], reference.series("elongation")[::1200, 0]
    assert np.max(np.abs(r - r_ref)) / np.max(r_ref) < 2e-3


def test_a_substep_taken_above_the_tolerance_at_the_smallest_size_is_warned():
    # at tolerance_t = 1e-12 every substep was dt/12288, taken whatever its estimate, and
    # the run ended as if the tolerance had been met
    import warnings

    from femphase.errors import StiffnessWarning
    from femphase.timestepping.adaptive import AdaptiveSAV2

    scene = scene_from_dict({
        "domain": {"Lx": 30.0, "Ly": 30.0},
        "particles": {"layout": "single", "initial_radius": 4.0},
        "numerics": {"tolerance_t": 1e-12},
        "output": {"fields": False},
        "phases": [{"duration": 2.0, "dt": 2.0, "frame_interval": 2.0}],
    })
    with pytest.warns(StiffnessWarning, match=r"tolerance_t not met: at t = 0 a substep of the smallest size "
                                              rf"dt/{AdaptiveSAV2.UNITS}") as caught:
        Simulation(scene).run(scene.initial_state(), [])
    assert sum("tolerance_t not met" in str(w.message) for w in caught) == 1  # once per phase
    with warnings.catch_warnings():
        warnings.simplefilter("error", StiffnessWarning)
        default = scene_from_dict({**scene.to_dict(), "numerics": {}})
        Simulation(default).run(default.initial_state(), [])


@pytest.mark.parametrize("estimate", ["embedded", "doubling"])
def test_a_resumed_adaptive_run_continues_bit_for_bit(tmp_path, estimate):
    from femphase.cli import main
    from femphase.io.checkpoints import load_checkpoint
    from femphase.scene import load_scene

    scene = tmp_path / "scene.toml"
    scene.write_text("""
[domain]
Lx = 40.0
Ly = 40.0
[particles]
layout = "list"
centres = [[14.0, 20.0], [27.0, 20.0]]
[numerics]
scheme = "adaptive"
estimate = "%s"
[[phases]]
duration = 60.0
dt = 10.0
frame_interval = 10.0
flow = { type = "shear", rate = 0.3 }
""" % estimate)
    assert main(["run", str(scene), "-o", str(tmp_path / "straight"), "-q"]) == 0
    assert main(["run", str(scene), "-o", str(tmp_path / "cut"), "-q", "--set", "phases.0.duration=30"]) == 0
    assert main(["run", str(scene), "-o", str(tmp_path / "cut"), "-q", "--resume"]) == 0
    for name in ("particles.csv", "global.csv"):
        assert (tmp_path / "straight" / name).read_bytes() == (tmp_path / "cut" / name).read_bytes()
    # the scheme's memory (substep level, last error, counts) came back from the checkpoint
    domain = load_scene(scene).domain
    straight, _ = load_checkpoint(tmp_path / "straight" / "checkpoint.h5", domain)
    resumed, _ = load_checkpoint(tmp_path / "cut" / "checkpoint.h5", domain)
    # (no r under flow: those substeps are plain IMEX midpoint steps)
    assert straight.memory.keys() == resumed.memory.keys() == {"adaptive_counts", "adaptive_phase_counts",
                                                               "adaptive_divisions", "adaptive_error"}
    assert all(np.array_equal(straight.memory[k], resumed.memory[k]) for k in straight.memory)


def test_each_phase_starts_the_step_controller_afresh(monkeypatch):
    # the error history of a quiet relaxation made the PI controller refine a shear's first
    # substeps, and its sticky sizes then kept them small (femphase.timestepping.adaptive.AdaptiveSAV2.start_phase)
    from femphase.timestepping.adaptive import AdaptiveSAV2

    calls, original = [], AdaptiveSAV2.start_phase

    def spy(self, state):
        before = set(state.memory)
        original(self, state)
        calls.append((state.phase, state.phase_step, before, set(state.memory)))

    monkeypatch.setattr(AdaptiveSAV2, "start_phase", spy)
    _sheared_particle("adaptive", 10.0, 1e-2)
    assert [(phase, step) for phase, step, *_ in calls] == [(0, 0), (1, 0)]
    _, _, before, after = calls[1]
    assert {"adaptive_divisions", "adaptive_error", "adaptive_counts"} <= before
    assert "adaptive_counts" in after and not after & {"adaptive_divisions", "adaptive_error"}


def test_substep_sizes_tile_the_step_and_include_thirds():
    # sizes dt/m, m = 2^k or 3·2^k, each starting at a multiple of its own length: whatever
    # sizes the controller asks for, the substeps end exactly on the step
    from femphase.timestepping.adaptive import AdaptiveSAV2 as Adaptive

    assert Adaptive.divisions_for(0.4, 0) == 3  # 1/3 of the step: the largest size ≤ 0.4
    assert Adaptive.divisions_for(1.0, 0) == 1
    assert Adaptive.divisions_for(0.3, Adaptive.UNITS // 3) == 6  # a quarter may not start at 1/3
    rng = np.random.default_rng(1)
    for _ in range(200):
        done = 0
        while done < Adaptive.UNITS:
            m = Adaptive.divisions_for(float(rng.uniform(1e-4, 1.2)), done)
            length = Adaptive.UNITS // m
            assert Adaptive.UNITS % m == 0 and done % length == 0
            done += length
        assert done == Adaptive.UNITS


@pytest.fixture
def substep_sizes(monkeypatch) -> list[float]:
    """The size of every relaxation substep taken while the test runs, in order."""
    from femphase.timestepping.sav2 import RelaxedSAV2

    sizes, relax = [], RelaxedSAV2.relax

    def recording(self, phi, layout, time, radii, r, dt, **decays):
        sizes.append(dt)
        return relax(self, phi, layout, time, radii, r, dt, **decays)

    monkeypatch.setattr(RelaxedSAV2, "relax", recording)
    return sizes


@pytest.mark.parametrize("implicit", [False, True])
def test_substeps_stay_where_the_area_mode_is_damped(substep_sizes, implicit):
    # each particle's area relaxes back at c = J0·8μ a/(πR²); the explicit midpoint step
    # damps that mode only for c·h < 2, and the estimate, small with the mode's amplitude,
    # does not stop larger substeps (μ × 10 at tolerance 0.1 drifted 3.9 % in area), so
    # substeps stay below RANK_ONE_STEP / c. With the mode implicit the estimate is blind to
    # it, and a sheared disc's area jumped by ±14 % from frame to frame at c·h ≈ 5.5: below
    # IMPLICIT_RANK_ONE_STEP / c
    from dataclasses import replace

    from helpers import small_system

    from femphase.config import Numerics
    from femphase.flows import linear_shear
    from femphase.model.parameters import ModelParameters
    from femphase.timestepping.adaptive import AdaptiveSAV2
    from femphase.timestepping.stepper import Stepper

    params = replace(ModelParameters(), area_stiffness=200.0)
    domain, state = small_system([[20.0, 20.0]], radius=8.0, initial_radius=8.0)
    stepper = Stepper(domain, params, Numerics(tolerance_t=0.1, area_implicit=implicit), 10.0,
                      linear_shear(2.0, 40.0), state.radii)
    for _ in range(3):
        area = float(np.sum(domain.operators.lumped_mass * state.global_field(0) ** 2))  # ∫φ², nodal
        step = AdaptiveSAV2.IMPLICIT_RANK_ONE_STEP if implicit else AdaptiveSAV2.RANK_ONE_STEP
        bound = step / (params.mobility * 8.0 * params.area_stiffness * area
                                              / (np.pi * 8.0**2) ** 2)
        substep_sizes.clear()
        stepper.step(state)
        assert 0.5 * bound < max(substep_sizes) <= bound  # up to the bound, not beyond


def test_flow_substeps_keep_the_split_decay_below_its_bound(substep_sizes):
    # the split repulsion's error is not in the estimate: two pressed discs at κ = 5 ended 12 %
    # off in repulsion energy at substeps of 3.33 (c·h = 17), 2.7 % below DECAY_STEP / c
    from dataclasses import replace

    params = replace(ModelParameters(), repulsion=5.0)
    domain, state = small_system([[14.0, 20.0], [26.0, 20.0]], radius=8.0, initial_radius=8.0)
    stepper = Stepper(domain, params, Numerics(), 10.0, linear_shear(1.0, 40.0), state.radii)
    layout, phi = state.flat()
    others = WindowedFields(phi, layout, state.radii).others_squared.max()
    bound = AdaptiveSAV2.DECAY_STEP / (params.mobility * 4.0 * params.repulsion / params.interface_width * others)
    assert 0.3 < others <= 1.0 and bound < 3.0  # the case: the bound binds below the default's 3.33
    stepper.step(state)
    assert 0.5 * bound < max(substep_sizes) <= bound


def test_a_checkpoint_from_before_the_thirds_resumes_at_its_substep(substep_sizes):
    # checkpoints that store the substep as "adaptive_level" k (dt/2^k, sizes of powers of two only)
    from helpers import small_system

    from femphase.config import Numerics
    from femphase.flows import linear_shear
    from femphase.model.parameters import ModelParameters
    from femphase.timestepping.stepper import Stepper

    domain, state = small_system([[20.0, 20.0]], radius=8.0, initial_radius=8.0)
    stepper = Stepper(domain, ModelParameters(), Numerics(), 2.0, linear_shear(0.5, 40.0), state.radii)
    state.memory["adaptive_level"] = np.array([3])
    stepper.step(state)
    assert substep_sizes[0] == 2.0 / 8
    assert "adaptive_level" not in state.memory and "adaptive_divisions" in state.memory


def _two_sheared(merged_steps: int, frame_interval: float = 80.0):
    """(final state, RowShift.advect calls) of two particles sheared for 16 steps of 10."""
    from femphase.domains.grid.advection import RowShift

    scene = scene_from_dict({
        "domain": {"Lx": 40.0, "Ly": 40.0},
        "particles": {"layout": "list", "centres": [[14.0, 20.0], [27.0, 20.0]]},
        "numerics": {"merged_steps": merged_steps}, "output": {"fields": False},
        "phases": [{"duration": 160.0, "dt": 10.0, "frame_interval": frame_interval,
                    "flow": {"type": "shear", "rate": 0.3}}]})
    advect, calls = RowShift.advect, []

    def counted(self, *args, **kwargs):
        calls.append(1)
        return advect(self, *args, **kwargs)

    RowShift.advect = counted
    try:
        state = Simulation(scene).run(scene.initial_state())
    finally:
        RowShift.advect = advect
    return state, len(calls)


def test_steps_merged_into_one_call_share_their_boundaries_and_stay_close_to_single_steps():
    single, single_advections = _two_sheared(merged_steps=1)
    merged, merged_advections = _two_sheared(merged_steps=8)  # 2 calls of 8 steps (frames every 80)
    assert merged.step == single.step == 16 and merged.time == single.time == 160.0
    # the same substeps; one advection per substep and one more per call instead of per step
    assert np.array_equal(merged.memory["adaptive_counts"], single.memory["adaptive_counts"])
    assert single_advections - merged_advections == 16 - 2
    difference = np.abs(merged.global_fields() - single.global_fields()).max()
    assert 0.0 < difference < 1e-3  # merged, yet the same solution to well within the scheme's error


def test_calls_end_at_frames_t1_looks_phase_ends_and_every_merged_steps():
    from types import SimpleNamespace

    scene = scene_from_dict({
        "domain": {"Lx": 40.0, "Ly": 40.0}, "particles": {"layout": "single"},
        "numerics": {"merged_steps": 4}, "output": {"fields": False, "t1_interval": 30.0},
        "phases": [{"duration": 130.0, "dt": 10.0, "frame_interval": 60.0}]})
    simulation, phase = Simulation(scene), scene.phases[0]

    def ends(t1_looks: bool) -> list[int]:
        state, out = SimpleNamespace(phase_step=0, time=0.0), []
        while state.phase_step < phase.n_steps:
            state.phase_step += simulation._steps_per_call(state, phase, t1_looks)
            state.time = 10.0 * state.phase_step
            out.append(state.phase_step)
        return out

    assert ends(False) == [4, 6, 8, 12, 13]  # every 4 steps, the frames at 6 and 12, the end at 13
    assert ends(True) == [3, 4, 6, 8, 9, 12, 13]  # and the T1 looks every 3 steps


def test_a_blow_up_inside_a_call_of_several_steps_names_its_step_and_leaves_the_state_unchanged(monkeypatch):
    from femphase.errors import BlowUpError
    from femphase.timestepping.adaptive import AdaptiveSAV2

    scene = scene_from_dict({
        "domain": {"Lx": 40.0, "Ly": 40.0}, "particles": {"layout": "single"}, "output": {"fields": False},
        "phases": [{"duration": 80.0, "dt": 10.0, "frame_interval": 80.0, "flow": {"type": "shear", "rate": 0.3}}]})
    state = scene.initial_state()
    stepper = Simulation(scene).stepper(scene.phases[0], state.radii)
    before = [f.copy() for f in state.fields]
    relax = AdaptiveSAV2.relax

    def poisoned(self, phi, layout, time, *args, **kwargs):
        new, r, error = relax(self, phi, layout, time, *args, **kwargs)
        return (new * np.nan, r, np.nan) if time >= 20.0 else (new, r, error)

    monkeypatch.setattr(AdaptiveSAV2, "relax", poisoned)
    started = time.process_time()
    with pytest.raises(BlowUpError, match="at step 3 .*after a substep of") as failure:
        stepper.step(state, 8)  # steps 1-8 in one call; the first substep from t >= 20 lies in step 3
    assert time.process_time() - started < 5.0
    # named at the substep that failed (20 → 23.3 here), not only at its step's end (t = 30)
    assert failure.value.step == 3 and 20.0 < failure.value.time < 30.0
    assert state.step == 0 and state.time == 0.0
    assert all(np.array_equal(a, b) for a, b in zip(before, state.fields))


def _relaxing_disc_areas(numerics: dict, dt: float, h: float = 1.0) -> np.ndarray:
    """A disc relaxing from R/2 in a 40 × 40 channel: its area at t = 10, 20, 50, 100
    (benchmarks/tolerance.py's disc case)."""
    scene = scene_from_dict({
        "domain": {"Lx": 40.0, "Ly": 40.0, "h": h},
        "particles": {"layout": "single", "initial_radius": 4.0},
        "numerics": numerics, "output": {"fields": False, "checkpoint": False},
        "phases": [{"duration": 100.0, "dt": dt, "frame_interval": 10.0}],
    })
    recorder = FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [recorder])
    return recorder.series("area")[[1, 2, 5, 10], 0]


@pytest.fixture(scope="module")
def relaxing_disc_reference() -> np.ndarray:
    return _relaxing_disc_areas({"scheme": "sav2"}, 0.05)  # second order: ~1e-5 from converged


def test_the_global_error_of_a_relaxing_disc_is_proportional_to_the_tolerance(relaxing_disc_reference):
    # without flow the scheme allows 0.01·(tolerance_t/0.1)^(3/4): 6e-3 … 3.3e-4 per substep here
    tolerances = np.array([5e-2, 5e-3, 5e-4])
    errors = np.array([np.max(np.abs(_relaxing_disc_areas({"tolerance_t": t}, 10.0) - relaxing_disc_reference))
                       for t in tolerances])
    slope = np.polyfit(np.log(tolerances), np.log(errors), 1)[0]
    assert 0.8 < slope < 1.2, (slope, errors)


def test_the_default_time_error_of_a_relaxing_disc_is_below_its_spatial_error(relaxing_disc_reference):
    """The default tolerance's purpose (Numerics.STILL_FRACTION): at h = 1 the time error
    stays below the h-error, here its lower bound, the difference to h = 0.5, at every time."""
    time_error = np.abs(_relaxing_disc_areas({}, 10.0) - relaxing_disc_reference)
    spatial_error = np.abs(_relaxing_disc_areas({"scheme": "sav2"}, 0.05, h=0.5) - relaxing_disc_reference)
    assert np.all(time_error < spatial_error), (time_error, spatial_error)


@pytest.mark.parametrize("still, tolerance, allowed", [(False, 0.2, 0.2), (False, 1e-3, 1e-3),
                                                      (True, 0.1, 0.01), (True, 1e-3, 1e-3 * 10**-0.5),
                                                      (True, 1e-5, 1e-5), (True, 0.5, 0.01 * 5**0.75)])
def test_phases_without_flow_allow_a_tenth_at_the_default_and_the_tolerance_to_the_power_three_quarters(
        still, tolerance, allowed):
    # without flow 0.01·(tolerance_t/0.1)^(3/4): each decade of tolerance_t is 10^(3/4) there
    from helpers import small_system

    from femphase.config import Numerics
    from femphase.flows import linear_shear
    from femphase.model.parameters import ModelParameters
    from femphase.timestepping.stepper import Stepper

    domain, state = small_system([[20.0, 20.0]], radius=8.0, initial_radius=8.0)
    flow = None if still else linear_shear(0.1, 40.0)
    stepper = Stepper(domain, ModelParameters(), Numerics(tolerance_t=tolerance), 10.0, flow, state.radii)
    assert stepper.scheme.tolerance == pytest.approx(allowed, rel=1e-12)


def test_the_default_tolerance_without_flow_is_a_tenth_to_the_last_bit():
    # the power about the default leaves every default run as it was
    from femphase.config import Numerics

    assert Numerics().substep_tolerance(True) == Numerics().tolerance_t * 0.1


def _drifting_pair(duration: float, merged_steps: int = 8):
    """Two discs of R = 8 pushed apart across a 27-wide channel, no flow: a quiet relaxation
    whose estimate falls below the tolerance as the drift slows."""
    scene = scene_from_dict({
        "domain": {"Lx": 27.0, "Ly": 120.0},
        "particles": {"layout": "list", "centres": [[13.5, 50.0], [13.5, 70.0]], "initial_radius": 8.0},
        "numerics": {"merged_steps": merged_steps},
        "output": {"fields": False, "checkpoint": False},
        "phases": [{"duration": duration, "dt": 10.0, "frame_interval": duration}],
    })
    state = scene.initial_state()
    Simulation(scene).run(state)
    return state.memory["adaptive_phase_counts"][0]


def test_capped_counts_the_substeps_whose_size_the_area_mode_ceiling_set(monkeypatch):
    from femphase.timestepping.adaptive import AdaptiveSAV2

    # the controller's wish against the bound, in units of dt: 0.45 is 4.5 time units (m = 3
    # gives 3.33 either way), 0.55 would be 5 (m = 2), which a ceiling of 0.375 cuts to 3.33
    assert AdaptiveSAV2.capped_divisions(0.45, 0.375, 0) == (3, False)
    assert AdaptiveSAV2.capped_divisions(0.55, 0.375, 0) == (3, True)
    assert AdaptiveSAV2.capped_divisions(0.55, np.inf, 0) == (2, False)
    accepted, rejected, capped = _drifting_pair(3000.0)
    assert 0 < capped < accepted
    # a capped substep that ends one stepper call starts the next one capped: calls of one
    # step (three substeps) count what calls of eight do
    assert _drifting_pair(3000.0, merged_steps=1).tolist() == [accepted, rejected, capped]
    monkeypatch.setattr(AdaptiveSAV2, "RANK_ONE_STEP", 1e9)  # the ceiling out of reach
    accepted_free, _, capped_free = _drifting_pair(3000.0)
    assert capped_free == 0 and accepted_free < accepted  # the capped substeps grow without it


# -- the controller's constants, pinned (an outside mutation check changed each unseen) ---------

def _scripted(monkeypatch, errors, dt=2.0):
    """A sheared disc's stepper whose relax reports ``errors`` in turn (the last repeated),
    without the area-mode ceiling; the substeps it is asked for are recorded."""
    sizes, relax = [], RelaxedSAV2.relax
    def fake(self, phi, layout, time, radii, r, h, **decays):
        sizes.append(h)
        new, r_next, _ = relax(self, phi, layout, time, radii, r, h, **decays)
        return new, r_next, errors[min(len(sizes) - 1, len(errors) - 1)]
    monkeypatch.setattr(RelaxedSAV2, "relax", fake)
    monkeypatch.setattr(AdaptiveSAV2, "RANK_ONE_STEP", 1e9)
    domain, state = small_system([[20.0, 20.0]], radius=8.0, initial_radius=8.0)
    stepper = Stepper(domain, ModelParameters(), Numerics(tolerance_t=0.1), dt, linear_shear(0.5, 40.0), state.radii)
    return stepper, state, sizes


def test_a_phase_starts_at_a_quarter_step(monkeypatch):
    # pins FIRST = 4, the documented first substep dt/4
    stepper, state, sizes = _scripted(monkeypatch, [1e-14])
    stepper.step(state)
    assert sizes[0] == 2.0 / 4


def test_growth_after_a_quiet_substep_is_four_fold(monkeypatch):
    # pins GROWTH = 4: an error of 0.05 keeps dt/4 (factor 0.9·2^0.4·(prev/tol)^0.155 ≈ 1.19, then
    # ≈ 1.07, short of 4/3); after 1e-14 the factor is clipped to 4: dt/4 → dt
    stepper, state, sizes = _scripted(monkeypatch, [0.05, 0.05, 0.05, 1e-14])
    stepper.step(state)
    assert sizes == [0.5] * 4
    # min(GROWTH, huge) = 4: dt/4 grows to dt/1 at the step's end
    assert int(state.memory["adaptive_divisions"][0]) == 1


def test_a_zero_estimate_does_not_cut_the_next_substep_to_the_shrink_bound(monkeypatch):
    # an estimate of 0 in the fields' precision (floored at 1e-14) fed the proportional term
    # (1e-13)^0.155 = 0.01: after it an error of 0.003 (3 % of the tolerance) gave the factor
    # 0.9·33^0.4·0.01 = 0.038, clipped to 0.2, and substeps fell fivefold (a mesh run took
    # substeps of 0.005). Read at ERROR_FLOOR = 1e-4 of the tolerance the factor is
    # 0.9·33^0.4·(1e-4)^0.155 ≈ 0.89. dt/4 (quiet, but a larger size cannot start at dt/4),
    # dt/4 with the error 0.003, then the largest size ≤ 0.89·dt/4 that starts at dt/2: dt/6
    # (with the 1e-14 read as it is, 0.2·dt/4 → dt/24)
    stepper, state, sizes = _scripted(monkeypatch, [1e-14, 0.003])
    stepper.step(state)
    assert sizes[:3] == [0.5, 0.5, 2.0 / 6]


def test_a_step_inside_a_merged_call_starts_under_its_own_ceiling(monkeypatch):
    # the ceiling was recomputed at a step boundary inside a call but the next substep had
    # been chosen under the old one: a whole step ran as one substep of 4× the new ceiling
    stepper, state, sizes = _scripted(monkeypatch, [1e-14])
    ceilings = iter([100.0, 0.5, 0.5, 0.5])
    monkeypatch.setattr(AdaptiveSAV2, "largest_substep", lambda self, *args: next(ceilings))
    stepper.step(state, 2)
    assert sum(sizes) == pytest.approx(4.0)
    second, done = [], 0.0
    for size in sizes:
        if done >= 2.0 - 1e-12:
            second.append(size)
        done += size
    assert second and max(second) <= 0.5


def test_a_stored_zero_error_is_read_at_the_floor(monkeypatch):
    # checkpoints written before the floor hold 1e-14: a resume cut its first substep fivefold
    stepper, state, sizes = _scripted(monkeypatch, [0.003])
    state.memory["adaptive_divisions"] = np.array([4, 0])
    state.memory["adaptive_error"] = np.array([1e-14])
    stepper.step(state)
    # factor 0.89 as after a floored quiet substep: the largest size ≤ 0.89·dt/4 that starts at
    # dt/4 is dt/8 (read at 1e-14, 0.2·dt/4 → dt/24)
    assert sizes[:2] == [0.5, 2.0 / 8]


def test_the_split_decay_ceiling_reads_the_rate_the_decay_integrates(monkeypatch):
    # with two decay terms the ceiling took the larger of their rates, the decay their sum
    from helpers import small_system

    params = ModelParameters()
    domain, state = small_system([[14.0, 20.0], [26.0, 20.0]], radius=8.0, initial_radius=8.0)
    stepper = Stepper(domain, params, Numerics(), 10.0, linear_shear(1.0, 40.0), state.radii)
    monkeypatch.setattr(RelaxedSAV2, "decay_rate", lambda self, fields: np.full(fields.phi.shape, 40.0))
    layout, phi = state.flat()
    assert stepper.scheme.largest_substep(phi, layout, state.radii) == pytest.approx(
        AdaptiveSAV2.DECAY_STEP / (params.mobility * 40.0))


def test_a_rejected_substep_far_above_the_tolerance_shrinks_by_shrink(monkeypatch):
    # pins the rejection's (tol/err)^0.5 and its floor 0.2
    stepper, state, sizes = _scripted(monkeypatch, [10.0, 1e-14])
    stepper.step(state)
    # factor = max(0.2, 0.9 (0.1/10)^0.5 = 0.09) = 0.2: 0.2·dt/4 = dt/20, the largest size ≤ that is dt/24
    assert sizes[:2] == [0.5, 2.0 / 24]


def test_the_area_ceiling_follows_the_fastest_particle():
    # pins the ceiling's max over particles (a mean gave a larger bound), from the rate
    # c_i = J0·8μ·∫φ_i²/(πR²)² computed here
    params = ModelParameters()
    domain, state = small_system([[20.0, 20.0], [20.0, 60.0]], width=80.0, radius=8.0, initial_radius=8.0)
    stepper = Stepper(domain, params, Numerics(), 2.0, linear_shear(0.5, 80.0), state.radii)
    layout, phi = state.flat()
    phi = phi.copy()
    first = slice(layout.offsets[0], layout.offsets[1])
    phi[first] *= 0.5
    areas = np.array([np.sum(layout.mass[layout.offsets[i]:layout.offsets[i + 1]] * phi[layout.offsets[i]:layout.offsets[i + 1]] ** 2) for i in range(2)])
    rates = params.mobility * 8.0 * params.area_stiffness * areas / (np.pi * 8.0**2) ** 2
    assert rates.max() > 1.5 * rates.min()
    assert stepper.scheme.largest_substep(phi, layout, state.radii) == pytest.approx(1.5 / rates.max(), rel=1e-6)
