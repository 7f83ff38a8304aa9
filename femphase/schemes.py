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
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from .stepping import SCHEMES
from .windows import Layout

if TYPE_CHECKING:
    from .stepping import Stepper


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
        mass_bound = 0.25 if stepper.numerics.mass == "consistent" else 1.0
        half_bound = 0.5 * stepper.energy.curvature_bound(stepper.smallest_radius, stepper.pairs)
        return max(0.0, half_bound - mass_bound / (stepper.mobility * stepper.dt))

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
