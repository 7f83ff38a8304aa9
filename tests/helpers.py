"""Small scenes shared by the tests."""

import numpy as np

from femphase.mesh import channel_grid
from femphase.model import ModelParameters
from femphase.state import discs_state
from femphase.stepping import Discretisation, Numerics, SemiImplicitStepper
from femphase.windows import WindowPolicy


def small_system(centres, length=40.0, width=40.0, h=1.0, radius=8.0, initial_radius=None,
                 windows=True, diagonals="right"):
    """(discretisation, state) for discs at ``centres`` in a small channel."""
    grid = channel_grid(length, width, h)
    disc = Discretisation.structured(grid, diagonals)
    centres = np.asarray(centres, dtype=float)
    n = len(centres)
    r0 = np.full(n, radius if initial_radius is None else initial_radius)
    state = discs_state(grid, centres, np.full(n, radius), r0, 2.0, WindowPolicy.for_spacing(h, enabled=windows))
    return disc, state


def stepper(disc, state, dt=1.0, flow=None, params=ModelParameters(), **numerics):
    return SemiImplicitStepper(disc, params, Numerics(**numerics), dt, flow, state.radii)
