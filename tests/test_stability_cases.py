"""The most telling cases of benchmarks/stability.py, as assertions (the full matrix is there)."""

import numpy as np
import pytest
from helpers import energy_of, small_system, stepper

from femphase.config import Numerics
from femphase.errors import BlowUpError
from femphase.flows import linear_shear
from femphase.model.parameters import ModelParameters
from femphase.timestepping.stepper import Stepper

# three discs of the full radius almost on top of each other: far from equilibrium, with
# large overlap (repulsion) forces
OVERLAPPING = [[20.0, 20.0], [23.0, 20.0], [20.0, 23.0]]


def energy(state, step):
    return energy_of(state, step.params).total


@pytest.mark.parametrize("mass", ["lumped", "consistent"])
def test_huge_steps_without_flow_decrease_the_energy_with_auto_stabilisation(mass):
    domain, state = small_system(OVERLAPPING, initial_radius=8.0)
    step = stepper(domain, state, dt=100.0, mass=mass)
    assert step.scheme.stabilisation > 0  # dt = 100 needs it
    energies = [energy(state, step)]
    for _ in range(10):
        step.step(state)
        energies.append(energy(state, step))
    rises = np.diff(energies) / np.abs(energies[:-1])
    assert rises.max() <= 1e-10
    assert energies[-1] < 0.9 * energies[0]  # it did relax
    assert all(f.min() > -0.1 and f.max() < 1.5 for f in state.fields)


def test_huge_steps_in_shear_stay_bounded():
    domain, state = small_system([[20.0, 12.0], [20.0, 28.0]], initial_radius=4.0)
    step = stepper(domain, state, dt=100.0, flow=linear_shear(10.0, 40.0))
    for _ in range(10):
        step.step(state)
    assert all(np.isfinite(f).all() and f.min() > -0.1 and f.max() < 1.5 for f in state.fields)


def test_without_stabilisation_a_large_step_blows_up_with_the_step_named_and_the_state_kept():
    domain, state = small_system(OVERLAPPING, initial_radius=8.0)
    step = stepper(domain, state, dt=10.0, stabilisation=0.0)
    before = state.copy()
    with pytest.raises(BlowUpError, match=r"step 1 \(t = 10\).*smaller dt") as failure:
        step.step(state)
    assert failure.value.step == 1
    assert state.step == 0 and all(np.array_equal(a, b) for a, b in zip(state.fields, before.fields))


def test_a_diverging_run_is_never_a_silent_nan():
    # without the range guard the unstable step grows to inf/NaN within a few steps: the
    # finiteness check must still stop it, naming the step, and leave the last finite state
    domain, state = small_system(OVERLAPPING, initial_radius=8.0)
    step = stepper(domain, state, dt=100.0, stabilisation=0.0, blowup_margin=1e300)
    with pytest.raises(BlowUpError, match="not finite") as failure, np.errstate(all="ignore"):
        for _ in range(50):
            step.step(state)
    assert failure.value.step == state.step + 1
    assert all(np.isfinite(f).all() for f in state.fields)


def test_a_non_finite_source_is_reported_at_its_step():
    domain, state = small_system([[20.0, 20.0]], initial_radius=8.0)

    def source(x, y, t):
        return np.full_like(x, np.nan if t > 2.5 else 0.0)

    step = Stepper(domain, ModelParameters(), Numerics(scheme="euler"), 1.0, source=source, radii=state.radii)
    with pytest.raises(BlowUpError, match=r"step 3 \(t = 3\).*not finite"):
        for _ in range(5):
            step.step(state)
    assert state.step == 2
