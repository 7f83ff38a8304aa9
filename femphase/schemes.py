"""Time schemes: how one step of dt advances the gathered fields.

A scheme is a :class:`TimeScheme` registered in :data:`femphase.stepping.SCHEMES` under the
name a scene gives as ``numerics.scheme``. It receives the :class:`~femphase.stepping.Stepper`
(which owns the domain, energy, flow, solvers and advection) and implements
:meth:`TimeScheme.advance`. A new scheme is one subclass (``docs/architecture.md``).

``euler`` (default): Lie splitting of advection and relaxation,

1. advection over dt by the domain's advection (exact row shift, semi-Lagrangian or
   Galerkin–Padé, :mod:`femphase.advection`; skipped without flow);
2. relaxation, linearly implicit in the gradient term, explicit in the rest:

       (G/dt + J0 S M_L + J0 D K) φ¹ = (G/dt + J0 S M_L) φ* − J0 M_L g(φ*) + M_L s(tⁿ⁺¹)

   with G the time mass (lumped M_L or consistent M), g the explicit part of δF/δφ,
   D the energy's diffusivity (2γλ) and S the stabilisation.

Stabilisation ("auto", :meth:`LinearlyImplicitEuler.auto_stabilisation`): with G ≥ c M_L
(c = 1 lumped, 1/4 consistent P1 mass) and L a bound on the explicit energy's curvature
(:meth:`femphase.energy.FreeEnergy.curvature_bound`), F(φ¹) − F(φ⁰) ≤ −(c/(J0 dt) + S −
L/2) |φ¹ − φ⁰|²_{M_L}, so S = max(0, L/2 − c/(J0 dt)) makes the no-flow step decrease the
discrete energy for any dt. At the paper's parameters S = 0 for dt ≤ dt* = 2c/(J0 L) ≈ 0.92
(lumped, several particles). Above dt*, G/dt + J0 S M_L = (J0 L/2) M_L no longer depends
on dt: the explicit forces advance by dt* per step whatever dt is, so large steps are stable
but slow the relaxation by dt/dt*.

In general (any S ≥ 0, either mass on smooth modes, where G ≈ M_L) one step moves φ by
−J0 g dt_eff with dt_eff = dt/(1 + J0 S dt): the relaxation runs 1 + J0 S dt times slower
than the clock (:attr:`LinearlyImplicitEuler.relaxation_slowdown`; = dt/dt* for the lumped
"auto"). :func:`stability_step` and :func:`auto_stabilisation` compute dt* and S without a
stepper (the accuracy guard, :mod:`femphase.guards`, uses them).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from .stepping import SCHEMES
from .windows import Layout

if TYPE_CHECKING:
    from .energy import FreeEnergy
    from .stepping import Stepper


#: c of the bound G ≥ c M_L on the time mass, by ``numerics.mass``.
MASS_BOUND = {"lumped": 1.0, "consistent": 0.25}


def stability_step(energy: "FreeEnergy", mobility: float, mass: str, smallest_radius: float, pairs: bool) -> float:
    """dt* = 2c/(J0 L): the largest dt at which the "auto" stabilisation is zero (inf when the
    explicit energy has no curvature)."""
    curvature = energy.curvature_bound(smallest_radius, pairs)
    return 2.0 * MASS_BOUND[mass] / (mobility * curvature) if curvature > 0 else float("inf")


def auto_stabilisation(energy: "FreeEnergy", mobility: float, mass: str, dt: float, smallest_radius: float,
                       pairs: bool) -> float:
    """S = max(0, L/2 − c/(J0 dt)): the smallest S that makes the no-flow step energy-decreasing."""
    half_bound = 0.5 * energy.curvature_bound(smallest_radius, pairs)
    return max(0.0, half_bound - MASS_BOUND[mass] / (mobility * dt))


class TimeScheme(ABC):
    """Advances the gathered fields of all particles by one step of ``stepper.dt``.

    order   the scheme's order of accuracy in dt (with exact advection)
    """

    name: ClassVar[str]
    order: ClassVar[int]

    def __init__(self, stepper: "Stepper") -> None:
        self.stepper = stepper

    @abstractmethod
    def advance(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray) -> tuple[np.ndarray, Layout]:
        """φ (layout order) at time + dt, and the layout it lives on (advection may move
        windows). ``phi`` is the stepper's own gathered copy: it may be overwritten."""


@SCHEMES.register("euler")
class LinearlyImplicitEuler(TimeScheme):
    """First order: Lie splitting of exact/Galerkin advection and a linearly implicit Euler
    relaxation (gradient term implicit, the rest explicit), energy-stable without flow at
    any dt through the stabilisation S ("auto")."""

    name = "euler"
    order = 1

    def __init__(self, stepper: "Stepper") -> None:
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

    def advance(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray) -> tuple[np.ndarray, Layout]:
        if self.stepper.advection is not None:
            phi, layout = self.stepper.advection.advect(phi, layout, time)
        return self.relax(phi, layout, time, radii), layout

    def relax(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray) -> np.ndarray:
        """The relaxation over one step from ``time``: one linearly implicit Euler step."""
        stepper = self.stepper
        j0 = stepper.mobility
        nodal = stepper.explicit_derivative(phi, layout, radii)
        nodal *= -j0
        if self.stabilisation:
            nodal += (j0 * self.stabilisation) * phi
        source = stepper.source_term(layout, time + stepper.dt)
        if source is not None:
            nodal += source
        return stepper.solve(nodal, phi, layout, 1.0 / stepper.dt, self.stabilisation)
