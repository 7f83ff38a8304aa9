"""The adaptive scheme: error-controlled sav2 substeps inside each step of a phase."""

import numpy as np
import pytest

from femphase.scene import scene_from_dict
from femphase.simulation import FrameRecorder, Simulation, Tracker


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
