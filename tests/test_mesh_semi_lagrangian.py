"""Semi-Lagrangian advection on meshes (femphase.domains.mesh.semi_lagrangian): its
interpolant, its departure points, when meshes choose it, and a translating disc."""

import warnings
from pathlib import Path

import numpy as np
import pytest
from test_unstructured import PARAMS, discs, python_flow, straight

from femphase.analysis.shape import shape_observables
from femphase.config import Numerics
from femphase.domains.mesh import semi_lagrangian
from femphase.domains.mesh.advection import GalerkinPade, GalerkinRungeKutta, TaylorGalerkin
from femphase.domains.mesh.domain import write_domain
from femphase.domains.mesh.generation import structured_channel
from femphase.errors import SceneError
from femphase.domains.mesh.semi_lagrangian import (
    SemiLagrangian,
    courant_number,
    departure_points,
    interpolation_matrix,
)
from femphase.flows import Flow
from femphase.scene import scene_from_dict
from femphase.timestepping.stepper import Stepper


@pytest.fixture(scope="module")
def channel():
    return straight(20.0, 12.0)


def test_the_interpolant_is_exact_for_quadratics_and_the_identity_at_nodes(channel):
    rng = np.random.default_rng(0)
    x, y = channel.coordinates
    # points away from the periodic seam, where a non-periodic quadratic is no field of the mesh
    points = np.stack([3.0 + 14.0 * rng.random(500), 12.0 * rng.random(500)])
    quadratic = lambda x, y: 1 + 0.1 * x - 0.05 * y + 0.02 * x * x - 0.03 * x * y + 0.01 * y * y  # noqa: E731
    matrix = interpolation_matrix(channel, points)
    assert np.abs(matrix @ quadratic(x, y) - quadratic(*points)).max() < 1e-10
    at_nodes = interpolation_matrix(channel, np.array(channel.coordinates))
    assert np.abs(at_nodes.toarray() - np.eye(channel.n_dofs)).max() < 1e-12


def test_points_across_the_seam_and_beyond_the_walls_keep_rows_of_unit_sum(channel):
    # a field periodic in x is interpolated the same from either side of the seam; a point a
    # hair beyond a wall (the departure's integration error) takes the nearest triangle
    x, y = channel.coordinates
    periodic = np.cos(2 * np.pi * x / channel.period) * (1 + 0.01 * y * y)
    seam = np.array([[channel.x0 + 1e-9, channel.x0 + channel.period - 1e-9], [5.0, 5.0]])
    values = interpolation_matrix(channel, seam) @ periodic
    assert values[0] == pytest.approx(values[1], abs=1e-6)
    beyond = np.array([[5.0, 9.0], [-0.01, 12.01]])
    matrix = interpolation_matrix(channel, beyond)
    np.testing.assert_allclose(np.asarray(matrix.sum(axis=1)).ravel(), 1.0, atol=1e-12)


def test_departure_points_in_uniform_flow_are_the_nodes_moved_back(channel):
    x, y = channel.coordinates
    velocity = np.stack([np.full_like(x, 1.5), np.zeros_like(y)])
    points = departure_points(channel, velocity, 4.0)
    expected = channel.x0 + np.mod(x - 6.0 - channel.x0, channel.period)
    np.testing.assert_allclose(points[1], y, atol=1e-12)
    shift = np.mod(points[0] - expected + channel.period / 2, channel.period) - channel.period / 2
    assert np.abs(shift).max() < 1e-9


def test_meshes_choose_it_for_steady_flows_by_the_courant_threshold_and_the_scene_key(channel):
    uniform = python_flow(lambda x, y: (np.ones_like(x), np.zeros_like(y)))
    edge = channel.median_edge
    slow = semi_lagrangian.COURANT * edge * 0.9
    fast = semi_lagrangian.COURANT * edge * 1.1
    assert courant_number(channel, np.stack([np.ones(3), np.zeros(3)]), fast) > semi_lagrangian.COURANT
    assert isinstance(channel.advection(uniform, slow, Numerics()), TaylorGalerkin)
    assert isinstance(channel.advection(uniform, fast, Numerics()), SemiLagrangian)
    assert isinstance(channel.advection(uniform, fast, Numerics(mesh_advection="galerkin")), TaylorGalerkin)
    # the Runge–Kutta step at every Courant number, whatever the solver
    for numerics in (Numerics(mesh_advection="runge-kutta"), Numerics(mesh_advection="runge-kutta", solver="direct")):
        assert isinstance(channel.advection(uniform, fast, numerics), GalerkinRungeKutta)
    assert isinstance(channel.advection(uniform, slow, Numerics(mesh_advection="semi-lagrangian")), SemiLagrangian)
    # per-window solvers keep their exact-solve reference, the Padé step, unless asked
    assert isinstance(channel.advection(uniform, fast, Numerics(solver="direct")), GalerkinPade)
    changing = Flow("python", lambda x, y, t: (np.ones_like(x), np.zeros_like(y)), steady=False)
    assert isinstance(channel.advection(changing, fast, Numerics()), TaylorGalerkin)
    with pytest.raises(ValueError, match="steady flow"):
        SemiLagrangian(channel, changing, fast)


def test_the_scene_key_is_checked_and_refused_for_flows_that_change(tmp_path):
    with pytest.raises(SceneError, match=r"numerics.mesh_advection' = 'upwind' is invalid: one of"):
        Numerics(mesh_advection="upwind")
    mesh, boundaries = structured_channel(20.0, 16.0, 1.0)
    write_domain(tmp_path / "channel.vtu", mesh, boundaries)
    table = {"domain": {"kind": "mesh", "mesh": str(tmp_path / "channel.vtu")}, "particles": {"layout": "single"},
             "model": {"radius": 4.0}, "numerics": {"mesh_advection": "semi-lagrangian"},
             "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0,
                         "flow": {"type": "oscillating_shear", "rate": 0.1, "frequency": 0.1}}]}
    with pytest.raises(SceneError, match=r"numerics.mesh_advection.*phases.0.flow changes with time"):
        scene_from_dict(table, tmp_path)
    table["numerics"]["mesh_advection"] = "galerkin"
    assert scene_from_dict(table, tmp_path).numerics.mesh_advection == "galerkin"


def relaxed_disc(length: float, height: float, centre: list[float]):
    """(domain, state, its shape observables) of a disc relaxed 40 time units in a straight
    channel of ``length`` × ``height``."""
    domain = straight(length, height)
    state = discs(domain, [centre])
    relax = Stepper(domain, PARAMS, Numerics(), 1.0, None, state.radii)
    for _ in range(40):
        relax.step(state)
    return domain, state, shape_observables(state)


def carried(monkeypatch, courant: float, speed: float = 3.0, dt: float = 2.0) -> tuple[float, float]:
    """(displacement error, elongation change) of a relaxed disc carried by u = ``speed``
    at phase dt ``dt`` under the default scheme, semi-Lagrangian from ``courant`` on."""
    monkeypatch.setattr(semi_lagrangian, "COURANT", courant)
    domain, state, start = relaxed_disc(40.0, 30.0, [10.0, 15.0])
    flow = python_flow(lambda x, y: (np.full_like(x, speed), np.zeros_like(y)))
    stepper = Stepper(domain, PARAMS, Numerics(), dt, flow, state.radii)
    steps = round(32.0 / (speed * dt))
    for _ in range(steps):
        stepper.step(state)
    end = shape_observables(state)
    distance = speed * dt * steps
    return ((end.x[0] - start.x[0]) % 40.0 - distance) / distance, end.elongation[0] - start.elongation[0]


def test_a_disc_carried_at_courant_numbers_above_two_keeps_its_speed_and_shape(monkeypatch):
    # u = 3, advections over 1 (Courant number 2.8): the semi-Lagrangian step
    # against the Galerkin step it replaces there, each its error in space and time
    semi, galerkin = carried(monkeypatch, semi_lagrangian.COURANT), carried(monkeypatch, np.inf)
    assert abs(semi[0]) < 0.005  # the meshes' bound on a translating particle's speed
    assert abs(semi[1]) <= abs(galerkin[1])


def test_a_disc_carried_past_its_margin_in_one_substep_keeps_its_field():
    # u = 8 at dt = 10: each of the adaptive scheme's advections carries the disc several
    # margins (4), so the refit before each gives its box room for that motion; without it
    # the field beyond the box was cut away and the disc vanished within a few steps
    domain, state, start = relaxed_disc(120.0, 24.0, [30.0, 12.0])
    stepper = Stepper(domain, PARAMS, Numerics(), 10.0, python_flow(lambda x, y: (np.full_like(x, 8.0), 0 * y)),
                      state.radii)
    assert stepper.roomless and isinstance(stepper.advection, SemiLagrangian)
    for _ in range(3):
        stepper.step(state)
        assert min(float(field.min()) for field in state.fields) > -1e-3
    end = shape_observables(state)
    assert end.area[0] == pytest.approx(start.area[0], rel=0.01)
    lag = (end.x[0] - start.x[0] - 240.0 + 60.0) % 120.0 - 60.0  # two periods travelled
    assert abs(lag) < 0.5


def test_a_flow_that_turns_within_a_substep_gives_room_on_every_side(tmp_path):
    # oscillating shear of rate 10 and frequency 0.5 on the straight mesh: the velocity at
    # one instant of a substep may be near zero, so room ahead of the mean motion then was
    # none, and a particle at the wall kept 111 of its 195 (the structured channel: 195)
    from femphase.io.files import read_csv
    from femphase.run.runner import run_scene
    from femphase.scene import load_scene

    scene = load_scene(Path(__file__).parents[1] / "examples" / "straight_mesh.toml", [
        "particles.N=10", "phases.0.duration=200", "phases.0.frame_interval=100", "phases.1.duration=100",
        "phases.1.frame_interval=10", 'phases.1.flow={type="oscillating_shear", rate=10.0, frequency=0.5}',
        "output.fields=false"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the guards' advection warning at this rate
        run_scene(scene, tmp_path / "run", progress=False)
    rows = read_csv(tmp_path / "run" / "particles.csv")
    assert rows["area"][rows["time"] >= 200].min() > 190
