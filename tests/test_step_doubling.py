"""The adaptive scheme's step-doubling estimate (``numerics.estimate = "doubling"``): it
contains every error of the split step, and the tolerance then controls the error."""

from dataclasses import replace

import numpy as np
import pytest
from helpers import small_system

from femphase.config import Numerics
from femphase.domains.layout import largest_difference
from femphase.errors import SceneError
from femphase.flows import linear_shear
from femphase.model.parameters import ModelParameters
from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict
from femphase.timestepping.stepper import Stepper

#: the repulsion ten times the paper's: its split decay's error, which the embedded estimate
#: sees only through the midpoint step, is then a large part of the step's
STIFF = replace(ModelParameters(), repulsion=5.0)


@pytest.fixture(scope="module")
def pressed_pair():
    """Two discs 12 apart (R = 8) in a 40 × 40 channel, relaxed for 50 time units without
    flow (sav2, double precision), with the time set back to 0."""
    domain, state = small_system([[14.0, 20.0], [26.0, 20.0]], radius=8.0, initial_radius=8.0)
    Stepper(domain, STIFF, Numerics(scheme="sav2", precision="double"), 0.25, None, state.radii).step(state, 200)
    return domain, replace(state, time=0.0, step=0, memory={})


def _one_substep(domain, state, estimate: str, h: float, flow=None):
    """The adaptive scheme's one substep of h (the whole step dt = h, the controller's first
    size forced to it, a tolerance it meets) under ``flow`` (default shear at γ̇ = 1): (the
    state after it, its estimate of the substep's local error; the doubled estimate is per
    time unit, so times h)."""
    state = state.copy()
    numerics = Numerics(estimate=estimate, precision="double", tolerance_t=0.5, merged_steps=1)
    stepper = Stepper(domain, STIFF, numerics, h, flow or linear_shear(1.0, 40.0), state.radii)
    state.memory["adaptive_divisions"] = np.array([1, 0])
    stepper.step(state)
    assert state.memory["adaptive_counts"].tolist() == [1, 0]
    return state, float(state.memory["adaptive_error"][0]) * (h if estimate == "doubling" else 1.0)


@pytest.mark.parametrize("h", [0.5, 1.0])
def test_the_doubled_estimate_is_the_local_error_splitting_included(pressed_pair, h):
    # the local error against sav2 at h/128 from the same state: the embedded estimate falls
    # short of it (the split decay's error is outside it), the doubled one is it
    domain, start = pressed_pair
    reference = start.copy()
    Stepper(domain, STIFF, Numerics(scheme="sav2", precision="double"), h / 128, linear_shear(1.0, 40.0),
            reference.radii).step(reference, 128)

    def local_error(state):
        return max(np.abs(state.global_field(i) - reference.global_field(i)).max() for i in range(2))

    embedded, embedded_estimate = _one_substep(domain, start, "embedded", h)
    doubled, doubled_estimate = _one_substep(domain, start, "doubling", h)
    assert embedded_estimate < 0.8 * local_error(embedded)
    assert 0.7 < doubled_estimate / local_error(doubled) < 1.5
    assert local_error(doubled) < 0.5 * local_error(embedded)  # the halves are kept


@pytest.mark.parametrize("start", [0.0, 2.0])
def test_in_a_flow_that_changes_the_doubled_estimate_is_still_the_local_error(pressed_pair, start):
    # each advection is the velocity's mean over its own span: the whole substep's catch-up
    # advection started at the substep's start made the estimate 19–129 times the local
    # error (ω h = 0.25 here: 0.98 and 0.94 of it)
    from femphase.flows import flow_from_spec

    domain, relaxed = pressed_pair
    start_state = replace(relaxed.copy(), time=start)
    flow = flow_from_spec({"type": "oscillating_shear", "rate": 1.0, "frequency": 0.5}, domain)
    reference = start_state.copy()
    Stepper(domain, STIFF, Numerics(scheme="sav2", precision="double"), 0.5 / 128, flow,
            reference.radii).step(reference, 128)
    doubled, estimate = _one_substep(domain, start_state, "doubling", 0.5, flow)
    error = max(np.abs(doubled.global_field(i) - reference.global_field(i)).max() for i in range(2))
    assert 0.7 < estimate / error < 1.5, (estimate, error)


def test_the_whole_substep_is_taken_and_its_halves_kept(pressed_pair, monkeypatch):
    # three relaxations per attempt, of h, h/2 and h/2; the decays on both sides of each
    from femphase.timestepping.sav2 import RelaxedSAV2

    calls, relax = [], RelaxedSAV2.relax

    def recording(self, phi, layout, time, radii, r, dt, **decays):
        calls.append((time, dt, decays["decay_before"], decays["decay_after"]))
        return relax(self, phi, layout, time, radii, r, dt, **decays)

    monkeypatch.setattr(RelaxedSAV2, "relax", recording)
    _one_substep(*pressed_pair, "doubling", 1.0)
    assert calls == [(0.0, 1.0, 0.5, 0.5), (0.0, 0.5, 0.25, 0.25), (0.5, 0.5, 0.25, 0.25)]


def _collision(numerics: dict, dt: float, duration: float = 200.0, trackers=()) -> FrameRecorder:
    """The frames every 10 time units of two discs of R = 8 colliding in a shear (κ × 10,
    60 × 40 channel, the upper one 20 behind, centres 8 apart across the flow), on the whole
    channel (``numerics.windows = false``: no refits, whose cuts do not converge in time)."""
    scene = scene_from_dict({
        "domain": {"Lx": 60.0, "Ly": 40.0}, "model": {"kappa": 5.0},
        "particles": {"layout": "list", "centres": [[34.0, 16.0], [14.0, 24.0]], "initial_radius": 8.0},
        "numerics": {**numerics, "windows": False}, "output": {"fields": False, "checkpoint": False},
        "phases": [{"duration": duration, "dt": dt, "frame_interval": 10.0,
                    "flow": {"type": "shear", "rate": 1.0}}]})
    recorder = FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [recorder, *trackers])
    return recorder


def _repulsion(recorder: FrameRecorder) -> np.ndarray:
    """The repulsion energy at the frames after the first."""
    return recorder.series("repulsion", "global")[1:]


def test_with_doubling_the_error_of_a_collision_follows_the_tolerance():
    # reference: sav2 at dt = 0.0125, its error ~1.5e-6 of the largest repulsion energy
    # (order 2.0 over dt = 0.025 … 0.00625), 5 % of the tighter run's
    reference = _repulsion(_collision({"scheme": "sav2", "precision": "double"}, 0.0125))
    errors = [np.abs(_repulsion(_collision({"estimate": "doubling", "tolerance_t": tolerance}, 10.0)) - reference).max()
              / reference.max() for tolerance in (1e-4, 1e-5)]
    assert 0.8 < np.log10(errors[0] / errors[1]) < 1.4, errors


def test_with_doubling_the_substep_shrinks_through_a_collision_and_grows_once_apart():
    # the discs touch from t ≈ 30, their repulsion energy peaks at t ≈ 130, and they are apart
    # again from t ≈ 260: substeps per 10 time units 8 before, 32 during, 6 after at 1e-4
    # (benchmarks/collision_substeps.py; the embedded estimate keeps 48 from t = 30 to 300)
    from femphase.run.simulation import Tracker

    class Counts(Tracker):
        def __init__(self) -> None:
            self.accepted = []

        def frame(self, frame) -> None:
            counts = frame.state.memory.get("adaptive_phase_counts")
            self.accepted.append(0 if counts is None else int(counts[-1, 0]))

    counts = Counts()
    _collision({"estimate": "doubling", "tolerance_t": 1e-4}, 10.0, duration=300.0, trackers=[counts])
    per_frame = np.diff(counts.accepted)  # entry k: substeps from t = 10k to 10(k + 1)
    apart_before, contact, apart_after = per_frame[1:3], per_frame[10:20], per_frame[26:30]
    assert contact.min() >= 2 * apart_before.max() and contact.min() >= 3 * apart_after.max(), per_frame


def test_doubling_computes_its_flow_steps_in_double_precision():
    # the halves' difference over h would read float32 rounding as an error growing as the
    # substep shrinks (a collision at 1e-4 went to the smallest substeps in mixed precision)
    assert Numerics(tolerance_t=1e-3).single_precision_allowed("adaptive")
    assert not Numerics(tolerance_t=1e-3, estimate="doubling").single_precision_allowed("adaptive")


def test_an_unknown_estimate_is_refused_naming_the_valid_ones():
    with pytest.raises(SceneError, match=r"numerics.estimate' = 'richardson' is invalid: one of \('embedded', "
                                         r"'doubling'\)"):
        Numerics(estimate="richardson")


def test_the_largest_difference_matches_fields_on_moved_windows():
    # the halves and the whole substep may end on windows shifted apart by a column: the
    # difference is then taken dof by dof, as on the whole domain
    domain, state = small_system([[14.0, 20.0], [26.0, 20.0]], radius=8.0, initial_radius=8.0)
    layout, phi = state.flat()
    moved = state.copy()
    rng = np.random.default_rng(3)
    moved.windows[1] = replace(moved.windows[1], ix0=moved.windows[1].ix0 + 1)
    moved.fields[1] = rng.uniform(0.0, 1.0, moved.fields[1].size)
    moved_layout, moved_phi = moved.flat()
    expected = max(np.abs(state.global_field(i) - moved.global_field(i)).max() for i in range(2))
    assert largest_difference(phi, layout, moved_phi, moved_layout) == pytest.approx(expected, rel=1e-12)
    assert largest_difference(phi, layout, phi + 0.25, layout) == pytest.approx(0.25)
