"""The default scheme ``adaptive``: error-controlled substeps of ``sav2`` inside every step of
the phase (:class:`AdaptiveSAV2`; its docstring gives the substep sizes, the estimate and
the controller). The phase's dt is the largest substep and the spacing of frames and
checkpoints; ``numerics.tolerance_t`` is the local error allowed per substep under flow; without,
a tenth of it at the default, its power 3/4 about the default in general
(:meth:`femphase.config.Numerics.substep_tolerance`).
"""

from __future__ import annotations

import warnings

import numpy as np

from femphase.domains.layout import Layout, largest_difference
from femphase.errors import BlowUpError, StiffnessWarning
from femphase.model.energy import WindowedFields
from femphase.state import State
from femphase.timestepping.base import SCHEMES, StepperProtocol, check_fields
from femphase.timestepping.sav2 import RelaxedSAV2

__all__ = ["AdaptiveSAV2", "counted_in_phase"]


@SCHEMES.register("adaptive")
class AdaptiveSAV2(RelaxedSAV2):
    """Error-controlled substeps of sav2 inside every step of the phase (frames stay at exact
    times): embedded first/second-order error estimate (or, with ``numerics.estimate =
    "doubling"`` under flow, step doubling: :meth:`_attempt`), PI step controller, rejected
    substeps redone; `numerics.tolerance_t` is the local error allowed per substep (max-norm of φ)
    under flow; without, a tenth of it at the default, its power 3/4 about the default in general
    (:meth:`femphase.config.Numerics.substep_tolerance`).

    Under flow, consecutive substeps share their half-steps of the split operators: the
    second half-advection of one substep and the first of the next are one advection
    (:meth:`_advection`). Where the local error allowed is at least MERGED_DECAY_TOLERANCE
    (at the default), so are the two half-decays of the repulsion, one decay after that
    advection: a substep then costs one advection and one decay instead of two of each
    (the decay's merge, with its arithmetic in place: 0.87× the CPU per time unit on the
    lattice, a same-run ratio). The merge moves a decay across an advection, and a pointwise
    decay commutes with the exact transport but not with its discretisation (the row
    shift's interpolation of the product): an error of first order in the substep, which at
    tighter tolerances held the sheared lattice's peak times near 0.01 time units and its
    r̄(t) at order 1.7 (docs/decisions/0046-decays-split-below-the-default.md). Below it each
    substep decays before and after its midpoint step, as sav2 does.

    Substep sizes: dt/m with m = 2^k or 3·2^k (10, 5, 3.33, 2.5, 1.67, 1.25, … at dt = 10),
    each substep starting at a multiple of its own size, so that substeps tile the step
    exactly and the finite set of sizes keeps solvers and advections reusable. The steps of
    4/3 and 3/2 between neighbouring sizes let the controller settle where the tolerance
    puts it instead of on a power of two below it: on the lattice at the default tolerance
    that is 3.33 instead of 2.5 (docs/decisions/0003-substep-sizes.md).

    Without flow (and source), a substep that would raise the free energy F is rejected as
    well; at the finest size, dt/(3·2^LEVELS), the energy-stable Euler step (:meth:`fallback`)
    replaces it, so F never rises, whatever dt. A substep of the finest size is otherwise
    accepted whatever its estimate (the step cannot shrink further; a smaller phase dt is
    then the remedy).

    Several steps in one call (``steps`` > 1,
    :meth:`femphase.timestepping.stepper.Stepper.step`) are one run of substeps: the
    half-advection and half-decay that end one step and those that start the next are
    merged like any two substeps', and the window refit between them is the substeps' own.
    Only the end of the call is synchronised (φ at that time, all half-steps done); each
    step's end inside it is checked for blow-up and renews the rank-one bound. Results then
    depend on where the calls end at the level of the splitting error (the simulation ends
    them at frames, T1 looks, phase ends and every ``numerics.merged_steps`` steps, all
    fixed by the clock, so a resumed run takes the same calls); the call's
    saving is measured in docs/decisions/0008-merged-steps.md."""

    name = "adaptive"
    order = 2
    merges_steps = True
    refits_substeps = True
    #: Substeps are dt/m, m in DIVISIONS (2^k and 3·2^k, k ≤ LEVELS, ascending).
    LEVELS = 12
    DIVISIONS = tuple(sorted({2**k for k in range(LEVELS + 1)} | {3 * 2**k for k in range(LEVELS + 1)}))
    #: The step in units of the finest substep: every size is a whole number of units.
    UNITS = DIVISIONS[-1]
    #: m of a phase's first substep (dt/4)
    FIRST = 4
    #: The PI controller (Gustafsson; the defaults of SUNDIALS ARKODE's PI): exponents of
    #: the error ratios for an estimate of order 2 in the substep, a safety factor, growth bounds.
    K_I, K_P, SAFETY, GROWTH, SHRINK = 0.8 / 2, 0.31 / 2, 0.9, 4.0, 0.2
    #: The least previous error, relative to the tolerance, that the controller's proportional
    #: term (previous/tolerance)^K_P reads (Hairer & Wanner's DOPRI5 floor, 1e-4): a substep
    #: whose estimate is 0 in the fields' precision (floored at 1e-14) would otherwise cut the
    #: next one's factor by (1e-13)^K_P = 0.01, to the shrink bound, whatever its own error.
    ERROR_FLOOR = 1e-4
    #: z = c·h, c the fastest explicit rank-one mode's rate (each particle's area relaxing
    #: back), up to which substeps may grow: the explicit midpoint step moves that mode by
    #: 1 − z + z²/2, 0.625 at z = 1.5, 1 (undamped) at 2, while the embedded estimate scales
    #: with the mode's small amplitude and does not stop it (measured: at tolerance 0.1 the
    #: slab with μ × 10 sheared at γ̇ = 1 drifted in area by 3.9 % without this bound).
    RANK_ONE_STEP = 1.5
    #: The same bound with the mode implicit in the predictor (``numerics.area_implicit``).
    #: Linearised, the step is then the implicit midpoint rule on the mode, stable at every
    #: z, and the embedded estimate is blind to it (the first-order step moves the mode as
    #: the second-order one does). The whole step is not: a lone disc (examples/single.toml,
    #: sav2 at dt = 0.25, μ = 850 … 1000, relaxation then shear at γ̇ = 1) held its area at
    #: 0.996–0.999 up to z = 4.72 and fell into a period-2 oscillation of ±30 % at z = 4.97;
    #: the adaptive scheme unbounded ran at z ≈ 5.5 with its area ±14 % from frame to frame.
    IMPLICIT_RANK_ONE_STEP = 4.0
    #: z = c·h, c the split decay's largest rate (the repulsion's, J0·4κ/λ Σ_{j≠i} φ_j²), up
    #: to which flow substeps may grow: the splitting's error is not in the embedded estimate,
    #: and it grows with z (docs/decisions/0052-split-repulsion-decay-ceiling.md:
    #: two pressed discs under shear, their repulsion energy 3 % off at z = 1.9, 3.6 % at 10,
    #: 12 % at 19, 4.8-fold at 188). At the paper's κ the bound is 20 time units: it never binds.
    DECAY_STEP = 10.0
    #: The smallest local error allowed under flow at which the half-decays of consecutive
    #: substeps are merged across their shared advection (class docstring): the default 0.1
    #: merges them, 0.03 does not
    MERGED_DECAY_TOLERANCE = 0.05

    def __init__(self, stepper: StepperProtocol) -> None:
        super().__init__(stepper)
        self.tolerance = stepper.numerics.substep_tolerance(stepper.flow.is_still)
        #: one advection per combination of half substeps in use, in the domain's budget (on a
        #: mesh they share the flow's matrices; with per-window solvers each keeps a complex
        #: LU per window there too)
        self._advections = stepper.domain.caches.cache("advections")
        #: whether a substep of the smallest size has been accepted above the tolerance
        self._floor_warned = False
        #: whether each substep is also taken as two halves, whose difference is the estimate
        #: (``numerics.estimate = "doubling"``, under flow: :meth:`_attempt`)
        self.doubles = stepper.numerics.estimate == "doubling" and not stepper.flow.is_still
        #: the advection ahead of a substep's start that one attempt at it runs, in substeps:
        #: half of it, and with doubling a quarter more (:meth:`_attempt`)
        self.reach = 0.75 if self.doubles else 0.5
        #: whether consecutive substeps' half-decays are one decay (class docstring); never with
        #: doubling, whose estimate would miss the merge's first-order error (:meth:`_attempt`)
        self.merges_decays = self.tolerance >= self.MERGED_DECAY_TOLERANCE and not self.doubles

    def start_phase(self, state: State) -> None:
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
        one advection (exact for steady row flows; the velocity's mean over it for unsteady
        ones, :func:`femphase.flows.time_mean`), which halves the advection work."""
        if self.stepper.flow.is_still:
            return None
        stepper = self.stepper
        return self._advections.setdefault(divisions, lambda: stepper.domain.advection(
            stepper.flow, sum(0.5 * stepper.dt / m for m in divisions), stepper.numerics))

    def largest_substep(self, phi: np.ndarray, layout: Layout, radii: np.ndarray) -> float:
        """The largest substep (time units) that damps the rank-one modes,
        RANK_ONE_STEP / max_i c_i with c_i = J0 β_i (M_L φ_i)ᵀφ_i (≈ 0.4 per time unit at
        the paper's values: 3.77), IMPLICIT_RANK_ONE_STEP / max_i c_i with them implicit
        (``numerics.area_implicit``: 10.05), and under flow keeps the split decay's error
        bounded, DECAY_STEP / (J0 max c) with c the decay terms' rate at every position
        (the repulsion's 4κ/λ Σ_{j≠i} φ_j², at most 0.5 per time unit at the paper's
        values: 20); unbounded without such modes and decays."""
        fields = WindowedFields(phi, layout, radii)
        largest = np.inf
        beta = self.reacting.rank_one_coefficient(fields)
        if beta is not None and beta.size:
            rate = self.stepper.mobility * beta * fields.areas
            bound = self.IMPLICIT_RANK_ONE_STEP if self.implicit_rank_one else self.RANK_ONE_STEP
            largest = bound / max(float(rate.max()), 1e-300)
        if self.decaying and phi.size:
            rate = self.stepper.mobility * float(self.decay_rate(fields).max())
            largest = min(largest, self.DECAY_STEP / max(rate, 1e-300))
        return largest

    def _split_step(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray, r: float | None,
                    m: int, owed: tuple[int, ...]) -> tuple[np.ndarray, Layout, float | None, float]:
        """sav2's substep of dt/m from ``time`` with its first half-advection (and half-decay,
        merged) joined to the half still owed by the substep of dt/owed[0] before it: (φ¹
        owing its own second half, its layout, r¹, the embedded estimate)."""
        h = self.stepper.dt / m
        advection = self._advection(owed + (m,))
        trial, trial_layout = phi.copy(), layout
        lag = 0.5 * self.stepper.dt / owed[0] if owed else 0.0
        if advection is not None:
            trial, trial_layout = advection.advect(trial, trial_layout, time - lag)
        # merged: the previous substep's second half-decay and this one's first are one
        # decay, after the advection (class docstring)
        decays = (lag + 0.5 * h, 0.0) if self.merges_decays else (0.5 * h, 0.5 * h)
        new, new_r, error = self.relax(trial, trial_layout, time, radii, r, h,
                                       decay_before=decays[0], decay_after=decays[1])
        return new, trial_layout, new_r, error

    def _attempt(self, phi: np.ndarray, layout: Layout, time: float, radii: np.ndarray, r: float | None, m: int,
                 owed: tuple[int, ...]) -> tuple[np.ndarray, Layout, float | None, float, int]:
        """One attempt at the substep dt/m from ``time``: (φ¹, its layout, r¹, the error
        estimate, m of the substep whose second half-advection φ¹ owes). Both estimates are
        of order 2 in the substep h.

        With the embedded estimate, :meth:`_split_step`. With step doubling
        (:attr:`doubles`) the substep h is taken whole and as two of h/2 from the same φ⁰;
        the whole one is brought to where the halves stand (a quarter substep more of
        advection, so that both owe the same half-advection) and the halves are kept. Their
        local error, at order 2, is a third of the two results' largest difference (h³C
        against 2(h/2)³C): every error of the split step, the advection's and the decay's
        splitting included. The estimate is that error per time unit, a third of the
        difference over h (error per unit step): kept at the tolerance, the local errors
        over a stretch T sum to at most tolerance × T whatever the substeps, so the global
        error follows the tolerance in proportion (controlled per substep, h would follow
        tolerance^(1/3) and the second-order global error tolerance^(2/3)). Each substep
        then decays on both sides of its midpoint step (:attr:`merges_decays` false): the
        merge's error is of first order in the substep, which a difference read at order 2
        does not scale. Measured from a relaxed pair of discs sheared at κ × 10, one substep
        of 0.5 and 1: the estimate 0.96 and 0.80 of the local error against sav2 at h/128,
        the embedded one 0.77 and 0.60 (benchmarks/doubling_local_error.py;
        docs/decisions/0053-step-doubling-estimate.md). A whole substep that is not finite
        where its halves are is an infinite estimate: the substep is refined, not the run
        stopped; halves that are not finite are a NaN estimate, a blow-up."""
        whole, whole_layout, whole_r, error = self._split_step(phi, layout, time, radii, r, m, owed)
        if not self.doubles:
            return whole, whole_layout, whole_r, error, m
        h = self.stepper.dt / m
        half, half_layout, half_r, _ = self._split_step(phi, layout, time, radii, r, 2 * m, owed)
        half, half_layout, half_r, _ = self._split_step(half, half_layout, time + 0.5 * h, radii, half_r, 2 * m,
                                                        (2 * m,))
        if not np.all(np.isfinite(half)):  # the kept result: a blow-up (NaN estimate)
            return half, half_layout, half_r, np.nan, 2 * m
        whole, whole_layout = self._advection((2 * m,)).advect(whole, whole_layout, time + 0.5 * h)
        difference = largest_difference(whole, whole_layout, half, half_layout)
        return half, half_layout, half_r, (difference if np.isfinite(difference) else np.inf) / (3.0 * h), 2 * m

    @classmethod
    def capped_divisions(cls, wanted: float, largest: float, done: int) -> tuple[int, bool]:
        """(m of the next substep for the controller's ``wanted`` size under the bound
        ``largest``, both in units of dt; whether that bound made it smaller than the
        controller alone would have): a substep a ceiling (:meth:`largest_substep`) set, not the error
        estimate."""
        m = cls.divisions_for(min(wanted, largest), done)
        return m, m != cls.divisions_for(wanted, done)

    @classmethod
    def divisions_for(cls, size: float, done: int) -> int:
        """m of the largest substep dt/m no larger than ``size`` (in units of dt) that can
        start after ``done`` units (it starts at a multiple of its own length)."""
        for m in cls.DIVISIONS:
            if 1.0 / m <= size * (1.0 + 1e-12) and done % (cls.UNITS // m) == 0:
                return m
        return cls.UNITS

    def advance(self, phi: np.ndarray, layout: Layout, state: State, steps: int = 1) -> tuple[np.ndarray, Layout]:
        stepper, dt = self.stepper, self.stepper.dt
        memory = state.memory
        if "adaptive_level" in memory:  # checkpoints that store the substep as dt/2^level
            memory["adaptive_divisions"] = 2 ** memory.pop("adaptive_level")
        total = steps * self.UNITS
        # the ceilings (:meth:`largest_substep`), once per step and at every step boundary
        # inside the call (areas and overlaps change slowly), in units of dt
        largest = self.largest_substep(phi, layout, state.radii) / dt
        # (m, whether the ceiling capped it) chosen at the end of the previous call; checkpoints
        # that did not record the second carry m alone
        stored = memory.get("adaptive_divisions", np.array([self.FIRST]))
        carried = int(stored[0])
        m, capped = self.capped_divisions(1.0 / carried, largest, 0)
        capped = capped or (stored.size > 1 and bool(stored[1]) and m == carried)
        previous_error = float(memory.get("adaptive_error", np.array([self.tolerance]))[0])
        if stepper.roomless:  # room for the first advection, which the call's refit left out
            layout, phi = stepper.refit(layout, phi, state.time, span=self.reach * dt / m)
        r = self.auxiliary(phi, layout, state)
        done = 0  # units (dt/UNITS) done in this step
        accepted = rejected = at_ceiling = 0  # at_ceiling: accepted substeps the ceiling set (capped_divisions)
        before = self.free_energy(phi, layout, state.radii) if self.checks_energy else None
        owed: tuple[int, ...] = ()  # m of the accepted substep whose second half-advection is still due
        while done < total:
            if done and done % self.UNITS == 0:  # a step boundary inside a merged call
                check_fields(phi, stepper.numerics.blowup_margin, state.step + done // self.UNITS,
                             state.time + dt * done / self.UNITS)
                largest = self.largest_substep(phi, layout, state.radii) / dt
                # the next substep was chosen under the previous step's ceiling
                m, recapped = self.capped_divisions(1.0 / m, largest, done)
                capped = capped or recapped
            h = dt / m
            time = state.time + dt * done / self.UNITS
            new, new_layout, new_r, error, kept = self._attempt(phi, layout, time, state.radii, r, m, owed)
            # NaN > tolerance is False: it would pass as accepted (infinite with doubling: the
            # whole substep's, its halves finite, :meth:`_attempt`)
            if np.isnan(error) or (np.isinf(error) and not self.doubles):
                raise BlowUpError(state.step + done // self.UNITS + 1, time + h,
                                  f"φ is not finite (NaN or inf) after a substep of {h:g} from t = {time:g}")
            error = max(error, 1e-14)
            if error > self.tolerance and m < self.UNITS:
                rejected += 1
                factor = max(self.SHRINK, self.SAFETY * (self.tolerance / error) ** 0.5)
                m, capped = self.capped_divisions(min(factor, 0.75) / m, largest, done)
                continue
            if before is not None:
                after = self.free_energy(new, layout, state.radii)
                if self.rises(before, after) and m < self.UNITS:  # F must not rise: a smaller substep
                    rejected += 1
                    m, capped = self.capped_divisions(0.75 / m, largest, done)
                    continue
                if self.rises(before, after):
                    new = self.fallback(phi, layout, time, state.radii, h)
                    new_r = self.restart(WindowedFields(new, layout, state.radii))
                    after = self.free_energy(new, layout, state.radii)
                before = after
            if error > self.tolerance and not self._floor_warned:  # at the smallest size: taken anyway
                self._floor_warned = True
                warnings.warn(
                    f"numerics.tolerance_t not met: at t = {time:g} a substep of the smallest size dt/{self.UNITS} = "
                    f"{h:.3g} had an error estimate {error:.3g} of the allowed {self.tolerance:.3g}, and was taken; "
                    "a larger tolerance_t, or a smaller phase dt (the smallest substep is dt/"
                    f"{self.UNITS}), brings the substeps back under control (warned once per phase)",
                    StiffnessWarning, stacklevel=2)
            phi, layout, r = new, new_layout, new_r
            owed = (kept,)
            done += self.UNITS // m
            accepted += 1
            at_ceiling += capped
            # the previous error at the floor, also where a checkpoint from before it holds 1e-14
            previous = max(previous_error, self.ERROR_FLOOR * self.tolerance)
            factor = self.SAFETY * (self.tolerance / error) ** self.K_I * (previous / self.tolerance) ** self.K_P
            factor = min(self.GROWTH, max(self.SHRINK, factor))
            # an infinite estimate taken at the smallest size (doubling: its whole substep not
            # finite) would grow the next substep fourfold through the proportional term
            previous_error = error if np.isfinite(error) else self.tolerance
            m, capped = self.capped_divisions(factor / m, largest, done)
            # room for the next attempt's advection: this substep's second half and the next
            # one's reach
            layout, phi = stepper.refit(layout, phi, state.time + dt * done / self.UNITS,
                                        span=0.5 * dt / owed[0] + self.reach * dt / m)
        lag = 0.5 * dt / owed[0]
        if self.decaying and self.merges_decays:
            phi = self.decay(phi, layout, state.radii, lag)
        advection = self._advection(owed)
        if advection is not None:
            phi, layout = advection.advect(phi, layout, state.time + steps * dt - lag)
        memory["adaptive_divisions"] = np.array([m, int(capped)])
        memory["adaptive_error"] = np.array([previous_error])
        memory["adaptive_counts"] = memory.get("adaptive_counts", np.zeros(2, dtype=np.int64)) + [accepted, rejected]
        memory["adaptive_phase_counts"] = counted_in_phase(memory.get("adaptive_phase_counts"), state.phase,
                                                           accepted, rejected, at_ceiling)
        self.keep(state, r)
        return phi, layout


def counted_in_phase(counts: np.ndarray | None, phase: int, accepted: int, rejected: int,
                     capped: int) -> np.ndarray:
    """``State.memory["adaptive_phase_counts"]`` with ``accepted``, ``rejected`` and
    ``capped`` substeps added to phase ``phase``: (phases so far, 3) int64, row k the
    accepted substeps of phase k, the rejected ones, and the accepted ones whose size the
    ceilings of :meth:`AdaptiveSAV2.largest_substep` set rather than the error estimate
    (:meth:`AdaptiveSAV2.capped_divisions`).
    The run directory's run.json reports them; ``adaptive_counts`` is the first two summed
    over phases, counted since the run began."""
    rows = max(phase + 1, 0 if counts is None else counts.shape[0])
    out = np.zeros((rows, 3), dtype=np.int64)
    if counts is not None:  # (phases, 2) from checkpoints that did not count capped substeps
        out[:counts.shape[0], :counts.shape[1]] = counts
    out[phase] += (accepted, rejected, capped)
    return out
