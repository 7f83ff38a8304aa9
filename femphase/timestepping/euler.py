"""The first-order scheme ``euler``: Lie splitting of advection and relaxation, the relaxation
linearly implicit in the gradient term and explicit in the rest, with the stabilisation S
that makes the no-flow step energy-decreasing at any dt (the step and its derivation:
:mod:`femphase.timestepping.base`). :func:`linearly_implicit_step` is that step, which the
second-order schemes use as their predictor and as their energy-stable fallback.
"""

from __future__ import annotations

import numpy as np

from femphase.domains.layout import Layout
from femphase.model.energy import FreeEnergy, WindowedFields
from femphase.state import State
from femphase.timestepping.base import SCHEMES, StepperProtocol, TimeScheme, auto_stabilisation, stability_step

__all__ = ["LinearlyImplicitEuler", "linearly_implicit_step"]


@SCHEMES.register("euler")
class LinearlyImplicitEuler(TimeScheme):
    """First order: Lie splitting of exact/Galerkin advection and a linearly implicit Euler
    relaxation (gradient term implicit, the rest explicit), energy-stable without flow at
    any dt through the stabilisation S ("auto")."""

    name = "euler"
    order = 1
    stabilised = True

    def __init__(self, stepper: StepperProtocol) -> None:
        super().__init__(stepper)
        setting = stepper.numerics.stabilisation
        self.stabilisation = self.auto_stabilisation() if setting == "auto" else float(setting)

    def auto_stabilisation(self) -> float:
        """The smallest S that makes the no-flow step energy-decreasing (module docstring)."""
        stepper = self.stepper
        return auto_stabilisation(stepper.energy, stepper.mobility, stepper.numerics.mass, stepper.dt,
                                  stepper.smallest_radius, stepper.pairs)

    @property
    def stability_step(self) -> float:
        """dt* = 2c/(J0 L): above it the "auto" stabilisation is active (module docstring)."""
        stepper = self.stepper
        return stability_step(stepper.energy, stepper.mobility, stepper.numerics.mass, stepper.smallest_radius,
                              stepper.pairs)

    @property
    def relaxation_slowdown(self) -> float:
        """1 + J0 S dt: how many times slower than dt the explicit forces relax (1 for S = 0;
        dt/dt* for the lumped "auto" stabilisation above dt*)."""
        return 1.0 + self.stepper.mobility * self.stabilisation * self.stepper.dt

    def advance(self, phi: np.ndarray, layout: Layout, state: State) -> tuple[np.ndarray, Layout]:
        if self.stepper.advection is not None:
            phi, layout = self.stepper.advection.advect(phi, layout, state.time)
        return self.relax(phi, layout, state.time, state.radii), layout

    def relax(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray) -> np.ndarray:
        """The relaxation over one step from ``time``: one linearly implicit Euler step."""
        return linearly_implicit_step(self.stepper, phi, layout, radii, self.stepper.dt, self.stabilisation,
                                      time + self.stepper.dt)


def linearly_implicit_step(stepper: StepperProtocol, phi: np.ndarray, layout: Layout, radii: np.ndarray, dt: float,
                           stabilisation: float, source_time: float,
                           fields: WindowedFields | None = None, energy: "FreeEnergy | None" = None,
                           tolerance: float | None = None) -> np.ndarray:
    """One linearly implicit Euler relaxation step of ``dt`` (module docstring), the source
    taken at ``source_time``: (G/dt + J0 S M_L + J0 D K) φ¹ = (G/dt + J0 S M_L) φ⁰ − J0 M_L g(φ⁰)
    + M_L s. ``fields``: φ⁰ as WindowedFields, if the caller has them (shares their cached
    sums); ``energy``: whose g (the stepper's unless given; D is always the stepper's);
    ``tolerance``: the batched Krylov solve's (default ``numerics.krylov_tolerance`` of the
    phase)."""
    j0 = stepper.mobility
    nodal = (energy or stepper.energy).explicit_derivative(fields or WindowedFields(phi, layout, radii))
    nodal *= -j0
    if stabilisation:
        nodal += (j0 * stabilisation) * phi
    source = stepper.source_term(layout, source_time)
    if source is not None:
        nodal += source
    return stepper.solve(nodal, phi, layout, 1.0 / dt, stabilisation, tolerance=tolerance)
