"""The second-order scheme "sav2" (femphase.schemes.RelaxedSAV2).

Order 2 in dt on the manufactured solution of verification/mms.py (at h = 0.25 the spatial
error, ~0.003, is small against the temporal errors at dt = 1 and 0.5: 0.074 and 0.020),
the free energy never increases without flow at any dt (up to 100, with the adaptive scheme
too), and a resumed run continues bit for
bit (the auxiliary variable r is kept in the checkpoint)."""

import numpy as np
import pytest

from femphase.channel import ChannelDomain
from femphase.errors import SceneError
from femphase.flows import linear_shear
from femphase.io import load_checkpoint, save_checkpoint
from femphase.mesh import channel_grid
from femphase.model import ModelParameters
from femphase.state import State
from femphase.stepping import Numerics, Stepper
from helpers import energy_of, small_system
from verification import mms


def _mms_error(dt: float, scheme: str, h: float = 0.25) -> float:
    domain = ChannelDomain(channel_grid(mms.LX, mms.LY, h))
    x, y = domain.coordinates
    state = State(domain, [domain.full_window()], [mms.exact(x, y, 0.0)], np.array([mms.PARAMS.radius]))
    stepper = Stepper(domain, mms.PARAMS, Numerics(windows=False, scheme=scheme), dt,
                      linear_shear(mms.SHEAR_RATE, mms.LY), state.radii, mms.source)
    for _ in range(round(mms.FINAL_TIME / dt)):
        stepper.step(state)
    return mms.error_norms(domain, state.global_field(0), mms.FINAL_TIME)[0]


def test_sav2_is_second_order_in_time_where_euler_is_first():
    sav = [_mms_error(dt, "sav2") for dt in (1.0, 0.5)]
    euler = [_mms_error(dt, "euler") for dt in (1.0, 0.5)]
    assert np.log2(sav[0] / sav[1]) > 1.75
    assert np.log2(euler[0] / euler[1]) < 1.2
    assert sav[1] < euler[1] / 10


@pytest.mark.parametrize("scheme", ["sav2", "adaptive"])
@pytest.mark.parametrize("dt", [0.1, 1.0, 10.0, 100.0])
def test_the_second_order_schemes_never_increase_the_free_energy_without_flow(dt, scheme):
    # from R/2 the relaxation is violent: without the energy check sav2 raised F at dt = 10
    # and left [0, 1] (φ = 3.6) at dt = 100
    domain, state = small_system([[12.0, 20.0], [26.0, 20.0]], initial_radius=4.0)
    stepper = Stepper(domain, ModelParameters(), Numerics(scheme=scheme, tolerance_t=1e-2), dt, None, state.radii)
    energies = [energy_of(state, ModelParameters()).total]
    for _ in range(max(3, round(60 / dt))):
        stepper.step(state)
        energies.append(energy_of(state, ModelParameters()).total)
    assert np.all(np.diff(energies) <= 1e-12 * abs(energies[0]))
    assert energies[-1] < energies[0]  # and it relaxes (slowly at dt = 100: the fallback saturates)


@pytest.mark.parametrize("flow", [None, linear_shear(0.5, 40.0)], ids=["still", "shear"])
def test_sav2_resumes_bit_for_bit_from_a_checkpoint(tmp_path, flow):
    domain, state = small_system([[12.0, 20.0], [26.0, 20.0]], initial_radius=6.0)
    straight = state.copy()
    make = lambda: Stepper(domain, ModelParameters(), Numerics(scheme="sav2"), 0.5, flow, state.radii)  # noqa: E731
    stepper = make()
    for _ in range(20):
        stepper.step(straight)
    for _ in range(10):
        stepper.step(state)
    save_checkpoint(tmp_path / "c.h5", state)
    resumed, _ = load_checkpoint(tmp_path / "c.h5", domain)
    assert ("sav_r" in resumed.memory) == (flow is None)  # under flow the step is the plain IMEX midpoint
    stepper = make()
    for _ in range(10):
        stepper.step(resumed)
    assert all(np.array_equal(a, b) for a, b in zip(resumed.fields, straight.fields))


def test_sav2_needs_the_lumped_mass():
    domain, state = small_system([[20.0, 20.0]])
    with pytest.raises(SceneError, match="numerics.mass"):
        Stepper(domain, ModelParameters(), Numerics(scheme="sav2", mass="consistent"), 1.0, None, state.radii)
