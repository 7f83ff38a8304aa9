"""Advection v·∇φ over one time step, split from the relaxation (Lie splitting).

Each domain picks its advection (:meth:`femphase.domains.base.Domain.advection`): the
structured channel's row shift and semi-Lagrangian step (:mod:`femphase.domains.grid.advection`),
the meshes' Galerkin steps (:mod:`femphase.domains.mesh.advection`). All take
the flow's mean over the step when it depends on time (:func:`femphase.flows.time_mean`:
exact in time for a flow of fixed direction field v = f(t) w(x), second order in dt for
others; exact for steady flows).

This module holds what they share: :class:`StepAdvection`, the nodal velocity, and the
regathering of fields after a move regroups the windows.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import scipy.sparse as sp

from femphase.caches import nbytes_of
from femphase.domains.base import Domain
from femphase.domains.layout import Layout
from femphase.flows import Flow, time_mean, velocity_at

__all__ = ["StepAdvection", "nodal_velocity", "regather"]


def regather(phi: np.ndarray, old: Layout, new: Layout) -> np.ndarray:
    """φ in ``old``'s order rearranged into ``new``'s (windows regrouped by a move)."""
    if np.array_equal(old.order, new.order):
        return phi
    return new.gather(old.scatter(phi))


class StepAdvection:
    """Advection over steps of fixed dt in ``flow`` on ``domain`` (the base of the three)."""

    #: Whether it moves the windows with the flow (the structured channel's row shift and
    #: semi-Lagrangian step), so that a field cannot leave its window by advection; the
    #: meshes' steps keep the windows where they are, and their refits leave room for the
    #: motion instead (:meth:`femphase.timestepping.stepper.Stepper.refit`)
    moves_windows: ClassVar[bool] = False

    def __init__(self, domain: Domain, flow: Flow, dt: float) -> None:
        self.domain, self.flow, self.dt = domain, flow, dt

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays and matrices it holds itself; what it keeps for reuse draws on
        the domain's budget (:attr:`~femphase.domains.base.Domain.caches`) and counts there."""
        return sum(nbytes_of(value) for value in vars(self).values()
                   if isinstance(value, np.ndarray) or sp.issparse(value))

    def velocity(self, time: float) -> np.ndarray:
        """(2, n_dofs) nodal velocity over the step starting at ``time`` (the flow's mean over
        it where the flow changes, as the advection takes it)."""
        if self.flow.steady:
            return nodal_velocity(self.domain, self.flow, time)
        if self.flow.profile is not None:  # v = f(t) w(x): f's mean times w, one evaluation of w
            return self.flow.mean_amplitude(time, self.dt) * nodal_velocity(self.domain, self.flow.profile)
        return time_mean(lambda t: nodal_velocity(self.domain, self.flow, t), time, self.dt)


def nodal_velocity(domain: Domain, flow: Flow, time: float = 0.0) -> np.ndarray:
    """(2, n_dofs): the flow's velocity at every dof."""
    if flow.stokes is not None:
        out = np.empty((2, domain.n_dofs))
        out[:, domain.dof_map] = flow.stokes.velocity_at_nodes()  # periodic partners carry equal values
        return out
    x, y = domain.coordinates
    return velocity_at(flow, x, y, time)
