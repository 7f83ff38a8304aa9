"""Flows that depend on time: v(x, y, t), on the structured channel and on a mesh.

In oscillatory shear u = γ̇ sin(ωt) y/Ly a particle at height y0 moves by
x(t) − x(0) = γ̇ y0 (1 − cos ωt)/(Ly ω): 2γ̇ y0/(Ly ω) at half a period, back to zero after a
whole one. Both advections take the velocity's mean over each step (three-point
Gauss–Legendre), exact in time for a flow of fixed direction field up to the rule's error.
"""

import numpy as np
import pytest

from femphase.domains.mesh.domain import write_domain
from femphase.domains.mesh.generation import structured_channel
from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict

RATE, PERIOD, LX, LY = 0.4, 40.0, 60.0, 40.0


def _displacements(domain: dict) -> np.ndarray:
    scene = scene_from_dict({
        "domain": domain,
        "particles": {"layout": "list", "centres": [[30.0, 20.0]], "initial_radius": 8.0},
        "output": {"fields": False},
        "phases": [{"duration": PERIOD, "dt": 1.0, "frame_interval": PERIOD / 2,
                    "flow": {"type": "oscillating_shear", "rate": RATE, "frequency": 2 * np.pi / PERIOD}}],
    })
    recorder = FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [recorder])
    x = recorder.series("x")[:, 0]
    return x - x[0]


def test_oscillating_shear_moves_a_particle_there_and_back_on_the_grid():
    half = 2 * RATE * 20.0 / (LY * 2 * np.pi / PERIOD)
    moved = _displacements({"Lx": LX, "Ly": LY})
    assert moved[1] == pytest.approx(half, rel=1e-2)
    assert abs(moved[2]) < 1e-2 * half


def test_oscillating_shear_moves_a_particle_there_and_back_on_a_mesh(tmp_path):
    mesh, boundaries = structured_channel(LX, LY, 1.0)
    write_domain(tmp_path / "channel.vtu", mesh, boundaries)
    half = 2 * RATE * 20.0 / (LY * 2 * np.pi / PERIOD)
    moved = _displacements({"kind": "mesh", "mesh": str(tmp_path / "channel.vtu")})
    assert moved[1] == pytest.approx(half, rel=3e-2)
    assert abs(moved[2]) < 3e-2 * half


def test_a_time_dependent_flow_is_rejected_with_its_key_when_a_key_is_missing():
    from femphase.errors import SceneError

    with pytest.raises(SceneError, match="phases.0.flow.frequency"):
        scene_from_dict({"domain": {"Lx": LX, "Ly": LY}, "particles": {"layout": "single"},
                         "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0,
                                     "flow": {"type": "oscillating_shear", "rate": 0.1}}]})


def test_flows_measure_y_from_the_lower_wall_and_the_oscillation_from_its_phase():
    # every test's lower wall was at y = 0, where y − y0 is y: dropping y0 from the shear, or
    # its sign in Poiseuille, went unseen, and so did the sign of the oscillation's phase
    from skfem import MeshTri

    from femphase.domains.mesh.domain import MeshDomain
    from femphase.flows import flow_from_spec

    mesh, _ = structured_channel(20.0, 12.0, 1.0)
    domain = MeshDomain.from_mesh(MeshTri(mesh.p + np.array([[0.0], [-4.0]]), mesh.t))  # walls at y = −4 and 8
    y = np.array([-4.0, 2.0, 8.0])
    x = np.zeros_like(y)
    shear = flow_from_spec({"type": "shear", "rate": 0.3}, domain)
    np.testing.assert_allclose(shear.velocity(x, y, 0.0)[0], [0.0, 0.15, 0.3], atol=1e-15)
    plain = flow_from_spec({"type": "shear", "rate": 0.3, "scale": "shear_rate"}, domain)
    np.testing.assert_allclose(plain.velocity(x, y, 0.0)[0], [0.0, 1.8, 3.6], atol=1e-14)
    poiseuille = flow_from_spec({"type": "poiseuille", "rate": 0.3}, domain)
    np.testing.assert_allclose(poiseuille.velocity(x, y, 0.0)[0], [0.0, 0.3, 0.0], atol=1e-15)
    omega, start = 0.2, 7.0  # φ0 = −ωT starts the oscillation from rest at the run's time T
    oscillating = flow_from_spec({"type": "oscillating_shear", "rate": 0.3, "frequency": omega,
                                  "phase": -omega * start}, domain)
    np.testing.assert_allclose(oscillating.velocity(x, y, start)[0], 0.0, atol=1e-15)
    quarter = start + 0.5 * np.pi / omega
    np.testing.assert_allclose(oscillating.velocity(x, y, quarter)[0], [0.0, 0.15, 0.3], atol=1e-15)


def _oscillation(domain, omega: float = 2 * np.pi / 10.0, phase: float = 0.3):
    from femphase.flows import flow_from_spec

    return flow_from_spec({"type": "oscillating_shear", "rate": 20.0, "frequency": omega, "phase": phase}, domain)


def test_a_row_shift_in_an_oscillating_shear_moves_each_row_by_its_integral():
    # a substep of 3.33 in a shear of period 10 moved rows by the midpoint velocity times
    # the step, 17 % short (sin(ωs/2)/(ωs/2)); a lone disc ended 13 % over-elongated at dt = 10
    from femphase.domains.grid.advection import RowShift
    from femphase.domains.grid.domain import GridDomain
    from femphase.domains.grid.lattice import channel_grid

    domain = GridDomain(channel_grid(40.0, 30.0, 1.0))
    omega, phase, start, span = 2 * np.pi / 10.0, 0.3, 101.0, 10.0 / 3.0
    flow = _oscillation(domain, omega, phase)
    _, y = domain.grid.coordinates()
    exact = 20.0 * y / 30.0 * (np.cos(omega * start + phase) - np.cos(omega * (start + span) + phase)) / omega
    shift = RowShift(domain, flow, span)._row_shift(start)
    np.testing.assert_allclose(shift, exact / domain.grid.h, rtol=1e-4, atol=1e-12)


def test_a_mesh_advection_matrix_over_a_step_is_the_mean_of_the_flows():
    # C is linear in v: in v = f(t) w(x) its mean over a step is C(w) times the mean of f
    from femphase.domains.mesh.advection import advection_matrix
    from femphase.domains.mesh.domain import MeshDomain
    from femphase.flows import linear_shear

    domain = MeshDomain.from_mesh(structured_channel(20.0, 12.0, 1.0)[0])
    omega, phase, start, span = 2 * np.pi / 10.0, 0.3, 101.0, 10.0 / 3.0
    mean = (np.cos(omega * start + phase) - np.cos(omega * (start + span) + phase)) / (omega * span)
    steady = advection_matrix(domain, linear_shear(20.0, 12.0))
    averaged = advection_matrix(domain, _oscillation(domain, omega, phase), start, span)
    assert abs(averaged - mean * steady).max() < 1e-4 * abs(mean * steady).max()
    at_start = advection_matrix(domain, _oscillation(domain, omega, phase), start)
    np.testing.assert_allclose(at_start.toarray(), np.sin(omega * start + phase) * steady.toarray(), atol=1e-12)


def test_the_time_mean_holds_over_steps_of_a_period_and_more():
    # one three-point rule errs by 1.6 % of the amplitude over a whole period and 39 % over
    # two; the adaptive scheme may take a substep of a whole dt whatever the flow's period
    from femphase.flows import time_mean

    omega, y = 2 * np.pi / 10.0, np.linspace(0.0, 1.0, 5)
    for span in (10.0 / 3.0, 10.0, 20.0, 35.0):
        mean = time_mean(lambda t: np.sin(omega * t + 0.3) * y, 101.0, span)
        exact = (np.cos(omega * 101.0 + 0.3) - np.cos(omega * (101.0 + span) + 0.3)) / (omega * span) * y
        np.testing.assert_allclose(mean, exact, atol=1e-6)


def test_the_grid_semi_lagrangian_step_traces_the_mean_velocity_of_a_changing_flow():
    # a flow that is not a row flow, v = f(t) w(x): departure points traced at the step's
    # midpoint moved a disc by f(t + s/2) instead of the mean of f over the step
    from helpers import small_system

    from femphase.domains.grid.advection import SemiLagrangian
    from femphase.flows import python_flow

    domain, state = small_system([[20.0, 20.0]], radius=6.0, initial_radius=6.0)
    layout, phi = state.flat()
    omega, start, span = 2 * np.pi / 10.0, 101.0, 10.0 / 3.0
    mean = (np.cos(omega * start) - np.cos(omega * (start + span))) / (omega * span)

    def swirl(x, y):  # divergence-free, tangential at the walls y = 0 and 40
        return 3.0 * np.sin(np.pi * y / 40.0) + 0 * x, 0.5 * np.sin(2 * np.pi * x / 40.0) * np.sin(np.pi * y / 40.0)

    changing = python_flow(lambda x, y, t: tuple(np.sin(omega * t) * c for c in swirl(x, y)), steady=False)
    steady = python_flow(lambda x, y: tuple(mean * c for c in swirl(x, y)))
    moved, _ = SemiLagrangian(domain, changing, span).advect(phi, layout, start)
    expected, _ = SemiLagrangian(domain, steady, span).advect(phi, layout, start)
    np.testing.assert_allclose(moved, expected, atol=1e-6)


def test_an_oscillating_shear_is_its_profile_times_its_amplitude():
    # the meshes' advection builds C from the profile once and scales it by the amplitude's
    # mean over each step: the flow's velocity must be that product at every time
    from femphase.domains.grid.domain import GridDomain
    from femphase.domains.grid.lattice import channel_grid
    from femphase.flows import Flow, time_mean

    domain = GridDomain(channel_grid(40.0, 30.0, 1.0))
    flow = _oscillation(domain)
    x, y = domain.coordinates
    assert flow.profile.steady and not flow.steady
    for t in (0.0, 1.3, 7.9):
        np.testing.assert_allclose(flow.velocity(x, y, t)[0], flow.amplitude(t) * flow.profile.velocity(x, y, 0.0)[0],
                                   rtol=1e-14, atol=1e-13)
    start, span = 101.0, 10.0 / 3.0
    exact = (np.cos(2 * np.pi / 10.0 * start + 0.3) - np.cos(2 * np.pi / 10.0 * (start + span) + 0.3)) / (
        2 * np.pi / 10.0 * span)
    assert flow.mean_amplitude(start, span) == pytest.approx(exact, rel=1e-6)
    np.testing.assert_allclose(flow.mean_amplitude(start, span) * flow.profile.velocity(x, y, 0.0)[0],
                               time_mean(lambda t: flow.velocity(x, y, t)[0], start, span), rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="amplitude f\\(t\\) and its steady profile"):
        Flow("half", flow.velocity, amplitude=flow.amplitude)
    with pytest.raises(ValueError, match="'shear' has no amplitude"):
        Flow("shear", flow.velocity).mean_amplitude(0.0, 1.0)
