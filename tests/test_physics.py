"""The paper's physics in miniature: a lone particle settles, a sheared lattice goes through T1s.

Both run on the coarse grid h = 2 in small channels at the paper's density and local shear
rate (γ̇/Ly as in the 70 × 240 channel at the stated γ̇), so that they take seconds.  The
full-size reproductions are verification/physics_*.py.
"""

import numpy as np

from femphase.analysis.lattice import lattice_angle, t1_event_times
from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict


def _record(scene_data: dict) -> FrameRecorder:
    scene = scene_from_dict(scene_data)
    recorder = FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [recorder])
    return recorder


def test_single_particle_in_shear_elongates_and_settles_without_oscillating():
    # 48 × 48 at wall velocity 0.2: local shear rate 0.2/48 ≈ 1/240, the paper's γ̇ = 1 in
    # its 240-wide channel (verification/physics_single.py has the full-size runs)
    recorder = _record({
        "domain": {"Lx": 48.0, "Ly": 48.0, "h": 2.0},
        "particles": {"layout": "single"},
        "output": {"fields": False},
        "phases": [
            {"duration": 100.0, "dt": 1.0, "frame_interval": 100.0},
            {"duration": 2600.0, "dt": 1.0, "frame_interval": 25.0, "flow": {"type": "shear", "rate": 0.2}},
        ],
    })
    t = recorder.times
    r = recorder.series("elongation")[:, 0]
    theta = recorder.series("orientation")[:, 0]
    late = t > t[-1] - 1000
    halves = np.array_split(r[late], 2)
    # elongated along a direction between the flow (0) and the strain axis (π/4)
    assert r[late].mean() > 1.5
    assert np.all((theta[late] > np.radians(15)) & (theta[late] < np.radians(35)))
    # settled: the mean no longer moves, and what is left is grid-crossing noise (~0.4 % on
    # this coarse grid), not an oscillation (the sheared lattice's r swings by ~100 %)
    assert abs(halves[1].mean() - halves[0].mean()) < 5e-3 * r[late].mean()
    assert np.ptp(r[late]) < 1e-2 * r[late].mean()
    assert np.ptp(theta[late]) < np.radians(0.5)


def test_sheared_hexagonal_lattice_slides_towards_square_and_exchanges_neighbours():
    # 5 per row × 4 rows in 70 × 48: the paper's lattice spacings (a = 14, Δy = 12) with the
    # walls closer; lanes slide by a/2 (the T1) after a Ly/(2 γ̇ Δy) = 140 time units
    rate, relax = 0.2, 100.0
    recorder = _record({
        "domain": {"Lx": 70.0, "Ly": 48.0, "h": 2.0},
        "particles": {"layout": "hexagonal", "N": 20, "per_row": 5},
        "output": {"fields": False},
        "phases": [
            {"duration": relax, "dt": 1.0, "frame_interval": relax},
            {"duration": 220.0, "dt": 1.0, "frame_interval": 10.0, "flow": {"type": "shear", "rate": rate}},
        ],
    })
    t = recorder.times
    centroids = [np.stack([f.shape.x, f.shape.y], axis=1) for f in recorder.frames]
    angle = np.array([lattice_angle(c, 70.0) for c in centroids])
    onset = int(np.searchsorted(t, relax))
    # hexagonal at shear onset (π/3 up to the wall rows' distortion) ...
    assert abs(angle[onset] - np.pi / 3) < 0.06
    # ... then the lanes slide: φ falls steadily towards the T1 configuration, whose angle
    # is atan(Δy/a) = 0.71 here (π/4 for the paper's square cells)
    before_t1 = (t > relax) & (t <= relax + 120)
    assert np.all(np.diff(angle[before_t1]) < 0)
    assert angle.min() < 0.76
    events = t1_event_times(centroids[onset:], t[onset:], 70.0)
    assert events.size >= 1
    # the first T1 near the geometric time of half a lattice spacing of sliding
    assert abs(events[0] - (relax + 14 * 48 / (2 * rate * 12))) < 40
    # and the lattice angle rises again after it
    assert angle[-1] > angle.min() + 0.05
