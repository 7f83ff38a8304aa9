"""The finite-difference reference scheme (femphase.timestepping.fd) against the finite-element stepper."""

from __future__ import annotations

import numpy as np
import pytest

from femphase.analysis.shape import shape_observables
from femphase.config import Numerics
from femphase.domains.grid.domain import GridDomain
from femphase.domains.grid.lattice import channel_grid
from femphase.domains.grid.windows import Window, WindowPolicy
from femphase.errors import BlowUpError, SceneError
from femphase.flows import linear_shear, python_flow
from femphase.model.energy import FreeEnergy
from femphase.model.parameters import ModelParameters
from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict
from femphase.timestepping.fd import (
    COURANT_NUMBER,
    explicit_stability_limit,
    five_point_laplacian,
    laplacian,
    upwind_advection,
)
from femphase.timestepping.stepper import Stepper

PARAMS = ModelParameters()


def fd_stepper(domain, dt, flow=None, radii=None, numerics=Numerics()):
    """The finite-difference reference scheme ("fd-heun") on ``domain``."""
    return Stepper(domain, PARAMS, numerics, dt, flow, radii, scheme="fd-heun")


def single_particle_scene(method_dt: float, duration: float, frame: float, **particles) -> object:
    return scene_from_dict({
        "domain": {"Lx": 32.0, "Ly": 32.0, "h": 1.0},
        "particles": {"layout": "single", **particles},
        "output": {"fields": False, "checkpoint": False},
        "numerics": {"scheme": "euler"},  # the FEM side: the first-order step these tests bound
        "phases": [{"name": "relax", "duration": duration, "dt": method_dt, "frame_interval": frame}],
    })


def test_laplacian_equals_minus_lumped_mass_inverse_stiffness_on_windows():
    """Δ_h φ = −M_L⁻¹Kφ node by node for fields zero outside their windows: walls (mirror),
    the periodic seam (a wrapping window, a full-width window) and artificial window edges."""
    grid = channel_grid(6.0, 4.0, 0.5)  # 12 × 9 nodes
    domain = GridDomain(grid)
    ops = domain.operators
    windows = [
        Window(2, 4, 3, 5),  # interior: zero beyond every edge
        Window(0, 5, 9, 6),  # on the bottom wall, wrapping across the seam
        Window(4, grid.ny - 4, 2, 7),  # on the top wall
        domain.full_window(),  # both walls, periodic in x
        Window(3, 4, 0, grid.nx),  # full width between the walls
    ]
    rng = np.random.default_rng(1)
    fields = [rng.random(w.ny * w.nx) for w in windows]
    for phi, w, lap in zip(fields, windows, laplacian(fields, windows, domain)):
        full = np.zeros(grid.n_nodes)
        nodes = domain.window_dofs(w)
        full[nodes] = phi
        fem = -(ops.stiffness @ full) / ops.lumped_mass
        np.testing.assert_allclose(lap.ravel(), fem[nodes], rtol=0, atol=1e-12 / grid.h**2)


def test_stencils_have_the_documented_symbols():
    """On a Fourier mode e^{iθj}: Laplacian −(4/h²) sin²(θ/2) per direction; upwind advection
    i sin θ(4 − cos θ)/(3h) + (1 − cos θ)²/(3h) (third order: error θ⁴/(12h) + O(θ⁵))."""
    h = 0.5
    theta = np.linspace(-np.pi, np.pi, 41)
    j = np.arange(-2, 3)
    mode = np.exp(1j * theta[:, None, None] * j[None, None, :]) * np.ones((1, 5, 1))  # varies along x
    lap = five_point_laplacian(mode, h)[:, 0, 0]  # the mode is 1 at the node itself
    np.testing.assert_allclose(lap, -4 / h**2 * np.sin(theta / 2) ** 2, atol=1e-12)
    adv = upwind_advection(mode, np.ones((theta.size, 1, 1)), 2, h)[:, 0, 0]
    expected = (1j * np.sin(theta) * (4 - np.cos(theta)) + (1 - np.cos(theta)) ** 2) / (3 * h)
    np.testing.assert_allclose(adv, expected, atol=1e-12)
    small = np.abs(theta) < 0.3
    assert np.all(np.abs(adv - 1j * theta / h)[small] <= 0.1 * np.abs(theta[small]) ** 4 / h + 1e-15)


def test_first_order_upwind_has_the_symbol_of_a_one_sided_difference():
    """order=1 on e^{iθj}: (1 − e^{−iθ})/h for w > 0, (e^{iθ} − 1)/h for w < 0."""
    h = 0.5
    theta = np.linspace(-np.pi, np.pi, 41)
    mode = np.exp(1j * theta[:, None, None] * np.arange(-2, 3)[None, None, :]) * np.ones((1, 5, 1))
    for w, expected in ((1.0, (1 - np.exp(-1j * theta)) / h), (-1.0, -(np.exp(1j * theta) - 1) / h)):
        adv = upwind_advection(mode, np.full((theta.size, 1, 1), w), 2, h, order=1)[:, 0, 0]
        np.testing.assert_allclose(adv, expected, atol=1e-12)


def _heun(z: np.ndarray) -> np.ndarray:
    return np.abs(1 + z + z**2 / 2)


@pytest.mark.parametrize("h, speed", [(1.0, 0.0), (1.0, 1.0), (0.5, 3.0), (2.0, 0.2), (0.25, 0.5)])
def test_documented_stability_limit_is_stable_for_the_frozen_coefficient_symbol(h, speed):
    """|Heun amplification| ≤ 1 at dt = dt_max for every mode (θx, θy), every reaction rate
    in [−J0 L, 0] and a flow of the given speed split between x and y in any proportion."""
    dt = explicit_stability_limit(PARAMS, h, speed)
    theta = np.linspace(-np.pi, np.pi, 61)
    tx, ty = np.meshgrid(theta, theta)
    diffusion = -PARAMS.diffusivity * 4 / h**2 * (np.sin(tx / 2) ** 2 + np.sin(ty / 2) ** 2)

    def advection(t):  # symbol of −u ∂ for u = 1 (see the previous test)
        return -(1j * np.sin(t) * (4 - np.cos(t)) + (1 - np.cos(t)) ** 2) / (3 * h)

    rates = -PARAMS.mobility * FreeEnergy.paper(PARAMS).curvature_bound(PARAMS.radius) * np.linspace(0, 1, 5)
    for share in np.linspace(0, 1, 5):
        for rate in rates:
            z = dt * (diffusion + rate + speed * (share * advection(tx) + (1 - share) * advection(ty)))
            assert _heun(z).max() <= 1 + 1e-12


def test_heun_with_upwind_advection_needs_the_courant_limit():
    """The documented Courant limit has a safety factor ~2: Heun + third-order upwind is
    stable up to ≈ 0.87 and unstable above."""
    theta = np.linspace(-np.pi, np.pi, 2001)
    symbol = -(1j * np.sin(theta) * (4 - np.cos(theta)) + (1 - np.cos(theta)) ** 2) / 3
    assert _heun(0.86 * symbol).max() <= 1 + 1e-12
    assert _heun(0.9 * symbol).max() > 1 + 1e-5
    assert 2 * COURANT_NUMBER < 0.87


def test_paper_dt_is_accepted_and_too_large_dt_raises_a_clear_error():
    grid = channel_grid(32.0, 32.0, 1.0)
    domain = GridDomain(grid)
    assert 0.3 < explicit_stability_limit(PARAMS, 1.0) < 0.35
    assert fd_stepper(domain, 0.1).scheme.dt_max == pytest.approx(explicit_stability_limit(PARAMS, 1.0))
    # numerics.scheme selects the reference as well as the stepper's argument does
    assert Stepper(domain, PARAMS, Numerics(scheme="fd-heun"), 0.1).scheme.name == "fd-heun"
    with pytest.raises(SceneError, match=r"phases\.dt.*≤ 0\.3"):
        fd_stepper(domain, 1.0)
    # a fast flow: the Courant condition dt (|u| + |v|)/h ≤ 0.4 binds, and the advice is its
    # limit, not the paper's dt = 0.1 it has just refused
    with pytest.raises(SceneError, match="advection") as refused:
        fd_stepper(domain, 0.1, linear_shear(8.0, grid.width))
    assert "set dt ≤ 0.05 here" in str(refused.value) and "use the paper's dt = 0.1" not in str(refused.value)
    fine = GridDomain(channel_grid(16.0, 16.0, 0.25))
    with pytest.raises(SceneError, match="h = 0.25"):
        fd_stepper(fine, 0.1)


def test_a_scene_whose_scheme_is_the_fd_reference_records_the_fd_method():
    # numerics.scheme = "fd-heun" without --method fd ran FD and recorded method "fem"
    from femphase.run.simulation import Simulation
    from femphase.scene import scene_from_dict

    scene = scene_from_dict({"domain": {"Lx": 20.0, "Ly": 20.0}, "particles": {"layout": "single"},
                             "numerics": {"scheme": "fd-heun"},
                             "phases": [{"duration": 0.2, "dt": 0.1, "frame_interval": 0.1}]})
    assert Simulation(scene).method == "fd"
    assert Simulation(scene_from_dict({**scene.to_dict(), "numerics": {}})).method == "fem"


def test_a_run_of_an_fd_scene_resumes_with_the_command_that_started_it(tmp_path):
    # recorded as "fd", it was refused on resume without --method fd: "'fd', the method the run
    # was started with"
    from femphase.run.runner import run_scene
    from femphase.scene import scene_from_dict

    data = {"domain": {"Lx": 20.0, "Ly": 20.0}, "particles": {"layout": "single"},
            "numerics": {"scheme": "fd-heun"}, "phases": [{"duration": 0.2, "dt": 0.1, "frame_interval": 0.1}]}
    run_scene(scene_from_dict(data), tmp_path / "run", progress=False)
    data["phases"][0]["duration"] = 0.4
    run_scene(scene_from_dict(data), tmp_path / "run", resume=True, progress=False)
    assert '"method": "fd"' in (tmp_path / "run" / "run.json").read_text()


def test_a_round_limit_is_named_as_it_is():
    # 0.4 · 1/40 = 0.01 was printed "0.00999" (a floor of 999.9999999999998)
    from femphase.timestepping.fd import rounded_down

    assert [rounded_down(v) for v in (0.4 / 40, 0.04, 0.3, 0.3197856)] == ["0.01", "0.04", "0.3", "0.3197"]


def test_the_limit_a_refusal_names_is_accepted():
    # the message gave the limit 0.3197856 as "0.3198", and dt = 0.3198 was refused
    import re

    for h, flow in ((1.0, None), (1.0, linear_shear(8.0, 32.0)), (0.5, None)):
        domain = GridDomain(channel_grid(32.0, 32.0, h))
        with pytest.raises(SceneError) as info:
            fd_stepper(domain, 1.0, flow)
        named = float(re.search(r"a time step ≤ ([0-9.e-]+)", str(info.value)).group(1))
        assert fd_stepper(domain, named, flow).dt == named


def test_an_oscillating_shear_is_checked_at_its_fastest_before_the_run():
    # at t = 0 sin(ωt) = 0, so the advective limit was skipped: the run went through its
    # earlier phases and stopped at the first unstable step (exit 3) instead of being refused
    from femphase.flows import flow_from_spec

    domain = GridDomain(channel_grid(32.0, 32.0, 1.0))
    fast = flow_from_spec({"type": "oscillating_shear", "rate": 100.0, "frequency": 1.0}, domain)
    assert fast.velocity(np.array([0.0]), np.array([32.0]), 0.0)[0] == 0.0 and fast.speed_bound == 100.0
    with pytest.raises(SceneError, match=r"max\|u\| \+ max\|v\| = 100 at its fastest"):
        fd_stepper(domain, 0.3, fast)
    slow = flow_from_spec({"type": "oscillating_shear", "rate": 0.1, "frequency": 1.0}, domain)
    assert fd_stepper(domain, 0.3, slow).dt == 0.3


def test_isolated_particle_relaxation_agrees_with_fem_to_the_fem_time_error():
    """Without flow FD and lumped-mass FEM discretise space identically (5-point Laplacian =
    −M_L⁻¹K, same nodal terms and quadrature), so their difference is the time stepping:
    Heun is O(dt²), the linearly implicit Euler step O(dt) with a global error whose leading
    term is ≤ (dt/2) ∫|d²A/dt²| dt = (dt/2) max|dA/dt| for the monotone area relaxation.
    Tolerance: |A_FEM − A_FD| ≤ (dt/2) max|dA/dt|; and halving dt halves the difference."""
    largest = {}
    for dt in (0.1, 0.05):
        areas = {}
        for method in ("fem", "fd"):
            scene = single_particle_scene(dt, 20.0, 0.5)
            recorder = FrameRecorder()
            Simulation(scene, method).run(scene.initial_state(), [recorder])
            areas[method] = recorder.series("area")[:, 0]
        fd = areas["fd"]
        rate = np.diff(fd) / 0.5
        assert np.all(rate > 0)  # monotone relaxation from R/2
        largest[dt] = np.max(np.abs(areas["fem"] - fd))
        assert 1e-3 * 0.5 * dt * rate.max() < largest[dt] <= 0.5 * dt * rate.max()
    assert largest[0.05] / largest[0.1] == pytest.approx(0.5, abs=0.05)


def _advect(h: float, centre: tuple, flow_for, steps: int, size=(48.0, 32.0)):
    """Run the FD stepper on a relaxed-size disc; returns (start, end) shape observables and
    the first and last window."""
    scene = scene_from_dict({
        "domain": {"Lx": size[0], "Ly": size[1], "h": h},
        "particles": {"layout": "single", "centres": [list(centre)], "initial_radius": 8.0},
        "phases": [{"name": "p", "duration": 1.0, "dt": 0.1, "frame_interval": 1.0}],
    })
    domain = scene.domain
    state = scene.initial_state()
    stepper = fd_stepper(domain, 0.1, flow_for(domain.grid), state.radii)
    start, window = shape_observables(state), state.windows[0]
    for _ in range(steps):
        stepper.step(state)
    return start, shape_observables(state), window, state.windows[0]


def test_advection_in_shear_moves_the_centroid_by_the_local_velocity():
    """u = γ̇ y/Ly: a disc centred at y_c stays point-symmetric and moves by u(y_c) t.

    The third-order scheme's phase speed sin θ (4 − cos θ)/(3θ) is 0.1–1 % slow for the
    interface's wavenumbers θ = kh ~ h/λ … 1, so at h = 1 the centroid may lag by a few
    tenths of a percent; the lag must fall at least 6× when h halves (third order: 8×)."""
    lag = {}
    for h in (1.0, 0.5):
        start, end, first, last = _advect(h, (12.0, 16.0), lambda g: linear_shear(0.8, g.width), 200)
        expected = 0.8 * start.y[0] / 32.0 * 20.0  # 8 lattice units in t = 20
        lag[h] = abs(end.x[0] - start.x[0] - expected)
        assert end.y[0] == pytest.approx(start.y[0], abs=2e-3 * h)
        assert end.elongation[0] > 0.1  # the shear deforms the particle
        assert last.ix0 != first.ix0  # the window followed the particle
    assert lag[1.0] < 3e-3 * 8.0
    assert lag[0.5] < lag[1.0] / 6


def test_general_flow_advects_along_both_axes():
    """A uniform (u, v) flow given as a general (non-row) flow moves the centroid by (u, v) t."""
    flow = python_flow(lambda x, y: (0.3 + 0 * x, 0.2 + 0 * y))
    start, end, _, _ = _advect(1.0, (12.0, 18.0), lambda g: flow, 150, size=(40.0, 48.0))
    np.testing.assert_allclose([end.x[0] - start.x[0], end.y[0] - start.y[0]], [4.5, 3.0], rtol=3e-3)


def test_blow_up_raises_and_leaves_the_state_unchanged():
    scene = single_particle_scene(0.1, 1.0, 1.0)
    state = scene.initial_state()
    state.fields[0].reshape(state.windows[0].shape)[3, 3] = np.nan
    before = state.copy()
    stepper = fd_stepper(scene.domain, 0.1)
    with pytest.raises(BlowUpError, match="not finite"):
        stepper.step(state)
    assert state.time == before.time and state.step == before.step
    assert state.windows == before.windows


def test_a_flow_that_speeds_up_past_the_courant_limit_stops_the_run_before_that_step():
    # the check at construction saw an oscillating shear at t = 0 only, where it is still:
    # rate 20 ran on and blew up at step 45 with φ in [−2.6, 3.3]
    from femphase.errors import UnstableStepError
    from femphase.flows import row_flow

    scene = single_particle_scene(0.1, 1.0, 1.0)
    state = scene.initial_state()
    rate, omega = 20.0, 0.5
    flow = row_flow("oscillating_shear", lambda y, t: rate * np.sin(omega * t) * y / 32.0, steady=False)
    stepper = fd_stepper(scene.domain, 0.1, flow, state.radii)  # accepted: still at t = 0
    # max|u| dt/h = 2 sin(t/2) reaches 0.4 at t = 0.4027: the step from 0.4 ends past it
    stepper.step(state, 4)
    before = state.copy()
    with pytest.raises(UnstableStepError, match=r"stopped before step 5 \(t = 0\.4\).*dt ≤ 0\.0"):
        stepper.step(state)
    assert state.time == before.time and state.step == before.step
    np.testing.assert_array_equal(state.fields[0], before.fields[0])


def test_windows_agree_with_full_mesh_fields():
    """Windows are exact up to the field left beyond their margin (φ < threshold there)."""
    scene = scene_from_dict({
        "domain": {"Lx": 32.0, "Ly": 32.0, "h": 1.0},
        "particles": {"layout": "list", "centres": [[10.0, 16.0], [22.0, 16.0]], "initial_radius": 7.0},
        "phases": [{"name": "p", "duration": 1.0, "dt": 0.1, "frame_interval": 1.0}],
    })
    results = []
    for windows in (True, False):
        state = scene.initial_state()
        if not windows:
            state.fields = [state.global_field(i) for i in range(2)]
            state.windows = [scene.domain.full_window()] * 2
        stepper = fd_stepper(scene.domain, 0.1, None, state.radii, Numerics(windows=windows))
        for _ in range(100):
            stepper.step(state)
        results.append(state.global_fields())
    assert np.max(np.abs(results[0] - results[1])) < WindowPolicy().threshold


def test_the_fd_method_off_the_structured_channel_is_refused_as_the_option_was_given(tmp_path):
    from femphase.domains.mesh.domain import write_domain
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing
    from femphase.scene import check_numerics

    write_domain(tmp_path / "channel.vtu", *delaunay_channel(24.0, edge_for_spacing(1.0), lambda x: 0 * x,
                                                            lambda x: 0 * x + 24.0, seed=1))
    def scene(**numerics):
        return scene_from_dict({
            "domain": {"kind": "mesh", "mesh": "channel.vtu"},
            "particles": {"layout": "single", "centres": [[12.0, 12.0]], "initial_radius": 5.0},
            "numerics": numerics,
            "phases": [{"name": "relax", "duration": 1.0, "dt": 0.1, "frame_interval": 1.0}],
        }, tmp_path)

    with pytest.raises(SceneError) as option:  # femphase run --method fd
        check_numerics(scene(), scheme="fd-heun")
    assert (option.value.key, option.value.value) == ("--method", "fd") and option.value.valid.startswith('"fem"')
    with pytest.raises(SceneError) as key:  # numerics.scheme = "fd-heun" in the scene
        check_numerics(scene(scheme="fd-heun"))
    assert (key.value.key, key.value.value) == ("numerics.scheme", "fd-heun") and "structured channel" in key.value.valid
