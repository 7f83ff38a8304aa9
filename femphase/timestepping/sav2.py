"""The second-order scheme ``sav2`` at fixed dt (:class:`RelaxedSAV2`).

Strang splitting of the advection around a relaxation that is Crank–Nicolson in the gradient
term and explicit midpoint in the rest, the midpoint from a linearly implicit Euler
predictor of dt/2 (:mod:`femphase.timestepping.euler`). Without flow the relaxation is in
relaxed scalar-auxiliary-variable form (Jiang, Zhang & Yang's RSAV: E1 = F − (D/2)φᵀKφ
enters through r = √(E1 + 1), r relaxed back to √(E1 + 1) as far as the step's dissipation
allows and carried in ``State.memory``); a step that would raise F falls back to the
energy-stable Euler step; its corrector takes a second pass with the forces at the first's
midpoint. With flow it is the plain IMEX midpoint with the repulsion split
off and integrated as the pointwise decay it is, in exponential form. Observed order in dt:
1.94 (``verification/mms.py``).
"""

from __future__ import annotations

import numpy as np

from femphase.domains.layout import Layout
from femphase.model.energy import WindowedFields
from femphase.state import State
from femphase.timestepping.base import SCHEMES, StepperProtocol, TimeScheme, auto_stabilisation
from femphase.timestepping.euler import linearly_implicit_step

__all__ = ["RelaxedSAV2", "relaxed"]


@SCHEMES.register("sav2")
class RelaxedSAV2(TimeScheme):
    """Second order: Strang splitting (advection over dt/2, relaxation over dt, advection
    over dt/2) with a relaxation step that is Crank–Nicolson in the gradient term and
    explicit midpoint in the rest (from a linearly implicit Euler predictor): relaxed
    scalar-auxiliary-variable (SAV) form without flow, plain IMEX midpoint with flow, the
    repulsion then split off and integrated in exponential form (:meth:`RelaxedSAV2.relax`). No
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
    masses = ("lumped",)
    #: C in r = √(E1 + C): any C > 0 keeps the root real (E1 ≥ 0 for the paper's terms).
    OFFSET = 1.0
    #: η: the share of each step's dissipation the relaxation of r may give back (Jiang,
    #: Zhang & Yang 2022); 0.95 keeps 5 % of it as a strict decrease.
    RELAXATION = 0.95
    #: Passes of the RSAV-CN step without flow (:meth:`relax`): the second takes the
    #: explicit forces at the first's midpoint (φ⁰ + φ¹)/2 instead of the predicted φ̄,
    #: whose error (and, above dt ≈ 1.8, the predictor's stabilisation) drifts slow
    #: relaxations. At the adaptive default: the separation of two discs after 20000 time
    #: units 1.45e-3 from the time-converged value instead of 1.26e-2; a relaxed random
    #: packing 0.013 in φ instead of 0.10; at about 1.5× the CPU of a phase without flow
    #: (0.72× that of one pass at the tolerance that gives the same 0.013).
    #: Under flow the midpoint step keeps one pass: a second doubled the sheared lattice's
    #: error in time, where the predictor's error partly cancels the splitting's
    #: (docs/decisions/0030-second-corrector-pass.md).
    STILL_PASSES = 2

    def __init__(self, stepper: StepperProtocol) -> None:
        super().__init__(stepper)
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
        #: (φ, layout, E1) of the last :meth:`restart`, for the :meth:`free_energy` after it
        self._restarted: tuple[np.ndarray, Layout, float] | None = None

    def predictor_stabilisation(self, dt: float) -> float:
        """S of the predictor, one linearly implicit Euler step of dt/2: the smallest that
        keeps it energy-stable (module docstring) for the terms it treats explicitly."""
        return max(0.0, self._half_bound - 1.0 / (self.stepper.mobility * 0.5 * dt))

    def decay(self, phi: np.ndarray, layout: Layout, radii: np.ndarray, dt: float) -> np.ndarray:
        """φ after ``dt`` of the decay terms alone, ∂tφ_i = −J0 c(φ) φ_i with c the sum of their
        :meth:`~femphase.model.energy.EnergyTerm.decay_rate`, by the exponential midpoint rule:
        φ_i e^{−J0 c(φ̃) dt}, the midpoint φ̃ = φ/(1 + J0 c(φ) dt/2) from an implicit Euler
        half step (first order there is enough for second order). Second order; ``|φ_i|`` never
        grows, whatever dt; ``dt = 0`` returns φ itself. One call costs two evaluations of c
        (Σ_{j≠i} φ_j², 0.2 ms each on the N = 100 lattice's 10⁵ positions) and one
        exponential (0.08 ms): 0.45 ms in all in the stepper, its arithmetic in place."""
        j0 = self.stepper.mobility
        if dt == 0.0:
            return phi

        def rate(values: np.ndarray) -> np.ndarray:
            return self.decay_rate(WindowedFields(values, layout, radii))

        # in place: each temporary of the plain expressions is a pass over 10⁵ positions
        denominator = rate(phi)
        denominator *= 0.5 * dt * j0
        denominator += 1.0
        factor = rate(np.divide(phi, denominator, out=denominator))
        factor *= -dt * j0
        np.exp(factor, out=factor)
        factor *= phi
        return factor

    def decay_rate(self, fields: WindowedFields) -> np.ndarray:
        """c at every position (per time unit per mobility): the sum of the decay terms'
        :meth:`~femphase.model.energy.EnergyTerm.decay_rate`, what :meth:`decay` integrates."""
        total = self.decaying[0].decay_rate(fields)
        for term in self.decaying[1:]:
            total = total + term.decay_rate(fields)
        return total

    def rank_one_predictor(self, explicit: np.ndarray, fields: WindowedFields, dt: float,
                           stabilisation: float) -> np.ndarray:
        """The predictor with the energy's rank-one parts β_i φ_i (M_L φ_i)ᵀ (the area term's,
        :meth:`~femphase.model.energy.EnergyTerm.rank_one_coefficient`) linearly implicit, from
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

    def advance(self, phi: np.ndarray, layout: Layout, state: State) -> tuple[np.ndarray, Layout]:
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
    def keep(state: State, r: float | None) -> None:
        """Carry r to the next step; none with flow, so that a later still phase restarts it."""
        if r is None:
            state.memory.pop("sav_r", None)
        else:
            state.memory["sav_r"] = np.array([r])

    def auxiliary(self, phi: np.ndarray, layout: Layout, state: State) -> float | None:
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
        """The discrete free energy F (energy units), window by window. Right after
        :meth:`restart` at the same ``phi`` and ``layout`` (every relaxation step's check),
        F = E1 + (D/2) φᵀKφ with restart's E1, which spares the areas, the neighbours' sums
        and the double well a second time (about 4 % of a relaxation step)."""
        fields = WindowedFields(phi, layout, radii, self.stepper.domain.stiffness_apply(layout))
        restarted, self._restarted = self._restarted, None
        if restarted is not None and restarted[0] is phi and restarted[1] is layout:
            return restarted[2] + self.stepper.energy.implicit_energy(fields)
        return self.stepper.energy.parts(fields).total

    def restart(self, fields: WindowedFields) -> float:
        """r = √(E1(φ) + C): the auxiliary variable equal to the energy it stands for. E1
        stays for the next :meth:`free_energy`, once, if that asks at the same φ and layout
        (identical objects: nothing runs between the two that could change φ in place)."""
        explicit = self.stepper.energy.explicit_energy(fields)
        self._restarted = (fields.phi, fields.layout, explicit)
        return float(np.sqrt(explicit + self.OFFSET))

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
        area term's rank-one mode implicit in it, :meth:`rank_one_predictor`; a batched Krylov
        solve stops at ``numerics.predictor_krylov_tolerance()``, as φ̄ enters the step only
        through g and the estimate) and treat the gradient term by Crank–Nicolson, with
        L = D M_L⁻¹K:

        * with r (no flow): relaxed SAV-CN (RSAV-CN). With V(φ) = √(E1(φ) + C) and
          b = g(φ̄)/V(φ̄),

              (φ¹ − φ⁰)/dt = −J0 [L (φ¹ + φ⁰)/2 + r^{1/2} b] + s(t + dt/2),
              r¹ − r⁰ = (b, φ¹ − φ⁰)_M / 2,                 r^{1/2} = (r¹ + r⁰)/2,

          whose modified energy D/2 φᵀKφ + r² falls by ``|φ¹ − φ⁰|²_M/(J0 dt)`` without source.
          φ¹ = p − r^{1/2} q from two solves with (2M/dt + J0 D K), and r^{1/2} from one
          scalar equation. A second pass (:attr:`STILL_PASSES`) takes b at that φ¹'s
          midpoint (φ⁰ + φ¹)/2 instead of φ̄ and solves for q once more (p does not depend
          on b); the modified energy falls as before, whatever b. Then r is relaxed towards
          V(φ¹): r ← ξ r¹ + (1 − ξ) V(φ¹), ξ ∈ [0, 1] the smallest that keeps
          ``r² − r¹² ≤ η |φ¹ − φ⁰|²_M/(J0 dt)``, so r stays √(E1 + C) wherever the
          dissipation allows (then the modified energy is F + C).
        * r None (with flow): the plain IMEX midpoint step, r^{1/2} b replaced by g(φ̄), one
          solve. With flow F is not a Lyapunov function and r would restart from E1 after
          every advection, so the SAV factor r^{1/2}/V(φ̄) = 1 + O(dt) would only add error
          and cost (one solve and three energy evaluations per step, ~27 % of the step).
          With ``numerics.repulsion_split`` (the default) the decay terms (the repulsion,
          whose δF/δφ_i = (4κ/λ) Σ_{j≠i} φ_j² φ_i decays a field's tail inside its neighbours
          at J0·4κ/λ·Σφ_j² ≈ 0.6 per time unit, 5× the double well's rate) are split off:
          :meth:`decay` over dt/2, the midpoint step of the other terms over dt, :meth:`decay`
          over dt/2 (Strang, second order). Explicit, that decay set the substep: at dt = 2.5
          the lattice's r(t) error in time falls from 2.8 % to 0.64 %
          (docs/decisions/0006-repulsion-split.md).

        The error estimate is ``max |φ¹ − (2φ̄ − φ⁰)|``: the predictor doubled is a first-order
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
    #: arrays stay in the core's 1 MiB L2 cache. Measured on this machine: a
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
                                          time + 0.5 * dt, fields, self.reacting,
                                          self.stepper.numerics.predictor_krylov_tolerance(self.stepper.flow.is_still))
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
        guess_product = None
        if stepper.batched and not self.implicit_rank_one:
            # the predictor solved (A + J0 S M_L) φ̄ = b with A this solve's system, so A (2φ̄) =
            # 2 (b − r − J0 S M_L φ̄) from its final residual r: the CG's first product spared
            # (one of about 23 sparse products of a substep on a mesh)
            guess_product = stepper.last_product()
            stabilisation = self.predictor_stabilisation(dt)
            if stabilisation:
                guess_product -= (stepper.mobility * stabilisation) * layout.mass_like(midpoint) * midpoint
            guess_product *= 2.0
        nodal = self.reacting.explicit_derivative(middle)  # this call's own array: scaled in place
        nodal *= -2.0 * stepper.mobility
        source = stepper.source_term(layout, time + 0.5 * dt)
        if source is not None:
            nodal += 2.0 * source
        # the unknown is φ¹ + φ⁰, and the embedded first-order step 2φ̄ − φ⁰ (:meth:`_estimate`)
        # puts it at 2φ̄, within the estimate: a start that many CG iterations closer
        new = stepper.solve(nodal, 2.0 * phi, layout, 2.0 / dt, 0.0, guess=2.0 * midpoint,
                            guess_product=guess_product)
        new -= phi
        return new, self._estimate(new, midpoint, phi)

    def _sav_step(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray, r: float,
                  dt: float) -> tuple[np.ndarray, float, float]:
        """The RSAV-CN step of :meth:`relax` (without flow): (φ¹, r¹, its estimate)."""
        stepper, j0, energy, mass = self.stepper, self.stepper.mobility, self.reacting, layout.mass
        midpoint, middle = self._predictor(phi, layout, time, radii, dt)
        source = stepper.source_term(layout, time + 0.5 * dt)
        nodal = np.zeros_like(phi) if source is None else 2.0 * source
        p = stepper.solve(nodal, 2.0 * phi, layout, 2.0 / dt, 0.0)
        p -= phi
        # what the passes share: p does not depend on b, so each pass solves for q alone
        p_change, zero = p - phi, np.zeros_like(phi)
        new = None
        for _ in range(self.STILL_PASSES):
            at = middle if new is None else WindowedFields(0.5 * (phi + new), layout, radii)
            b = energy.explicit_derivative(at) / np.sqrt(energy.explicit_energy(at) + self.OFFSET)
            q = stepper.solve(2.0 * j0 * b, zero, layout, 2.0 / dt, 0.0)
            weighted_b = mass * b
            r_half = (r + 0.25 * float(weighted_b @ p_change)) / (1.0 + 0.25 * float(weighted_b @ q))
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
