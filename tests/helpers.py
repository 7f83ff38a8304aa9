"""Small scenes shared by the tests."""

import numpy as np

from femphase.config import Numerics
from femphase.domains.grid.domain import GridDomain
from femphase.domains.grid.lattice import channel_grid
from femphase.model.energy import EnergyParts, FreeEnergy, WindowedFields
from femphase.model.parameters import ModelParameters
from femphase.state import State, discs_state
from femphase.timestepping.stepper import Stepper


def small_system(centres, length=40.0, width=40.0, h=1.0, radius=8.0, initial_radius=None,
                 windows=True, diagonals="right"):
    """(domain, state) for discs at ``centres`` in a small structured channel."""
    domain = GridDomain(channel_grid(length, width, h), diagonals)
    centres = np.asarray(centres, dtype=float)
    n = len(centres)
    r0 = np.full(n, radius if initial_radius is None else initial_radius)
    policy = domain.window_policy(Numerics(windows=windows, diagonals=diagonals))
    state = discs_state(domain, centres, np.full(n, radius), r0, 2.0, policy)
    return domain, state


def stepper(domain, state, dt=1.0, flow=None, params=ModelParameters(), **numerics):
    """The stepper of ``domain`` for ``state``'s particles (``numerics``: Numerics fields; the
    first-order scheme "euler" unless they name one: the tests using this helper check its
    stabilisation, solvers and splitting)."""
    return Stepper(domain, params, Numerics(**{"scheme": "euler", **numerics}), dt, flow, state.radii)


def energy_of(state: State, params: ModelParameters) -> EnergyParts:
    """The paper's free energy of ``state``, computed window by window."""
    layout, phi = state.flat()
    fields = WindowedFields(phi, layout, state.radii, state.domain.stiffness_apply(layout))
    return FreeEnergy.paper(params).parts(fields)
