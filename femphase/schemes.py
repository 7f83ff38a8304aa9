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
from collections import OrderedDict
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from .energy import WindowedFields
from .errors import BlowUpError, SceneError
from .stepping import SCHEMES, check_fields
from .windows import Layout

if TYPE_CHECKING:
    from .energy import FreeEnergy
    from .state import State
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
    #: Whether :meth:`advance` takes a fourth argument ``steps`` and advances by that many
    #: steps at once, sharing work between them; else the stepper calls it step by step.
    merges_steps: ClassVar[bool] = False
    #: Whether its steps may compute in single precision under flow (``numerics.precision =
    #: "mixed"``); the finite-difference reference's stay double
    mixed_precision: ClassVar[bool] = True

    def __init__(self, stepper: "Stepper") -> None:
        self.stepper = stepper

    @abstractmethod
    def advance(self, phi: np.ndarray, layout: Layout, state: "State") -> tuple[np.ndarray, Layout]:
        """φ (layout order) at ``state.time`` + dt (+ steps·dt, :attr:`merges_steps`), and the
        layout it lives on (advection may move windows). ``phi`` is the stepper's own gathered
        copy of ``state``'s fields: it may be overwritten. ``state`` is read (time, step,
        radii) and not changed, except ``state.memory``, where a scheme keeps what it carries
        from step to step (saved in checkpoints, so that a resumed run continues bit for bit)."""

    def start_phase(self, state: "State") -> None:
        """Called before the first step of a phase (not on a resume inside one): drop from
        ``state.memory`` what describes the dynamics of the phase before. Nothing here."""


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

    def advance(self, phi: np.ndarray, layout: Layout, state: "State") -> tuple[np.ndarray, Layout]:
        if self.stepper.advection is not None:
            phi, layout = self.stepper.advection.advect(phi, layout, state.time)
        return self.relax(phi, layout, state.time, state.radii), layout

    def relax(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray) -> np.ndarray:
        """The relaxation over one step from ``time``: one linearly implicit Euler step."""
        return linearly_implicit_step(self.stepper, phi, layout, radii, self.stepper.dt, self.stabilisation,
                                      time + self.stepper.dt)


def linearly_implicit_step(stepper: "Stepper", phi: np.ndarray, layout: Layout, radii: np.ndarray, dt: float,
                           stabilisation: float, source_time: float,
                           fields: WindowedFields | None = None, energy: "FreeEnergy | None" = None) -> np.ndarray:
    """One linearly implicit Euler relaxation step of ``dt`` (module docstring), the source
    taken at ``source_time``: (G/dt + J0 S M_L + J0 D K) φ¹ = (G/dt + J0 S M_L) φ⁰ − J0 M_L g(φ⁰)
    + M_L s. ``fields``: φ⁰ as WindowedFields, if the caller has them (shares their cached
    sums); ``energy``: whose g (the stepper's unless given; D is always the stepper's)."""
    j0 = stepper.mobility
    nodal = (energy or stepper.energy).explicit_derivative(fields or WindowedFields(phi, layout, radii))
    nodal *= -j0
    if stabilisation:
        nodal += (j0 * stabilisation) * phi
    source = stepper.source_term(layout, source_time)
    if source is not None:
        nodal += source
    return stepper.solve(nodal, phi, layout, 1.0 / dt, stabilisation)


@SCHEMES.register("sav2")
class RelaxedSAV2(TimeScheme):
    """Second order: Strang splitting (advection over dt/2, relaxation over dt, advection
    over dt/2) with a relaxation step that is Crank–Nicolson in the gradient term and
    explicit midpoint in the rest (from a linearly implicit Euler predictor): relaxed
    scalar-auxiliary-variable (SAV) form without flow, plain IMEX midpoint with flow, the
    repulsion then split off and integrated in exponential form (:meth:`relax`). No
    stabilisation to saturate. Lumped mass only.

    Energy stability: the SAV step never increases its modified energy, but the free energy
    F itself can rise at large dt (measured: dt = 10 on two particles relaxing from R/2;
    at dt = 100 φ reached 3.6). So without flow each step checks F and, where it would
    rise, takes the energy-stable Euler step (:meth:`fallback`) instead: F never rises, at
    any dt (``tests/test_sav2.py`` up to dt = 100); such steps are first order and counted
    in ``state.memory["sav_fallbacks"]``. The check costs one energy evaluation per step and
    only runs without flow (with flow F is not monotone)."""

    name = "sav2"
    order = 2
    #: C in r = √(E1 + C): any C > 0 keeps the root real (E1 ≥ 0 for the paper's terms).
    OFFSET = 1.0
    #: η: the share of each step's dissipation the relaxation of r may give back (Jiang,
    #: Zhang & Yang 2022); 0.95 keeps 5 % of it as a strict decrease.
    RELAXATION = 0.95

    def __init__(self, stepper: "Stepper") -> None:
        super().__init__(stepper)
        if stepper.numerics.mass != "lumped":
            raise SceneError("numerics.mass", stepper.numerics.mass,
                             f'"lumped" with numerics.scheme = "{self.name}" (or scheme = "euler" for the consistent mass)')
        flow, dt = stepper.flow, stepper.dt
        self.half = None if flow.is_still else stepper.domain.advection(flow, 0.5 * dt, stepper.numerics)
        split = stepper.numerics.repulsion_split and not flow.is_still
        #: the terms of the IMEX step, and the decay terms split off around it (flow only)
        self.reacting, self.decaying = stepper.energy.split_decay() if split else (stepper.energy, ())
        self._half_bound = 0.5 * self.reacting.curvature_bound(stepper.smallest_radius, stepper.pairs)
        self.implicit_rank_one = stepper.numerics.area_implicit and any(t.rank_one for t in self.reacting.terms)
        #: whether every term of the midpoint step is window-local (with the repulsion split
        #: off, the paper's are), so that the step may run part by part (:meth:`relax`)
        self.window_local = all(term.window_local for term in self.reacting.terms)

    def predictor_stabilisation(self, dt: float) -> float:
        """S of the predictor, one linearly implicit Euler step of dt/2: the smallest that
        keeps it energy-stable (module docstring) for the terms it treats explicitly."""
        return max(0.0, self._half_bound - 1.0 / (self.stepper.mobility * 0.5 * dt))

    def decay(self, phi: np.ndarray, layout: Layout, radii: np.ndarray, dt: float) -> np.ndarray:
        """φ after ``dt`` of the decay terms alone, ∂tφ_i = −J0 c(φ) φ_i with c the sum of their
        :meth:`~femphase.energy.EnergyTerm.decay_rate`, by the exponential midpoint rule:
        φ_i e^{−J0 c(φ̃) dt}, the midpoint φ̃ = φ/(1 + J0 c(φ) dt/2) from an implicit Euler
        half step (first order there is enough for second order). Second order; |φ_i| never
        grows, whatever dt; ``dt = 0`` returns φ itself. One call costs two evaluations of c
        (Σ_{j≠i} φ_j², 0.2 ms each on the N = 100 lattice's 10⁵ positions) and one
        exponential (0.08 ms): 0.45 ms in all in the stepper (0.8 before its arithmetic was
        made in place, session 10)."""
        j0 = self.stepper.mobility
        if dt == 0.0:
            return phi

        def rate(values: np.ndarray) -> np.ndarray:
            fields = WindowedFields(values, layout, radii)
            total = self.decaying[0].decay_rate(fields)
            for term in self.decaying[1:]:
                total = total + term.decay_rate(fields)
            return total

        # in place: each temporary of the plain expressions is a pass over 10⁵ positions
        denominator = rate(phi)
        denominator *= 0.5 * dt * j0
        denominator += 1.0
        factor = rate(np.divide(phi, denominator, out=denominator))
        factor *= -dt * j0
        np.exp(factor, out=factor)
        factor *= phi
        return factor

    def rank_one_predictor(self, explicit: np.ndarray, fields: WindowedFields, dt: float,
                           stabilisation: float) -> np.ndarray:
        """The predictor with the energy's rank-one parts β_i φ_i (M_L φ_i)ᵀ (the area term's,
        :meth:`~femphase.energy.EnergyTerm.rank_one_coefficient`) linearly implicit, from
        ``explicit``, the predictor φ̂ that treats them explicitly: with A = M_L/dt + J0 S M_L
        + J0 D K, the linearly implicit Euler step of dt that adds J0 M_L β_i φ_i s_i,
        s_i = (M_L φ_i)ᵀ(φ̄_i − φ_i), to the left-hand side is, by Sherman–Morrison,

            φ̄_i = φ̂_i − J0 β_i s_i w_i,   w_i = A⁻¹ M_L φ_i,   s_i = ŝ_i / (1 + J0 β_i (M_L φ_i)ᵀ w_i),

        ŝ_i = (M_L φ_i)ᵀ(φ̂_i − φ_i): one more solve. The midpoint step after it then moves
        the area's deviation by (1 − z/2)/(1 + z/2), z = J0·8μ a/(πR²)·dt, as the implicit
        midpoint rule (explicit: 1 − z + z²/2, which reaches 1 at dt = 5), and the embedded
        estimate no longer contains that mode."""
        phi, layout, j0 = fields.phi, fields.layout, self.stepper.mobility
        coefficient = j0 * self.reacting.rank_one_coefficient(fields)
        w = self.stepper.solve(phi, np.zeros_like(phi), layout, 1.0 / dt, stabilisation)
        weighted = layout.mass * phi
        change = layout.reduce(np.add, weighted * (explicit - phi))
        response = layout.reduce(np.add, weighted * w)
        shift = coefficient * change / (1.0 + coefficient * response)
        return explicit - fields.on_positions(shift) * w

    def advance(self, phi: np.ndarray, layout: Layout, state: "State") -> tuple[np.ndarray, Layout]:
        dt = self.stepper.dt
        if self.half is not None:
            phi, layout = self.half.advect(phi, layout, state.time)
        r = self.auxiliary(phi, layout, state)
        before = self.free_energy(phi, layout, state.radii) if self.checks_energy else None
        phi_new, r, _ = self.relax(phi, layout, state.time, state.radii, r, dt)
        if before is not None and self.rises(before, self.free_energy(phi_new, layout, state.radii)):
            phi_new = self.fallback(phi, layout, state.time, state.radii, dt)
            r = self.restart(WindowedFields(phi_new, layout, state.radii))
            state.memory["sav_fallbacks"] = state.memory.get("sav_fallbacks", np.zeros(1, dtype=np.int64)) + 1
        self.keep(state, r)
        if self.half is not None:
            phi_new, layout = self.half.advect(phi_new, layout, state.time + 0.5 * dt)
        return phi_new, layout

    @staticmethod
    def keep(state: "State", r: float | None) -> None:
        """Carry r to the next step; none with flow, so that a later still phase restarts it."""
        if r is None:
            state.memory.pop("sav_r", None)
        else:
            state.memory["sav_r"] = np.array([r])

    def auxiliary(self, phi: np.ndarray, layout: Layout, state: "State") -> float | None:
        """r at the start of a step: None with flow (the plain IMEX midpoint step, see
        :meth:`relax`), else the carried r, or √(E1 + C) when there is none yet."""
        if not self.stepper.flow.is_still:
            return None
        r = state.memory.get("sav_r")
        return self.restart(WindowedFields(phi, layout, state.radii)) if r is None else float(r[0])

    @property
    def checks_energy(self) -> bool:
        """Whether steps must not raise F: without flow and without a source term."""
        return self.stepper.flow.is_still and self.stepper.source is None

    #: Relative change of F below which a rise is rounding, not a rise: near equilibrium F
    #: changes by ~1e-16 relative per step either way, and treating that as a rise would
    #: refine the adaptive substeps to the finest size for nothing.
    ROUNDING = 1e-12

    def rises(self, before: float, after: float) -> bool:
        """Whether F rose from ``before`` to ``after`` by more than rounding."""
        return after - before > self.ROUNDING * max(abs(before), 1.0)

    def free_energy(self, phi: np.ndarray, layout: Layout, radii: np.ndarray) -> float:
        """The discrete free energy F (energy units), window by window."""
        fields = WindowedFields(phi, layout, radii, self.stepper.domain.stiffness_apply(layout))
        return self.stepper.energy.parts(fields).total

    def restart(self, fields: WindowedFields) -> float:
        """r = √(E1(φ) + C): the auxiliary variable equal to the energy it stands for."""
        return float(np.sqrt(self.stepper.energy.explicit_energy(fields) + self.OFFSET))

    def fallback(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray, dt: float) -> np.ndarray:
        """The linearly implicit Euler step of ``dt`` with the "auto" stabilisation, which
        lowers F at any dt (module docstring): taken instead of a relaxation step that would
        raise F (first order on that step; counted in ``state.memory["sav_fallbacks"]``)."""
        stepper = self.stepper
        stabilisation = auto_stabilisation(stepper.energy, stepper.mobility, "lumped", dt, stepper.smallest_radius,
                                           stepper.pairs)
        return linearly_implicit_step(stepper, phi, layout, radii, dt, stabilisation, time + dt)

    def relax(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray,
              r: float | None, dt: float, decay_before: float | None = None,
              decay_after: float | None = None) -> tuple[np.ndarray, float | None, float]:
        """One relaxation step of ``dt`` from ``time``: (φ¹, the new auxiliary variable r, an
        estimate of the step's local error). With the repulsion split off, the decay runs
        for ``decay_before`` before the midpoint step and ``decay_after`` after it (time
        units; default dt/2 each, Strang).

        Both variants evaluate the explicit part g = δE1/δφ at a predicted midpoint φ̄ (one
        linearly implicit Euler step of dt/2 from φ⁰; with ``numerics.area_implicit`` the
        area term's rank-one mode implicit in it, :meth:`rank_one_predictor`) and treat the
        gradient term by Crank–Nicolson, with L = D M_L⁻¹K:

        * with r (no flow): relaxed SAV-CN (RSAV-CN). With V(φ) = √(E1(φ) + C) and
          b = g(φ̄)/V(φ̄),

              (φ¹ − φ⁰)/dt = −J0 [L (φ¹ + φ⁰)/2 + r^{1/2} b] + s(t + dt/2),
              r¹ − r⁰ = (b, φ¹ − φ⁰)_M / 2,                 r^{1/2} = (r¹ + r⁰)/2,

          whose modified energy D/2 φᵀKφ + r² falls by |φ¹ − φ⁰|²_M/(J0 dt) without source.
          φ¹ = p − r^{1/2} q from two solves with (2M/dt + J0 D K), and r^{1/2} from one
          scalar equation. Then r is relaxed towards V(φ¹): r ← ξ r¹ + (1 − ξ) V(φ¹), ξ ∈
          [0, 1] the smallest that keeps r² − r¹² ≤ η |φ¹ − φ⁰|²_M/(J0 dt), so r stays
          √(E1 + C) wherever the dissipation allows (then the modified energy is F + C).
        * r None (with flow): the plain IMEX midpoint step, r^{1/2} b replaced by g(φ̄), one
          solve. With flow F is not a Lyapunov function and r would restart from E1 after
          every advection, so the SAV factor r^{1/2}/V(φ̄) = 1 + O(dt) would only add error
          and cost (one solve and three energy evaluations per step, ~27 % of the step).
          With ``numerics.repulsion_split`` (the default) the decay terms (the repulsion,
          whose δF/δφ_i = (4κ/λ) Σ_{j≠i} φ_j² φ_i decays a field's tail inside its neighbours
          at J0·4κ/λ·Σφ_j² ≈ 0.6 per time unit, 5× the double well's rate) are split off:
          :meth:`decay` over dt/2, the midpoint step of the other terms over dt, :meth:`decay`
          over dt/2 (Strang, second order). Explicit, that decay set the substep: at dt = 2.5
          the lattice's r(t) error in time falls from 2.8 % to 0.64 % (benchmarks/README.md,
          "Kept in session 8").

        The error estimate is max |φ¹ − (2φ̄ − φ⁰)|: the predictor doubled is a first-order
        step, so this is that step's local error, O(dt²), at no extra cost (an embedded pair
        of orders 1 and 2; the second-order result is kept). With the split it is the
        midpoint step's: the decay is integrated in exponential form, and its splitting error
        is not estimated."""
        if self.decaying:
            phi = self.decay(phi, layout, radii, 0.5 * dt if decay_before is None else decay_before)
        if r is not None:
            new, r_next, estimate = self._sav_step(phi, layout, time, radii, r, dt)
        elif self.window_local and phi.size > self.WHOLE_POSITIONS:  # part by part, in cache
            new, estimate = np.empty_like(phi), 0.0
            for begin, end, part in layout.parts(self.PART_POSITIONS):
                new[begin:end], part_estimate = self._midpoint_step(phi[begin:end], part, time, radii, dt)
                estimate = max(estimate, part_estimate)
            r_next = None
        else:
            (new, estimate), r_next = self._midpoint_step(phi, layout, time, radii, dt), None
        if self.decaying:
            new = self.decay(new, layout, radii, 0.5 * dt if decay_after is None else decay_after)
        return new, r_next, estimate

    #: Positions of the parts the midpoint step works on at a time when its terms are window-
    #: local (:attr:`window_local`): 2¹⁵ positions, 256 kB per array, so that the step's dozen
    #: arrays stay in the core's 1 MiB L2 cache. Measured on this machine (session 11): a
    #: chain of pointwise operations costs 3.1 ns a position on arrays of 10⁵ positions (the
    #: N = 100 lattice), 7.0 on 1.6·10⁶ (N = 1600), 3.8 in parts of 16k.
    PART_POSITIONS = 2**15
    #: Up to this many positions (the N = 100 lattice has 10⁵) the step's arrays fit the
    #: cache whole and parts would only add Python calls (same-run ratios 0.99–1.05 there)
    WHOLE_POSITIONS = 2**17

    def _predictor(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray,
                   dt: float) -> tuple[np.ndarray, WindowedFields]:
        """φ̄, the predicted midpoint (one linearly implicit Euler step of dt/2, :meth:`relax`),
        and φ̄ as WindowedFields."""
        fields = WindowedFields(phi, layout, radii)
        stabilisation = self.predictor_stabilisation(dt)
        midpoint = linearly_implicit_step(self.stepper, phi, layout, radii, 0.5 * dt, stabilisation,
                                          time + 0.5 * dt, fields, self.reacting)
        if self.implicit_rank_one:
            midpoint = self.rank_one_predictor(midpoint, fields, 0.5 * dt, stabilisation)
        return midpoint, WindowedFields(midpoint, layout, radii)

    # (2M/dt + J0 D K) p = (2M/dt − J0 D K) φ⁰ + 2 M s (− 2 J0 M g(φ̄) for the midpoint step) is
    # solved below as (2M/dt + J0 D K)(p + φ⁰) = 4M/dt φ⁰ + 2 M s (…): the same p without the
    # product K φ⁰ (7 % of the substep), rounding aside

    def _midpoint_step(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray,
                       dt: float) -> tuple[np.ndarray, float]:
        """The plain IMEX midpoint step of :meth:`relax` (with flow): (φ¹, its estimate)."""
        stepper = self.stepper
        midpoint, middle = self._predictor(phi, layout, time, radii, dt)
        nodal = self.reacting.explicit_derivative(middle)  # this call's own array: scaled in place
        nodal *= -2.0 * stepper.mobility
        source = stepper.source_term(layout, time + 0.5 * dt)
        if source is not None:
            nodal += 2.0 * source
        new = stepper.solve(nodal, 2.0 * phi, layout, 2.0 / dt, 0.0)
        new -= phi
        return new, self._estimate(new, midpoint, phi)

    def _sav_step(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray, r: float,
                  dt: float) -> tuple[np.ndarray, float, float]:
        """The RSAV-CN step of :meth:`relax` (without flow): (φ¹, r¹, its estimate)."""
        stepper, j0, energy, mass = self.stepper, self.stepper.mobility, self.reacting, layout.mass
        midpoint, middle = self._predictor(phi, layout, time, radii, dt)
        source = stepper.source_term(layout, time + 0.5 * dt)
        b = energy.explicit_derivative(middle) / np.sqrt(energy.explicit_energy(middle) + self.OFFSET)
        nodal = np.zeros_like(phi) if source is None else 2.0 * source
        p = stepper.solve(nodal, 2.0 * phi, layout, 2.0 / dt, 0.0)
        p -= phi
        q = stepper.solve(2.0 * j0 * b, np.zeros_like(phi), layout, 2.0 / dt, 0.0)
        weighted_b = mass * b
        r_half = (r + 0.25 * float(weighted_b @ (p - phi))) / (1.0 + 0.25 * float(weighted_b @ q))
        new = p - r_half * q
        change = new - phi
        dissipation = float(mass @ (change * change)) / (j0 * dt)
        r_next = relaxed(2.0 * r_half - r, self.restart(WindowedFields(new, layout, radii)),
                         self.RELAXATION * dissipation)
        return new, r_next, self._estimate(new, midpoint, phi)

    @staticmethod
    def _estimate(new: np.ndarray, midpoint: np.ndarray, phi: np.ndarray) -> float:
        """max |φ¹ − (2φ̄ − φ⁰)|: the embedded first-order step's difference (:meth:`relax`)."""
        deviation = midpoint * -2.0  # in place
        deviation += new
        deviation += phi
        return float(np.abs(deviation, out=deviation).max()) if new.size else 0.0


def relaxed(r: float, target: float, allowance: float) -> float:
    """ξ r + (1 − ξ) target with the smallest ξ ∈ [0, 1] such that the result's square exceeds
    r² by at most ``allowance`` (≥ 0)."""
    if target * target - r * r <= allowance:
        return target
    # (target + ξ (r − target))² − r² = allowance: the root in [0, 1]
    a, b, c = (r - target) ** 2, 2.0 * target * (r - target), target * target - r * r - allowance
    if a == 0.0:
        return r
    root = (-b - np.sqrt(max(b * b - 4.0 * a * c, 0.0))) / (2.0 * a)
    roots = [x for x in (root, (-b + np.sqrt(max(b * b - 4.0 * a * c, 0.0))) / (2.0 * a)) if 0.0 <= x <= 1.0]
    xi = min(roots) if roots else 1.0
    return xi * r + (1.0 - xi) * target


@SCHEMES.register("adaptive")
class AdaptiveSAV2(RelaxedSAV2):
    """Error-controlled substeps of sav2 inside every step of the phase (frames stay at exact
    times): embedded first/second-order error estimate, PI step controller, rejected substeps
    redone; `numerics.tolerance_t` is the local error allowed per substep (max-norm of φ).

    Under flow, consecutive substeps share their half-steps of the split operators: the
    second half-advection of one substep and the first of the next are one advection
    (:meth:`_advection`), and so are the two half-decays of the repulsion (one decay after
    that advection: a pointwise decay and a transport of all fields alike commute). A
    substep then costs one advection and one decay instead of two of each (the decay's
    merge, with its arithmetic in place: 0.87× the CPU per time unit on the lattice, a
    same-run ratio, session 10).

    Substep sizes: dt/m with m = 2^k or 3·2^k (10, 5, 3.33, 2.5, 1.67, 1.25, … at dt = 10),
    each substep starting at a multiple of its own size, so that substeps tile the step
    exactly and the finite set of sizes keeps solvers and advections reusable. The steps of
    4/3 and 3/2 between neighbouring sizes let the controller settle where the tolerance
    puts it instead of on a power of two below it: on the lattice at the default tolerance
    that is 3.33 instead of 2.5 (benchmarks/README.md, "Session 10").

    Without flow (and source), a substep that would raise the free energy F is rejected as
    well; at the finest size, dt/(3·2^LEVELS), the energy-stable Euler step (:meth:`fallback`)
    replaces it, so F never rises, whatever dt. A substep of the finest size is otherwise
    accepted whatever its estimate (the step cannot shrink further; a smaller phase dt is
    then the remedy).

    Several steps in one call (``steps`` > 1, :meth:`Stepper.step`) are one run of substeps:
    the half-advection and half-decay that end one step and those that start the next are
    merged like any two substeps', and the window refit between them is the substeps' own.
    Only the end of the call is synchronised (φ at that time, all half-steps done); each
    step's end inside it is checked for blow-up and renews the rank-one bound. Results then
    depend on where the calls end at the level of the splitting error (the simulation ends
    them at frames, T1 looks, phase ends and every ``numerics.merged_steps`` steps, all
    fixed by the clock, so a resumed run takes the same calls); the call's
    saving is measured in benchmarks/README.md ("Session 12")."""

    name = "adaptive"
    order = 2
    merges_steps = True
    #: Substeps are dt/m, m in DIVISIONS (2^k and 3·2^k, k ≤ LEVELS, ascending).
    LEVELS = 12
    DIVISIONS = tuple(sorted({2**k for k in range(LEVELS + 1)} | {3 * 2**k for k in range(LEVELS + 1)}))
    #: The step in units of the finest substep: every size is a whole number of units.
    UNITS = DIVISIONS[-1]
    #: m of a phase's first substep (dt/4)
    FIRST = 4
    #: Advections kept (least recently used dropped first): one per pair of neighbouring
    #: sizes in use; on a mesh each holds a complex LU (tens of MB on the obstacle example)
    ADVECTIONS_KEPT = 8
    #: The PI controller (Gustafsson; the defaults of SUNDIALS ARKODE's PI): exponents of
    #: the error ratios for an estimate of local order 2, a safety factor, growth bounds.
    K_I, K_P, SAFETY, GROWTH, SHRINK = 0.8 / 2, 0.31 / 2, 0.9, 4.0, 0.2
    #: z = c·h, c the fastest explicit rank-one mode's rate (each particle's area relaxing
    #: back), up to which substeps may grow: the explicit midpoint step moves that mode by
    #: 1 − z + z²/2, 0.625 at z = 1.5, 1 (undamped) at 2, while the embedded estimate scales
    #: with the mode's small amplitude and does not stop it (measured: at tolerance 0.1 the
    #: slab with μ × 10 sheared at γ̇ = 1 drifted in area by 3.9 % without this bound).
    RANK_ONE_STEP = 1.5

    def __init__(self, stepper: "Stepper") -> None:
        super().__init__(stepper)
        self.tolerance = stepper.numerics.tolerance_t
        self._advections: OrderedDict[tuple[int, ...], object] = OrderedDict()

    def start_phase(self, state: "State") -> None:
        """A new phase (the flow switched on, off or changed) starts the controller afresh,
        at the substep dt/4 and without the error history: the PI step's proportional
        factor (previous error / tolerance)^K_P carried over from a quiet relaxation (the
        random packing's last estimate: 4 % of the tolerance, a factor ≈ 0.6) refined the
        first substeps of a shear and, with PI's sticky sizes, the whole phase (at γ̇ = 1:
        1.25 instead of 2.5). The counts stay."""
        state.memory.pop("adaptive_divisions", None)
        state.memory.pop("adaptive_error", None)

    def _advection(self, divisions: tuple[int, ...]):
        """The advection over the sum of the half substeps dt/(2m), m in ``divisions`` (None
        without flow): the second half of one substep and the first half of the next are
        one advection (exact for steady row flows; midpoint-rule time for unsteady ones,
        still second order), which halves the advection work."""
        if self.stepper.flow.is_still:
            return None
        advections = self._advections
        if divisions in advections:
            advections.move_to_end(divisions)
        else:
            stepper = self.stepper
            duration = sum(0.5 * stepper.dt / m for m in divisions)
            advections[divisions] = stepper.domain.advection(stepper.flow, duration, stepper.numerics)
            if len(advections) > self.ADVECTIONS_KEPT:
                advections.popitem(last=False)
        return advections[divisions]

    def largest_substep(self, phi: np.ndarray, layout: Layout, radii: np.ndarray) -> float:
        """The largest substep (time units) that damps the explicit rank-one modes,
        RANK_ONE_STEP / max_i c_i with c_i = J0 β_i (M_L φ_i)ᵀφ_i (≈ 0.4 per time unit at
        the paper's values: 3.75); unbounded without such modes or with them implicit
        (``numerics.area_implicit``)."""
        if self.implicit_rank_one:
            return np.inf
        fields = WindowedFields(phi, layout, radii)
        beta = self.reacting.rank_one_coefficient(fields)
        if beta is None or beta.size == 0:
            return np.inf
        rate = self.stepper.mobility * beta * fields.areas
        return self.RANK_ONE_STEP / max(float(rate.max()), 1e-300)

    @classmethod
    def divisions_for(cls, size: float, done: int) -> int:
        """m of the largest substep dt/m no larger than ``size`` (in units of dt) that can
        start after ``done`` units (it starts at a multiple of its own length)."""
        for m in cls.DIVISIONS:
            if 1.0 / m <= size * (1.0 + 1e-12) and done % (cls.UNITS // m) == 0:
                return m
        return cls.UNITS

    def advance(self, phi: np.ndarray, layout: Layout, state: "State", steps: int = 1) -> tuple[np.ndarray, Layout]:
        stepper, dt = self.stepper, self.stepper.dt
        memory = state.memory
        if "adaptive_level" in memory:  # a checkpoint from before session 10: substep dt/2^level
            memory["adaptive_divisions"] = 2 ** memory.pop("adaptive_level")
        total = steps * self.UNITS
        # the rank-one modes' bound, once per step (the areas change slowly), in units of dt
        largest = self.largest_substep(phi, layout, state.radii) / dt
        carried = int(memory.get("adaptive_divisions", np.array([self.FIRST]))[0])
        m = self.divisions_for(min(1.0 / carried, largest), 0)
        previous_error = float(memory.get("adaptive_error", np.array([self.tolerance]))[0])
        r = self.auxiliary(phi, layout, state)
        done = 0  # units (dt/UNITS) done in this step
        accepted = rejected = 0
        before = self.free_energy(phi, layout, state.radii) if self.checks_energy else None
        owed: tuple[int, ...] = ()  # m of the accepted substep whose second half-advection is still due
        while done < total:
            if done and done % self.UNITS == 0:  # a step boundary inside a merged call
                check_fields(phi, stepper.numerics.blowup_margin, state.step + done // self.UNITS,
                             state.time + dt * done / self.UNITS)
                largest = self.largest_substep(phi, layout, state.radii) / dt
            h = dt / m
            time = state.time + dt * done / self.UNITS
            advection = self._advection(owed + (m,))
            trial, trial_layout = phi.copy(), layout
            lag = 0.5 * dt / owed[0] if owed else 0.0
            if advection is not None:
                trial, trial_layout = advection.advect(trial, trial_layout, time - lag)
            # the previous substep's second half-decay and this one's first are one decay, after
            # the advection: pointwise decay and transport commute (both act on all fields alike)
            new, new_r, error = self.relax(trial, trial_layout, time, state.radii, r, h,
                                           decay_before=lag + 0.5 * h, decay_after=0.0)
            if not np.isfinite(error):  # NaN > tolerance is False: it would pass as accepted
                raise BlowUpError(state.step + done // self.UNITS + 1, time + h,
                                  f"φ is not finite (NaN or inf) after a substep of {h:g} from t = {time:g}")
            error = max(error, 1e-14)
            if error > self.tolerance and m < self.UNITS:
                rejected += 1
                factor = max(self.SHRINK, self.SAFETY * (self.tolerance / error) ** 0.5)
                m = self.divisions_for(min(min(factor, 0.75) / m, largest), done)
                continue
            if before is not None:
                after = self.free_energy(new, layout, state.radii)
                if self.rises(before, after) and m < self.UNITS:  # F must not rise: a smaller substep
                    rejected += 1
                    m = self.divisions_for(min(0.75 / m, largest), done)
                    continue
                if self.rises(before, after):
                    new = self.fallback(phi, layout, time, state.radii, h)
                    new_r = self.restart(WindowedFields(new, layout, state.radii))
                    after = self.free_energy(new, layout, state.radii)
                before = after
            phi, layout, r = new, trial_layout, new_r
            owed = (m,)
            done += self.UNITS // m
            accepted += 1
            factor = self.SAFETY * (self.tolerance / error) ** self.K_I * (previous_error / self.tolerance) ** self.K_P
            factor = min(self.GROWTH, max(self.SHRINK, factor))
            previous_error = error
            m = self.divisions_for(min(factor / m, largest), done)
            layout, phi = stepper.refit(layout, phi)
        lag = 0.5 * dt / owed[0]
        if self.decaying:
            phi = self.decay(phi, layout, state.radii, lag)
        advection = self._advection(owed)
        if advection is not None:
            phi, layout = advection.advect(phi, layout, state.time + steps * dt - lag)
        memory["adaptive_divisions"] = np.array([m])
        memory["adaptive_error"] = np.array([previous_error])
        memory["adaptive_counts"] = memory.get("adaptive_counts", np.zeros(2, dtype=np.int64)) + [accepted, rejected]
        self.keep(state, r)
        return phi, layout
