"""The FEM stepper: relaxation, shear, windows against the full mesh, advection, solvers."""

import numpy as np
import pytest
from helpers import energy_of, small_system, stepper

from femphase.analysis.shape import shape_observables
from femphase.config import Numerics
from femphase.domains.grid.advection import shift_rows
from femphase.domains.grid.domain import GridDomain, tensor_solver
from femphase.domains.grid.lattice import channel_grid
from femphase.domains.grid.windows import Window
from femphase.errors import SceneError
from femphase.fem.meshfiles import load_mesh
from femphase.fem.solvers import AMGSolver, DirectSolver, TensorSolver
from femphase.flows import linear_shear, python_flow
from femphase.model.parameters import ModelParameters
from femphase.timestepping.stepper import Stepper


def test_isolated_particle_relaxes_to_the_area_set_by_tension_and_constraint():
    # Equilibrium of σ·2πr + μ(1 − a)² with σ = 2γ/3 (the tanh profile's line tension)
    # gives 1 − a ≈ πσR/(2μ): the area settles slightly below πR².
    params = ModelParameters()
    domain, state = small_system([[20, 20]], initial_radius=4.0)
    step = stepper(domain, state)
    ratios = []
    for _ in range(400):
        step.step(state)
        ratios.append(shape_observables(state).area[0] / (np.pi * 64))
    sigma = 2 * params.tension / 3
    expected = 1 - np.pi * sigma * 8 / (2 * params.area_stiffness)
    assert ratios[0] < 0.5  # started from R/2
    assert abs(ratios[-1] - expected) < 0.005
    assert abs(ratios[-1] - ratios[-50]) < 1e-4  # settled


def test_isolated_particle_in_shear_elongates_and_settles_without_oscillating():
    domain, state = small_system([[35, 120]], length=70, width=240, initial_radius=8.0)
    relax = stepper(domain, state)
    for _ in range(100):
        relax.step(state)
    shear = stepper(domain, state, flow=linear_shear(1.0, 240.0))
    elongation = []
    for _ in range(1400):
        shear.step(state)
        elongation.append(shape_observables(state).elongation[0])
    elongation = np.array(elongation)
    late = elongation[-600:]
    assert elongation.max() > 1.0  # deformed
    assert np.ptp(late) < 0.05 * late.mean()  # settled: no sustained oscillation
    assert np.all(np.abs(np.diff(late)) < 1e-3)


def test_windows_agree_with_the_full_mesh():
    results = []
    for windows in (True, False):
        domain, state = small_system([[15, 20], [30, 22]], length=50, width=40, initial_radius=6.0, windows=windows)
        step = stepper(domain, state, windows=windows)
        for _ in range(60):
            step.step(state)
        shear = stepper(domain, state, flow=linear_shear(0.5, 40.0), windows=windows)
        for _ in range(60):
            shear.step(state)
        results.append((state.global_fields(), energy_of(state, step.params).total))
    (windowed, e_w), (full, e_f) = results
    # a window drops the field beyond its edge, where the tanh tail has decayed from the
    # threshold over the margin: φ_edge ≈ threshold · exp(−2 margin/λ) = 0.01 e^{−4} ≈ 1.8e-4
    truncation = 0.01 * np.exp(-2 * 4.0 / 2.0)
    assert np.abs(windowed - full).max() < 2 * truncation
    assert e_w == pytest.approx(e_f, rel=1e-5)


def test_row_shift_is_exact_for_integer_shifts_and_invertible():
    rng = np.random.default_rng(0)
    fields = rng.random((2, 5, 15))  # odd length: no Nyquist mode, so integer shifts are rolls
    shifts = np.array([[0, 1, 2, 3, -4]] * 2, dtype=float)
    shifted = shift_rows(fields, shifts)
    for row in range(5):
        assert np.allclose(shifted[0, row], np.roll(fields[0, row], int(shifts[0, row])))
    fractional = rng.uniform(-0.5, 0.5, (2, 5))
    assert np.allclose(shift_rows(shift_rows(fields, fractional), -fractional), fields)


def test_row_shifts_of_even_rows_compose_exactly_and_keep_the_nyquist_mode():
    # even length: the Nyquist mode stays in place (the spectral derivative's convention),
    # so two shifts are one, however a displacement is split into steps
    rng = np.random.default_rng(1)
    fields = rng.random((2, 5, 16))
    first, second = rng.uniform(-0.7, 0.7, (2, 2, 5))
    twice = shift_rows(shift_rows(fields, first), second)
    assert np.abs(twice - shift_rows(fields, first + second)).max() < 1e-13
    nyquist = lambda f: np.fft.rfft(f, axis=-1)[..., -1]
    assert np.allclose(nyquist(shift_rows(fields, first)), nyquist(fields))
    # a window moved by an odd number of nodes carries the mode with the opposite sign
    assert np.allclose(nyquist(shift_rows(fields, first, moves=np.ones((2, 5), dtype=int))), -nyquist(fields))


def test_shear_advection_of_windows_does_not_depend_on_how_a_step_is_split():
    # two advections of dt/2 are one of dt while no window moves by whole nodes: the
    # adaptive scheme merges half-steps of neighbouring substeps into one advection
    domain, state = small_system([[13.0, 12.0], [26.0, 28.0]])
    flow = linear_shear(0.6, 40.0)
    numerics = Numerics(precision="double")
    layout, phi = state.flat()
    halves = [domain.advection(flow, 0.25, numerics) for _ in range(2)]
    split, split_layout = halves[1].advect(*halves[0].advect(phi.copy(), layout, 0.0), 0.25)
    whole, whole_layout = domain.advection(flow, 0.5, numerics).advect(phi.copy(), layout, 0.0)
    assert split_layout.windows == whole_layout.windows == layout.windows
    assert np.abs(split - whole).max() < 1e-13
    assert np.abs(whole - phi).max() > 1e-3  # the fields did move


def test_shear_advection_does_not_limit_dt():
    # the paper's highest shear, γ̇ = 1 in its channel (u = γ̇ y/Ly): at dt = 10 the top rows
    # move 10 nodes per step; the step stays stable and moves the particle at u(y_c)
    outcomes = {}
    for dt in (1.0, 10.0):
        domain, state = small_system([[35, 120]], length=70, width=240, initial_radius=8.0)
        step = stepper(domain, state, dt=dt, flow=linear_shear(1.0, 240.0))
        for _ in range(int(200 / dt)):
            step.step(state)
        outcomes[dt] = shape_observables(state)
        assert all(np.isfinite(f).all() and -0.05 < f.min() and f.max() < 1.1 for f in state.fields)
    for obs in outcomes.values():
        expected = (35 + 0.5 * 200) % 70
        assert abs((obs.x[0] - expected + 35) % 70 - 35) < 0.05
    # dt = 10 is stable, not accurate: its stabilisation (S ≈ 2) slows the explicit forces by
    # 1 + J0 S dt ≈ 11, so the particle is more elongated, but bounded
    assert outcomes[1.0].elongation[0] < outcomes[10.0].elongation[0] < 10.0


def test_semi_lagrangian_general_flow_matches_the_exact_row_shift():
    finals = []
    for flow in (linear_shear(0.6, 40.0), python_flow(lambda x, y: (0.6 * y / 40.0, 0.0 * x))):
        domain, state = small_system([[20, 20]], length=60, width=40, initial_radius=8.0)
        step = stepper(domain, state, flow=flow)
        for _ in range(50):
            step.step(state)
        finals.append(state.global_fields()[0])
    assert np.abs(finals[0] - finals[1]).max() < 0.02


def test_amg_and_direct_solvers_agree():
    grid = channel_grid(30, 20, 1.0)
    ops = GridDomain(grid).operators
    matrix = (ops.mass + 0.12 * ops.stiffness).tocsr()
    rhs = np.random.default_rng(1).random((grid.n_nodes, 3))
    amg = AMGSolver(matrix, tol=1e-12)
    assert amg.accel == "cg"
    assert np.allclose(amg.solve(rhs), DirectSolver(matrix).solve(rhs), atol=1e-9)


def test_the_stepper_gives_the_same_result_with_either_solver():
    outcomes = []
    for solver in ("direct", "amg", "tensor"):
        domain, state = small_system([[20, 20]], initial_radius=5.0)
        step = stepper(domain, state, solver=solver, tolerance=1e-12)
        for _ in range(20):
            step.step(state)
        outcomes.append(state.global_fields())
    assert np.abs(outcomes[0] - outcomes[1]).max() < 1e-9
    assert np.abs(outcomes[0] - outcomes[2]).max() < 1e-12


@pytest.mark.parametrize("window", [Window(5, 12, 5, 9), Window(0, 7, 27, 8), Window(13, 7, 0, 30),
                                    Window(0, 20, 0, 30)],
                         ids=["interior", "wall-and-seam", "wall-full-width", "whole-channel"])
def test_the_tensor_solver_solves_every_kind_of_window_exactly(window):
    grid = channel_grid(30, 19, 1.0)
    domain = GridDomain(grid)
    params = ModelParameters()
    step = Stepper(domain, params, Numerics(scheme="euler"), 0.7)
    stabilisation = step.scheme.stabilisation
    system = step.system(1 / 0.7, stabilisation)[0]
    nodes = domain.window_dofs(window)
    block = system[nodes][:, nodes]
    a = 1 / 0.7 + params.mobility * stabilisation
    solver = tensor_solver(block, window, grid, a, params.diffusivity)
    assert isinstance(solver, TensorSolver)
    rhs = np.random.default_rng(2).random((nodes.size, 4))
    assert np.allclose(block @ solver.solve(rhs), rhs, atol=1e-12)
    assert np.allclose(solver.solve(rhs[:, 0]), DirectSolver(block).solve(rhs[:, 0]), atol=1e-12)
    # a wrong coefficient is detected, not silently solved
    assert tensor_solver(block, window, grid, 1.01 * a, params.diffusivity) is None


def test_the_tensor_solver_refuses_alternating_diagonals_and_the_consistent_mass():
    grid = channel_grid(30, 20, 1.0)
    alternating = GridDomain(grid, "alternating")
    step = Stepper(alternating, ModelParameters(), Numerics(scheme="euler", diagonals="alternating"), 1.0)
    system = step.system(1.0, step.scheme.stabilisation)[0]
    window = Window(3, 10, 4, 10)
    nodes = alternating.window_dofs(window)
    assert tensor_solver(system[nodes][:, nodes], window, grid, 1.0, ModelParameters().diffusivity) is None
    domain, state = small_system([[20, 20]], initial_radius=5.0)
    with pytest.raises(SceneError, match="tensor"):
        stepper(domain, state, solver="tensor", mass="consistent").step(state)


def test_the_default_mesh_file_gives_the_generated_operators():
    grid = channel_grid(70, 240, 1.0)
    from_file = GridDomain(grid, mesh=load_mesh("meshes/channel_70x240_h1.vtu")).operators
    generated = GridDomain(grid).operators
    assert abs(from_file.stiffness - generated.stiffness).max() < 1e-12
    assert np.allclose(from_file.lumped_mass, generated.lumped_mass)


@pytest.mark.parametrize("diagonals", ["left", "alternating"])
def test_other_diagonal_patterns_relax_like_the_default(diagonals):
    areas = []
    for pattern in ("right", diagonals):
        domain, state = small_system([[20, 20]], initial_radius=4.0, diagonals=pattern)
        step = stepper(domain, state, diagonals=pattern)
        for _ in range(100):
            step.step(state)
        areas.append(shape_observables(state).area[0])
    if diagonals == "left":
        # the mirror-image mesh: same stiffness (5-point stencil), same lumped mass
        assert areas[0] == pytest.approx(areas[1], rel=1e-9)
    else:
        # same stiffness, but the lumped mass alternates 2h²/3, 4h²/3: an O(h²) difference
        assert areas[0] == pytest.approx(areas[1], rel=2e-3)
        assert areas[0] != pytest.approx(areas[1], rel=1e-9)


def test_inconsistent_states_are_refused_with_what_is_inconsistent():
    # State and discs_state checked nothing: one window for two fields ran with one particle,
    # a negative radius ran with an area target of 64, a centre beyond the wall failed in numpy
    from femphase.scene import scene_from_dict
    from femphase.state import State, discs_state

    scene = scene_from_dict({"domain": {"Lx": 60.0, "Ly": 40.0}, "particles": {"layout": "list",
                             "centres": [[15.0, 20.0], [45.0, 20.0]]},
                             "phases": [{"duration": 4.0, "dt": 1.0, "frame_interval": 2.0}]})
    good = scene.initial_state()
    policy = scene.window_policy()
    cases = [
        (lambda: State(good.domain, good.windows[:1], good.fields, good.radii), "one window, field and radius"),
        (lambda: State(good.domain, good.windows, good.fields, np.array([-8.0, 8.0])), "radii must be finite"),
        (lambda: State(good.domain, good.windows, [good.fields[0][:-1], good.fields[1]], good.radii),
         "field 0 has"),
        (lambda: discs_state(good.domain, [[15.0, 20.0], [45.0, 20.0]], [-8.0, 8.0], 4.0, 2.0, policy),
         "radii must be one length > 0"),
        (lambda: discs_state(good.domain, [[15.0, 80.0]], 8.0, 4.0, 2.0, policy), "outside the domain's walls"),
    ]
    for build, message in cases:
        with pytest.raises(ValueError, match=message):
            build()


def test_a_state_the_scene_cannot_continue_is_refused_not_run_forever():
    # a state stopped at step 6 of a phase continued under a scene whose phase has 4 steps
    # looped for ever; a state from a wider channel ran and reported x beyond Lx
    from femphase.run.simulation import Simulation
    from femphase.scene import scene_from_dict

    def scene(length=60.0, duration=4.0):
        return scene_from_dict({"domain": {"Lx": length, "Ly": 40.0}, "particles": {"layout": "single"},
                                "phases": [{"duration": duration, "dt": 1.0, "frame_interval": 2.0}]})

    import signal

    from femphase.errors import Interrupted

    state = scene(duration=10.0).initial_state()
    with pytest.raises(Interrupted):
        Simulation(scene(duration=10.0)).run(state, stop=lambda: signal.SIGINT if state.time >= 6.0 else None)
    with pytest.raises(ValueError, match="step 6 of phase 0, which has 4"):
        Simulation(scene()).run(state)
    with pytest.raises(ValueError, match="another domain"):
        Simulation(scene()).run(scene(length=80.0).initial_state())


def test_an_unsteady_row_flow_moves_by_the_integral_of_its_velocity():  # V2
    from femphase.flows import row_flow
    domain, state = small_system([[20.0, 20.0]], radius=8.0, initial_radius=8.0)
    layout, phi = state.flat()
    flow = row_flow("ramp", lambda y, t: 1.0 * t + 0.0 * y, steady=False)
    before = domain.centroids(layout, phi)[0, 0]
    moved_phi, moved = domain.advection(flow, 1.0, Numerics()).advect(phi.copy(), layout, 1.0)
    after = domain.centroids(moved, moved_phi)[0, 0]
    # ∫_1^2 t dt = 1.5 (the midpoint rule is exact for a velocity linear in time)
    assert after - before == pytest.approx(1.5, abs=1e-3)


def test_semi_lagrangian_departure_points_are_second_order():  # V5
    domain, state = small_system([[30.0, 20.0]], length=60.0, width=50.0, radius=8.0, initial_radius=8.0)
    layout, phi = state.flat()
    a, c, dt = 0.05, 1.0, 4.0
    flow = python_flow(lambda x, y: (a * y + 0.0 * x, c + 0.0 * y))
    before = domain.centroids(layout, phi)[0]
    moved_phi, moved = domain.advection(flow, dt, Numerics()).advect(phi.copy(), layout, 0.0)
    after = domain.centroids(moved, moved_phi)[0]
    # y(t) = y0 + c t, x' = a y: Δx = a dt (y0 + c dt/2) = 0.05·4·22 = 4.4 (not 4.8), Δy = 4
    assert after[0] - before[0] == pytest.approx(a * dt * (before[1] + 0.5 * c * dt), abs=0.05)
    assert after[1] - before[1] == pytest.approx(c * dt, abs=0.05)


def test_a_row_shift_moves_the_window_by_the_rounded_mean_shift():  # V4
    from femphase.flows import row_flow
    domain, state = small_system([[20.0, 20.0]], length=60.0, radius=8.0, initial_radius=8.0)
    layout, phi = state.flat()
    flow = row_flow("uniform", lambda y, t: 2.75 + 0.0 * y)  # 2.75 nodes per step at h = 1
    _, moved = domain.advection(flow, 1.0, Numerics()).advect(phi.copy(), layout, 0.0)
    # rint(2.75) = 3 whole nodes, fractional −0.25 left to the rows
    assert (moved.corners[0, 2] - layout.corners[0, 2]) % 60 == 3
