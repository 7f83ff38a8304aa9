"""The discrete free energy, its derivative, and energy stability of the no-flow step."""

import numpy as np
import pytest
from helpers import energy_of, small_system, stepper

from femphase.domains.grid.domain import GridDomain
from femphase.domains.grid.lattice import channel_grid
from femphase.domains.grid.windows import Window
from femphase.model.energy import FreeEnergy, WindowedFields
from femphase.model.parameters import ModelParameters, double_well
from femphase.state import State


def random_state(seed=3):
    """Three random fields (values in [−0.1, 1.1]) on overlapping windows of a 12 × 11 lattice:
    the whole channel, one wrapping across the seam from the bottom wall, one at the top wall."""
    domain = GridDomain(channel_grid(12, 10, 1.0))
    ny, nx = domain.lattice
    windows = [domain.full_window(), Window(0, 6, 8, 7), Window(ny - 5, 5, 3, 6)]
    rng = np.random.default_rng(seed)
    fields = [rng.uniform(-0.1, 1.1, size=domain.window_dofs(w).size) for w in windows]
    return State(domain, windows, fields, np.array([2.0, 2.5, 3.0]))


def test_gradient_matches_finite_difference_of_discrete_energy():
    state = random_state()
    domain, params = state.domain, ModelParameters()
    energy = FreeEnergy.paper(params)
    layout, phi = state.flat()
    stiffness = domain.stiffness_apply(layout)

    def total(values):
        return energy.parts(WindowedFields(values, layout, state.radii, stiffness)).total

    # δF/δφ = g + D M_L⁻¹ K φ (lumped metric), window by window
    gradient = energy.explicit_derivative(WindowedFields(phi, layout, state.radii))
    gradient += energy.diffusivity * stiffness(phi) / layout.mass
    overlaps = layout.overlap_positions
    assert overlaps.size > 0
    positions = [0, 37, layout.offsets[1] - 1, layout.offsets[-1] - 1, *overlaps[[0, overlaps.size // 2, -1]]]
    eps = 1e-6
    for p in positions:
        plus, minus = phi.copy(), phi.copy()
        plus[p] += eps
        minus[p] -= eps
        numeric = (total(plus) - total(minus)) / (2 * eps)
        # ∂F_h/∂φ_ik = m_k (δF/δφ_i)_k
        assert numeric == pytest.approx(layout.mass[p] * gradient[p], rel=1e-6, abs=1e-9)


def test_a_decaying_terms_rate_times_phi_is_its_derivative():
    # the repulsion's decay_rate drives the default scheme's split flow step, and nothing
    # tied it to the derivative the energy test checks: halved, it changed the split step's
    # fields by 0.06 with every test passing
    state = random_state()
    layout, phi = state.flat()
    fields = WindowedFields(phi, layout, state.radii)
    decaying = [term for term in FreeEnergy.paper(ModelParameters()).terms if term.decays]
    assert [term.name for term in decaying] == ["repulsion"]
    for term in decaying:
        rate = term.decay_rate(fields)
        assert np.all(rate >= 0)
        np.testing.assert_allclose(rate * phi, term.explicit_derivative(fields), rtol=1e-12, atol=1e-15)


def dense_energy(state, params):
    """The free energy from the dense (N, n_dofs) fields and the assembled operators."""
    ops = state.domain.operators
    phis = state.global_fields()
    m, lam = ops.lumped_mass, params.interface_width
    gradient_term = np.einsum("ik,ik->", phis, (ops.stiffness @ phis.T).T)
    interface = params.tension / lam * (np.sum(double_well(phis) @ m) + lam**2 * gradient_term)
    ratio = (phis**2 @ m) / (np.pi * state.radii**2)
    area = params.area_stiffness * np.sum((1 - ratio) ** 2)
    squares = phis**2
    ordered_pairs = np.zeros(ops.lumped_mass.size)  # Σ_i Σ_{j≠i} φ_i² φ_j²
    for i in range(len(phis)):
        for j in range(len(phis)):
            if i != j:
                ordered_pairs += squares[i] * squares[j]
    repulsion = params.repulsion / lam * (m @ ordered_pairs)
    return {"interface": interface, "area": area, "repulsion": repulsion}


@pytest.mark.parametrize("case", ["random", "discs"])
def test_window_wise_energy_equals_the_dense_energy(case):
    params = ModelParameters()
    if case == "random":
        state = random_state(5)
    else:
        # overlapping discs on windows, one across the seam, relaxed a few steps
        domain, state = small_system([[20, 14], [31, 16], [3, 22]], initial_radius=7.0)
        step = stepper(domain, state)
        for _ in range(5):
            step.step(state)
        assert state.layout().overlap_positions.size > 0
    parts = energy_of(state, params)
    dense = dense_energy(state, params)
    assert set(parts) == set(dense)
    for name, value in dense.items():
        assert abs(value) > 1e-3, name  # each part is exercised
        assert parts[name] == pytest.approx(value, rel=1e-10), name
    assert parts.total == pytest.approx(sum(dense.values()), rel=1e-10)


def test_parts_follow_the_stated_conventions():
    domain = GridDomain(channel_grid(20, 20, 1.0))
    params = ModelParameters()
    full = domain.full_window()
    one = [np.zeros(domain.n_dofs), np.zeros(domain.n_dofs)]
    one[0][5] = one[1][5] = 1.0
    energy = energy_of(State(domain, [full, full], one, np.array([8.0, 8.0])), params)
    m = domain.operators.lumped_mass[5]
    # ordered pairs: the pair (0, 1) counts twice: 2 κ/λ φ0² φ1² m
    assert energy.repulsion == pytest.approx(2 * params.repulsion / params.interface_width * m)
    a = m / (np.pi * 64)
    assert energy.area == pytest.approx(2 * params.area_stiffness * (1 - a) ** 2)


@pytest.mark.parametrize("dt", [0.1, 1.0, 10.0])
def test_no_flow_dynamics_never_increase_the_free_energy(dt):
    # three particles growing from R/2 into contact: interface, area and repulsion all act
    domain, state = small_system([[12, 14], [27, 14], [20, 27]], length=40, width=40, initial_radius=5.0,
                                 windows=False)
    step = stepper(domain, state, dt=dt)
    energies = []
    for _ in range(int(round(120 / dt)) if dt < 1 else 60):
        energies.append(energy_of(state, step.params).total)
        step.step(state)
    energies = np.array(energies)
    increases = np.diff(energies)
    assert increases.max() <= 1e-10 * abs(energies).max(), increases.max()
    assert energies[-1] < 0.5 * energies[0]  # it did relax


def test_stabilisation_is_zero_at_the_paper_step_and_grows_for_large_steps():
    domain, state = small_system([[20, 20]])
    assert stepper(domain, state, dt=0.1).scheme.stabilisation == 0.0
    assert stepper(domain, state, dt=10.0).scheme.stabilisation > stepper(domain, state, dt=1.0).scheme.stabilisation
