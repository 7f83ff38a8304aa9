"""Time schemes: how one step of dt advances the gathered fields.

A scheme is a :class:`TimeScheme` registered in :data:`SCHEMES` under the name a scene
gives as ``numerics.scheme``. It receives the stepper that runs it (what it may use of it:
:class:`StepperProtocol`; the stepper owns the domain, energy, flow, solvers and advection)
and implements :meth:`TimeScheme.advance`. A new scheme is one subclass
(``docs/architecture.md``). The schemes: ``euler`` (:mod:`femphase.timestepping.euler`),
``sav2`` (:mod:`femphase.timestepping.sav2`), ``adaptive`` (the default,
:mod:`femphase.timestepping.adaptive`) and ``fd-heun`` (:mod:`femphase.timestepping.fd`).

The first-order step and its stabilisation, which the others build on (``euler``): Lie
splitting of advection and relaxation,

1. advection over dt by the domain's advection (exact row shift, semi-Lagrangian or
   Galerkin on meshes, :mod:`femphase.domains.advection`; skipped without flow);
2. relaxation, linearly implicit in the gradient term, explicit in the rest:

       (G/dt + J0 S M_L + J0 D K) φ¹ = (G/dt + J0 S M_L) φ* − J0 M_L g(φ*) + M_L s(tⁿ⁺¹)

   with G the time mass (lumped M_L or consistent M), g the explicit part of δF/δφ,
   D the energy's diffusivity (2γλ) and S the stabilisation.

Stabilisation ("auto", :meth:`femphase.timestepping.euler.LinearlyImplicitEuler.auto_stabilisation`): with G ≥ c M_L
(c = 1 lumped, 1/4 consistent P1 mass) and L a bound on the explicit energy's curvature
(:meth:`femphase.model.energy.FreeEnergy.curvature_bound`), F(φ¹) − F(φ⁰) ≤ −(c/(J0 dt) + S −
L/2) ``|φ¹ − φ⁰|²_{M_L}``, so S = max(0, L/2 − c/(J0 dt)) makes the no-flow step decrease the
discrete energy for any dt. At the paper's parameters S = 0 for dt ≤ dt* = 2c/(J0 L) ≈ 0.92
(lumped, several particles). Above dt*, G/dt + J0 S M_L = (J0 L/2) M_L no longer depends
on dt: the explicit forces advance by dt* per step whatever dt is, so large steps are stable
but slow the relaxation by dt/dt*.

In general (any S ≥ 0, either mass on smooth modes, where G ≈ M_L) one step moves φ by
−J0 g dt_eff with dt_eff = dt/(1 + J0 S dt): the relaxation runs 1 + J0 S dt times slower
than the clock (:attr:`femphase.timestepping.euler.LinearlyImplicitEuler.relaxation_slowdown`; = dt/dt* for the lumped
"auto"). :func:`stability_step` and :func:`auto_stabilisation` compute dt* and S without a
stepper (the accuracy guard, :mod:`femphase.run.guards`, uses them).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Callable, ClassVar, Protocol

import numpy as np

from femphase.config import Numerics
from femphase.domains.base import Domain
from femphase.domains.layout import Layout
from femphase.errors import BlowUpError, SceneError
from femphase.flows import Flow
from femphase.model.energy import FreeEnergy
from femphase.model.parameters import ModelParameters
from femphase.registry import Registry
from femphase.state import State

__all__ = ["MASS_BOUND", "SCHEMES", "StepperProtocol", "TimeScheme", "auto_stabilisation", "check_fields",
           "scheme_class", "stability_step"]

#: Time schemes by name (``numerics.scheme``). Each scheme module registers itself;
#: importing :mod:`femphase.timestepping` registers them all.
SCHEMES: Registry[type[TimeScheme]] = Registry("Time schemes", "numerics.scheme")


#: c of the bound G ≥ c M_L on the time mass, by ``numerics.mass``.
MASS_BOUND = {"lumped": 1.0, "consistent": 0.25}


def stability_step(energy: FreeEnergy, mobility: float, mass: str, smallest_radius: float, pairs: bool) -> float:
    """dt* = 2c/(J0 L): the largest dt at which the "auto" stabilisation is zero (inf when the
    explicit energy has no curvature)."""
    curvature = energy.curvature_bound(smallest_radius, pairs)
    return 2.0 * MASS_BOUND[mass] / (mobility * curvature) if curvature > 0 else float("inf")


def auto_stabilisation(energy: FreeEnergy, mobility: float, mass: str, dt: float, smallest_radius: float,
                       pairs: bool) -> float:
    """S = max(0, L/2 − c/(J0 dt)): the smallest S that makes the no-flow step energy-decreasing."""
    half_bound = 0.5 * energy.curvature_bound(smallest_radius, pairs)
    return max(0.0, half_bound - MASS_BOUND[mass] / (mobility * dt))


class StepperProtocol(Protocol):
    """What a time scheme uses of the :class:`~femphase.timestepping.stepper.Stepper` that
    runs it (the stepper owns the domain, the energy, the flow, the solvers and the advection;
    a scheme only combines them). Units: times in time units, lengths in lattice units."""

    domain: Domain
    params: ModelParameters
    numerics: Numerics
    dt: float                       # the phase's step
    flow: Flow
    energy: FreeEnergy
    advection: object | None        # the domain's advection over dt (None without flow)
    source: Callable | None         # s(x, y, t) added to the right-hand side, or None

    @property
    def mobility(self) -> float:
        """J0."""

    @property
    def smallest_radius(self) -> float:
        """The smallest target radius R_i (the area term's curvature bound)."""

    @property
    def pairs(self) -> bool:
        """Whether particles can overlap (the repulsion's curvature counts)."""

    def explicit_derivative(self, phi: np.ndarray, layout: Layout, radii: np.ndarray) -> np.ndarray:
        """g, the explicitly treated part of δF/δφ at every position."""

    def source_term(self, layout: Layout, time: float) -> np.ndarray | None:
        """s(x, y, t) at every position, or None."""

    def solve(self, nodal_rhs: np.ndarray, previous: np.ndarray, layout: Layout, shift: float,
              stabilisation: float, guess: np.ndarray | None = None,
              tolerance: float | None = None, guess_product: np.ndarray | None = None) -> np.ndarray:
        """φ with (shift·G + J0 S M_L + J0 D K) φ = M_L nodal_rhs + shift·G previous; ``guess``
        (default ``previous``) starts iterative solvers, ``tolerance`` (default
        ``numerics.krylov_tolerance`` of the phase) stops the batched Krylov solves,
        ``guess_product`` (the system times ``guess``, where known) spares them a product."""

    def last_product(self) -> np.ndarray:
        """The last batched solve's system times its solution, from its final residual."""


class TimeScheme(ABC):
    """Advances the gathered fields of all particles by one step of ``stepper.dt``.

    order   the scheme's order of accuracy in dt (with exact advection)
    """

    name: ClassVar[str]
    order: ClassVar[int]
    #: Whether :meth:`advance` takes a fourth argument ``steps`` and advances by that many
    #: steps at once, sharing work between them; else the stepper calls it step by step.
    merges_steps: ClassVar[bool] = False
    #: Whether it refits the windows between its substeps (:meth:`Stepper.refit` without a
    #: time), so that a step's motion never runs more than one substep past a refit
    refits_substeps: ClassVar[bool] = False
    #: Whether it reads ``numerics.stabilisation`` (a stabilised explicit part; only euler)
    stabilised: ClassVar[bool] = False
    #: Whether its steps may compute in single precision under flow (``numerics.precision =
    #: "mixed"``); the finite-difference reference's stay double
    mixed_precision: ClassVar[bool] = True
    #: The time masses (``numerics.mass``) it can step with
    masses: ClassVar[tuple[str, ...]] = ("lumped", "consistent")

    def __init__(self, stepper: StepperProtocol) -> None:
        self.check_mass(stepper.numerics.mass)
        self.stepper = stepper

    @classmethod
    def check_mass(cls, mass: str) -> None:
        """SceneError when the scheme cannot step with the time mass ``mass``."""
        if mass not in cls.masses:
            others = [name for name in SCHEMES.names() if mass in SCHEMES.get(name).masses]
            raise SceneError("numerics.mass", mass, " or ".join(f'"{m}"' for m in cls.masses)
                             + f' with numerics.scheme = "{cls.name}" (or numerics.scheme = '
                             + " or ".join(f'"{n}"' for n in others) + f' for the {mass} mass)')

    @abstractmethod
    def advance(self, phi: np.ndarray, layout: Layout, state: State) -> tuple[np.ndarray, Layout]:
        """φ (layout order) at ``state.time`` + dt (+ steps·dt, :attr:`merges_steps`), and the
        layout it lives on (advection may move windows). ``phi`` is the stepper's own gathered
        copy of ``state``'s fields: it may be overwritten. ``state`` is read (time, step,
        radii) and not changed, except ``state.memory``, where a scheme keeps what it carries
        from step to step (saved in checkpoints, so that a resumed run continues bit for bit)."""

    def start_phase(self, state: State) -> None:
        """Called before the first step of a phase (not on a resume inside one): drop from
        ``state.memory`` what describes the dynamics of the phase before. Nothing here."""

def scheme_class(name: object, key: str = "numerics.scheme") -> type[TimeScheme]:
    """The time scheme registered as ``name``, checked as a scheme: a :class:`TimeScheme`
    subclass with its order of accuracy in dt (``order``, which ``femphase converge --dt``
    extrapolates with). SceneError naming ``key`` otherwise: an entry of the user's own
    module is named by its definition."""
    entry = SCHEMES.get(name, key)
    where = SCHEMES.origin(name) or f"{getattr(entry, '__module__', '')}.{getattr(entry, '__qualname__', entry)}"
    if not (isinstance(entry, type) and issubclass(entry, TimeScheme)):
        raise SceneError(key, name, f"a registered subclass of femphase.timestepping.base.TimeScheme; {where} is "
                         f"a {type(entry).__name__}")
    order = getattr(entry, "order", None)
    if not (isinstance(order, (int, float)) and not isinstance(order, bool) and order > 0):
        raise SceneError(key, name, f"a scheme that states its order of accuracy in dt: {where} has no class "
                         f"attribute order > 0 (it has {order!r})")
    return entry


def check_fields(phi: np.ndarray, margin: float, step: int, time: float) -> None:
    """Raise BlowUpError when phi is not finite or leaves [−margin, 1 + margin]."""
    if not np.all(np.isfinite(phi)):
        raise BlowUpError(step, time, "φ is not finite (NaN or inf)")
    low, high = float(phi.min()), float(phi.max())
    if low < -margin or high > 1.0 + margin:
        raise BlowUpError(
            step, time,
            f"φ left [{-margin:g}, {1 + margin:g}] (min {low:.3g}, max {high:.3g}); "
            "try a smaller dt (the adaptive scheme: a smaller numerics.tolerance_t; euler: also "
            "numerics.stabilisation > 0), or, if the overshoot is physical, a larger numerics.blowup_margin",
        )
