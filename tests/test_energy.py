"""The discrete free energy, its derivative, and energy stability of the no-flow step."""

import numpy as np
import pytest

from femphase.energy import free_energy, free_energy_gradient
from femphase.mesh import channel_grid
from femphase.model import ModelParameters
from femphase.stepping import Discretisation

from helpers import small_system, stepper


def test_gradient_matches_finite_difference_of_discrete_energy():
    grid = channel_grid(12, 10, 1.0)
    ops = Discretisation.structured(grid).operators
    rng = np.random.default_rng(3)
    phis = rng.uniform(-0.1, 1.1, size=(3, grid.n_nodes))
    radii = np.array([2.0, 2.5, 3.0])
    params = ModelParameters()
    gradient = free_energy_gradient(phis, radii, params, ops)
    eps = 1e-6
    for i, k in [(0, 0), (1, 37), (2, 65), (0, grid.n_nodes - 1)]:
        plus, minus = phis.copy(), phis.copy()
        plus[i, k] += eps
        minus[i, k] -= eps
        numeric = (free_energy(plus, radii, params, ops).total - free_energy(minus, radii, params, ops).total) / (2 * eps)
        # ∂F_h/∂φ_ik = m_k (δF/δφ_i)_k
        assert numeric == pytest.approx(ops.lumped_mass[k] * gradient[i, k], rel=1e-6, abs=1e-9)


def test_parts_follow_the_stated_conventions():
    grid = channel_grid(20, 20, 1.0)
    ops = Discretisation.structured(grid).operators
    params = ModelParameters()
    one = np.zeros((2, grid.n_nodes))
    one[0, 5] = one[1, 5] = 1.0
    energy = free_energy(one, np.array([8.0, 8.0]), params, ops)
    m = ops.lumped_mass[5]
    # ordered pairs: the pair (0, 1) counts twice: 2 κ/λ φ0² φ1² m
    assert energy.repulsion == pytest.approx(2 * params.repulsion / params.interface_width * m)
    a = m / (np.pi * 64)
    assert energy.area == pytest.approx(2 * params.area_stiffness * (1 - a) ** 2)


@pytest.mark.parametrize("dt", [0.1, 1.0, 10.0])
def test_no_flow_dynamics_never_increase_the_free_energy(dt):
    # three particles growing from R/2 into contact: interface, area and repulsion all act
    disc, state = small_system([[12, 14], [27, 14], [20, 27]], length=40, width=40, initial_radius=5.0, windows=False)
    step = stepper(disc, state, dt=dt)
    energies = []
    for _ in range(int(round(120 / dt)) if dt < 1 else 60):
        energies.append(free_energy(state.global_fields(), state.radii, step.params, disc.operators).total)
        step.step(state)
    energies = np.array(energies)
    increases = np.diff(energies)
    assert increases.max() <= 1e-10 * abs(energies).max(), increases.max()
    assert energies[-1] < 0.5 * energies[0]  # it did relax


def test_stabilisation_is_zero_at_the_paper_step_and_grows_for_large_steps():
    disc, state = small_system([[20, 20]])
    assert stepper(disc, state, dt=0.1).stabilisation == 0.0
    assert stepper(disc, state, dt=10.0).stabilisation > stepper(disc, state, dt=1.0).stabilisation
