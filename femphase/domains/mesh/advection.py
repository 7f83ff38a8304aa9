"""Galerkin advection on meshes, over one step of fixed dt.

Galerkin in space: consistent mass M and the skew-symmetric advection matrix C
(:func:`advection_matrix`), M φ' = −C φ. Why Galerkin and not semi-Lagrangian on meshes:
semi-Lagrangian with P1 interpolation adds a numerical diffusion ~ h² C(1 − C)/(2 dt) (C the
Courant number) as large as the model's own diffusivity at the paper's u ~ 1, h = 1; Galerkin
has none, and the resolved interface held to its tanh profile by the double well does not
oscillate at cell Péclet numbers above 2. A quadratic-exact semi-Lagrangian step
(:mod:`femphase.domains.mesh.semi_lagrangian`) is as accurate from Courant number 2 on, and
the domain takes it there in steady flows
(:meth:`femphase.domains.mesh.domain.MeshDomain.advection`). Three steps in time:

* **Taylor–Galerkin** (:class:`TaylorGalerkin`, with the batched window solves, the meshes'
  default): the third-order Taylor–Galerkin step (Donea 1984), the Taylor series of φ over
  a substep h to h³ with the second and third time derivatives taken from the equation,
  φ_tt = (v·∇)²φ, whose Galerkin form is −S (the streamline matrix
  S_ij = ∫(v·∇φ_j)(v·∇φ_i), :func:`streamline_matrix`):

      (M + (h²/6) S) Δ = −h (C + (h/2) S) φ,   φ ← φ + Δ,

  the left-hand side inverted as M is in the Runge–Kutta step below, by its lumping (M_L: S's
  rows sum to zero) with K = :data:`MASS_CORRECTIONS` Jacobi corrections; subcycled at the
  same ω h ≤ :data:`COURANT`. No system is solved, and a substep costs K + 1 sparse products
  where the Runge–Kutta step's costs s (K + 1): an advection of examples/straight_mesh.toml's
  windows under flow in 1.5 against 4.5 ms, and the flow in 0.79× the CPU
  (docs/decisions/0058-taylor-galerkin-mesh-advection.md).
  Stable up to ω h ≈ 1.3 at K = 2 (tests/test_mesh_advection.py). Its S terms damp the
  Galerkin dispersion, first order in h against the semi-discrete Galerkin solution
  but not against the exact one: a disc translated 10 units by u = 1 lies closer to the same
  disc relaxed there (root mean square 0.0070 against the Runge–Kutta step's 0.0133 and
  converged Padé's 0.0114) and barely undershoots (−0.002 against −0.06), and a translating
  disc lags by 0.10–0.15 % (Runge–Kutta 0.17 %, Padé 0.10 %). The price is a spurious
  stretch along the flow: +0.013 over 32 units at u = 1 where the Runge–Kutta step's is
  +0.005 (verification/README.md, "Advection on meshes");
* **explicit Runge–Kutta** (:class:`GalerkinRungeKutta`, ``numerics.mesh_advection =
  "runge-kutta"``): an explicit Runge–Kutta step of s = :data:`STAGES` stages and order s on
  φ' = −P C φ, P = Σ_{k≤K} (I − M_L⁻¹M)^k M_L⁻¹ the lumped mass inverse with K =
  :data:`MASS_CORRECTIONS` Jacobi corrections, subcycled so that ω h ≤ :data:`COURANT` (ω
  the spectral radius of P C). No system is solved; each stage costs K + 1 sparse products.
  P is symmetric positive definite (the polynomial Σ(1 − s)^k is positive on the spectrum
  [1/4, 1] of M_L⁻¹M for P1 triangles), so P C is skew in the P⁻¹ inner product: its
  eigenvalues are imaginary, and the step is stable on the imaginary axis up to √3 (three
  stages) or 2√2 (four). K trades accuracy against products: the lumped inverse (K = 0) is
  second order in phase, and each correction brings P closer to M⁻¹ on the smooth modes that
  carry a particle (a disc translating at u = 1 on a Delaunay mesh at h = 1 lags by 2.4 %,
  0.38 %, 0.17 %, 0.13 % at K = 0, 1, 2, 3; with M⁻¹ exactly, 0.10 %; verification/README.md,
  "Advection on meshes");
* **Galerkin–Padé** (:class:`GalerkinPade`, with ``numerics.solver`` "direct" or "amg"): the
  (2,2) Padé approximant of the exact propagator exp(−dt M⁻¹C),

      φ* = R(dt M⁻¹C) φ⁰,   R(z) = (1 − z/2 + z²/12) / (1 + z/2 + z²/12)
                                = 1 + 2 Re[−2i√3 / (1 − z/r)],   r = −3 + i√3,

  i.e. one complex solve per window, φ* = φ⁰ + 4√3 Im w with (M − (dt/r) C) w = M φ⁰, by a
  factorisation kept per window: A-stable at any dt and ∫φ²-conserving, the exact-solve
  reference. Why Padé (2,2) and not Crank–Nicolson: CN's phase error (ω dt)²/12 made a disc
  translating at u = 1 with dt = 1 lag by 1.2 % and stretch (elongation +0.024); Padé cuts
  both to 0.1 % and +0.002 (verification/README.md, meshed geometries).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from skfem import Basis, BilinearForm, ElementTriP1
from skfem.helpers import dot, grad

from femphase.caches import nbytes_of
from femphase.config import Numerics
from femphase.domains.advection import StepAdvection
from femphase.domains.base import Domain, window_block
from femphase.domains.layout import Layout
from femphase.fem.blocks import pattern_entries, unsigned
from femphase.fem.operators import nodes_to_dofs
from femphase.fem.solvers import make_solver
from femphase.flows import Flow, time_mean, velocity_at

__all__ = ["COURANT", "MASS_CORRECTIONS", "PADE_POLE", "SPECTRAL_MARGIN", "STAGES", "ExplicitGalerkin",
           "GalerkinAdvection", "GalerkinPade", "GalerkinRungeKutta", "QuadratureAdvection", "TaylorGalerkin",
           "WARM_ITERATIONS", "advection_matrix", "corrected_inverse", "skew_advection", "spectral_radius",
           "streamline_form", "streamline_matrix"]


@BilinearForm
def skew_advection(u, v, w):
    return 0.5 * (dot(w.velocity, grad(u)) * v - dot(w.velocity, grad(v)) * u)


@BilinearForm
def streamline_form(u, v, w):
    return dot(w.velocity, grad(u)) * dot(w.velocity, grad(v))


def advection_matrix(domain: Domain, flow: Flow, time: float = 0.0, span: float = 0.0) -> sp.csr_matrix:
    """The skew-symmetric advection matrix C_ij = c(φ_j, φ_i) on the periodic dofs,

        c(φ, ψ) = ½ ∫ (v·∇φ) ψ − ½ ∫ (v·∇ψ) φ,

    equal to the advective form for a divergence-free v with v·n = 0 on the walls and
    periodic sides, and exactly antisymmetric for the only weakly divergence-free P2 Stokes
    velocity, so the step conserves ∫φ² (mass-matrix norm) at any dt. The velocity enters at
    the quadrature points (the P2 Stokes field exactly, analytic flows by evaluation): at
    ``time``, or with ``span`` > 0 its mean over [time, time + span]
    (:func:`~femphase.flows.time_mean`; C is linear in v, so this is the mean of C over the
    step). An analytic flow's C comes from its velocities by :class:`QuadratureAdvection`,
    the domain's, kept with the flows' operators."""
    return _velocity_matrix(domain, flow, time, span, skew_advection, lambda assembly: assembly.matrix)


def streamline_matrix(domain: Domain, flow: Flow, time: float = 0.0, span: float = 0.0) -> sp.csr_matrix:
    """The streamline matrix S_ij = ∫ (v·∇φ_j)(v·∇φ_i) on the periodic dofs: symmetric,
    positive semidefinite, rows summing to zero; −S is the Galerkin form of (v·∇)², the
    second time derivative of an advected field (the Taylor–Galerkin step's, with v·n = 0 on
    the walls). The velocity as in :func:`advection_matrix`; with ``span`` > 0 S is the mean
    velocity's (S is quadratic in v: the step's flow frozen at its mean over the step)."""
    return _velocity_matrix(domain, flow, time, span, streamline_form, lambda assembly: assembly.streamline)


def _velocity_matrix(domain: Domain, flow: Flow, time: float, span: float, form: BilinearForm,
                     quadrature: Callable[["QuadratureAdvection"], Callable[[np.ndarray], sp.csr_matrix]]
                     ) -> sp.csr_matrix:
    """``form`` with the flow's velocity on the periodic dofs: the Stokes field assembled by
    skfem, an analytic flow's by the domain's :class:`QuadratureAdvection` (its map
    ``quadrature(assembly)``)."""
    if flow.stokes is not None:
        basis = flow.stokes.pressure_basis  # P1 on the velocity basis' quadrature points
        velocity = np.asarray(flow.stokes.velocity_basis.interpolate(flow.stokes.velocity))
        fold = nodes_to_dofs(domain.dof_map, domain.n_dofs)
        return (fold.T @ form.assemble(basis, velocity=velocity) @ fold).tocsr()
    assembly = domain.advection_operators.setdefault("quadrature advection", lambda: QuadratureAdvection(domain))
    return quadrature(assembly)(assembly.velocity(flow, time, span))


class QuadratureAdvection:
    """C (:func:`advection_matrix`) and S (:func:`streamline_matrix`) of any velocity given
    at the quadrature points of the P1 basis of degree 4, each as one linear or quadratic
    map: on element e, with ∇φ_a constant, m_a = Σ_q w_q det(J_e) φ_a(x_q) v(x_q) and
    T_e = Σ_q w_q det(J_e) v(x_q) v(x_q)ᵀ (J_e the element map's Jacobian),

        C^e_ab = ½ (m_a·∇φ_b − m_b·∇φ_a),   S^e_ab = ∇φ_a · T_e ∇φ_b,

    summed into the entries of the domain's block pattern on the periodic dofs. The same
    matrices as :data:`skew_advection` and :data:`streamline_form` assembled by skfem and
    folded onto the dofs, to rounding; C in 3 ms instead of 70 on examples/straight_mesh.toml
    (33 480 elements): what a flow that changes in time and has no fixed direction field
    (:attr:`~femphase.flows.Flow.profile`) pays at every step."""

    def __init__(self, domain: Domain) -> None:
        basis = Basis(domain.mesh, ElementTriP1(), intorder=4)
        #: (x, y) of the quadrature points, each (elements, points per element)
        self.points = tuple(basis.mapping.F(basis.X))
        hats = [basis.basis[a][0] for a in range(3)]
        self._dx = np.asarray(basis.dx)  # (elements, points): weight × det(J)
        self._weighted = np.stack([np.asarray(hat) * self._dx for hat in hats])  # (3, elements, points)
        self._gradients = np.stack([hat.grad[:, :, 0] for hat in hats])  # (3, 2, elements): P1's are constant
        pattern = domain.block_pattern
        dofs = np.asarray(domain.dof_map)[domain.mesh.t].astype(np.int64)  # (3, elements)
        rows, columns = np.broadcast_arrays(dofs[:, None, :], dofs[None, :, :])
        #: the pattern's entry of every (a, b, element), a the row's corner
        self._entries, stored = pattern_entries(pattern, rows.ravel(), columns.ravel())
        if not stored.all():  # the pattern is the dofs' element connectivity: a mesh broken
            raise ValueError("the block pattern lacks pairs of dofs that share an element")
        self._pattern = pattern
        #: the last velocity asked (:meth:`velocity`): (flow, time, span) and its values, in an
        #: array made here so that the budget counts it from the start
        self._asked: tuple | None = None
        self._velocity = np.empty((2, *self._dx.shape))

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (*self.points, self._dx, self._weighted, self._gradients, self._entries,
                                          self._velocity)))

    def velocity(self, flow: Flow, time: float, span: float) -> np.ndarray:
        """(2, elements, points per element): the flow's velocity at :attr:`points` at
        ``time``, or with ``span`` > 0 its mean over [time, time + span]
        (:func:`~femphase.flows.time_mean`). The last one asked is kept: C and S of a step
        ask for the same, and the mean over a step was two thirds of an oscillating shear's
        step where both took it anew."""
        if self._asked is None or self._asked[0] is not flow or self._asked[1:] != (time, span):
            x, y = self.points
            self._velocity[...] = (velocity_at(flow, x, y, time) if span == 0.0
                                   else time_mean(lambda t: velocity_at(flow, x, y, t), time, span))
            self._asked = (flow, time, span)
        return self._velocity

    def matrix(self, velocity: np.ndarray) -> sp.csr_matrix:
        """C of the velocity (2, elements, points per element) at :attr:`points`."""
        moments = np.einsum("aeq,ceq->ace", self._weighted, velocity)  # m_a, (3, 2, elements)
        products = np.einsum("ace,bce->abe", moments, self._gradients)  # m_a·∇φ_b
        return self._summed(0.5 * (products - products.transpose(1, 0, 2)))

    def streamline(self, velocity: np.ndarray) -> sp.csr_matrix:
        """S of the velocity (2, elements, points per element) at :attr:`points`."""
        tensors = np.einsum("eq,ceq,deq->cde", self._dx, velocity, velocity)  # T_e, (2, 2, elements)
        return self._summed(np.einsum("ace,cde,bde->abe", self._gradients, tensors, self._gradients))

    def _summed(self, local: np.ndarray) -> sp.csr_matrix:
        """The element matrices ``local`` (3, 3, elements) summed on the block pattern."""
        data = np.bincount(self._entries, weights=local.ravel(), minlength=self._pattern.nnz)
        # the pattern's own index arrays copied: a caller may reorder a matrix's in place
        return sp.csr_matrix((data, self._pattern.indices.copy(), self._pattern.indptr.copy()),
                             shape=self._pattern.shape)


#: The pole r of the (2,2) Padé approximant R(z) = 1 + 2 Re[−2i√3/(1 − z/r)] of exp(−z).
PADE_POLE = -3.0 + 1j * np.sqrt(3.0)


class GalerkinAdvection(StepAdvection):
    """What the Galerkin steps share: the advection matrix C of the flow, assembled once for a
    steady flow and at every step, as its mean over the step, for a time-dependent one, and
    kept in the domain's budget per flow, so that advections of one flow over different dt
    (the adaptive scheme's substep sizes) share it and what is derived from it (:meth:`_per_flow`).

    A flow of fixed direction field, v = f(t) w(x) (:attr:`~femphase.flows.Flow.profile`), is
    the exception: C is linear in v, so the step's C is w's, assembled once, times f's mean
    over the step (:attr:`_scale`), and so are ω and everything else derived from C.
    Built at every step (C and S by :class:`QuadratureAdvection` from one mean velocity, ω
    by :data:`WARM_ITERATIONS` power iterations), an oscillating shear on
    examples/straight_mesh.toml takes 4.1× the CPU under flow of these scaled operators,
    and 4.5× a steady shear's (benchmarks/mesh_unsteady.py)."""

    def __init__(self, domain: Domain, flow: Flow, dt: float) -> None:
        super().__init__(domain, flow, dt)
        #: the time C is averaged over: None for a steady flow or one of fixed direction
        #: field, else the current step's (start, length)
        self._when: tuple[float, float] | None = None
        #: the current step's C over the assembled one: f's mean over the step for a flow of
        #: fixed direction field, else 1
        self._scale = 1.0

    def _per_flow(self, name: str, build: Callable[[], object]):
        """What ``build()`` derives from the flow at :attr:`_when` (C itself, its aligned entries,
        ω), kept under ``name`` for this flow and time."""
        key = (name, id(self.flow))
        operators = self.domain.advection_operators
        kept = operators.get(key)
        if kept is None or kept[0] is not self.flow or kept[1] != self._when:
            value = build()
            kept = operators.put(key, (self.flow, self._when, value), nbytes_of(value))
        return kept[2]

    @property
    def advection(self) -> sp.csr_matrix:
        """C (full mesh, periodic dofs) at :attr:`_when`, of the flow's profile where it has one
        (the step's C is then this times :attr:`_scale`)."""
        return self._per_flow("matrix", lambda: advection_matrix(self.domain, self.flow.profile or self.flow,
                                                                 *(self._when or (0.0, 0.0))))

    def _step_from(self, time: float) -> None:
        """Set :attr:`_scale` (a flow of fixed direction field) or :attr:`_when` (any other flow
        that changes) for the step from ``time``: C is then its mean over the step
        (:func:`advection_matrix`)."""
        if self.flow.profile is not None:
            self._scale = self.flow.mean_amplitude(time, self.dt)
        elif not self.flow.steady:
            self._when = (time, self.dt)


class GalerkinPade(GalerkinAdvection):
    """Galerkin advection with the (2,2) Padé step on a meshed domain (module docstring), one
    complex solver per window key in the domain's budget, rebuilt when the flow changes."""

    def __init__(self, domain: Domain, flow: Flow, dt: float, numerics: Numerics) -> None:
        self.numerics = numerics
        super().__init__(domain, flow, dt)
        self._solvers = domain.caches.cache("Padé solvers")
        self._system: tuple[float | None, sp.csr_matrix] | None = None

    def advect(self, phi: np.ndarray, layout: Layout, time: float) -> tuple[np.ndarray, Layout]:
        self._step_from(time)
        if self._system is None or self._system[0] != (self._when, self._scale):
            self._system = ((self._when, self._scale),
                            (self.domain.operators.mass - (self.dt * self._scale / PADE_POLE) * self.advection).tocsr())
            self._solvers.clear()
        system, mass = self._system[1], self.domain.operators.mass
        # solvers are kept for the layout's boxes only: a box left is rarely met again
        self._solvers.retain({key for key, *_ in layout.groups})
        out = np.empty_like(phi)
        for group, (key, members, start, stop, size) in enumerate(layout.groups):
            dofs = self.domain.window_dofs(layout.representative(group))
            solver, mass_block = self._solvers.setdefault(key, lambda: (
                make_solver(window_block(system, dofs), self.numerics.solver, self.numerics.tolerance),
                window_block(mass, dofs)))
            current_phi = phi[start:stop].reshape(members.size, size).T
            w = solver.solve((mass_block @ current_phi).astype(complex))
            out[start:stop].reshape(members.size, size).T[...] = current_phi + 4.0 * np.sqrt(3.0) * w.imag
        return out, layout


#: K, the Jacobi corrections of the lumped inverse in the explicit steps (module docstring:
#: a translating disc lags by 0.10–0.15 % under the Taylor–Galerkin step at K = 2, 0.17 %
#: under the Runge–Kutta step, 0.10 % with M⁻¹ exactly).
MASS_CORRECTIONS = 2
#: s, the stages and order of :class:`GalerkinRungeKutta`'s step. Three: a translating disc
#: lags as at four (0.17 %) and stretches by +0.0045 instead of +0.0037 (dt = 1), for three
#: quarters of the products, 0.87× the CPU of flow on examples/straight_mesh.toml
#: (docs/decisions/0026-three-stage-mesh-advection.md). Both are time errors far below the
#: spatial ones; the fourth-order step's extra accuracy is not needed.
STAGES = 3
#: The largest ω h of a substep, ω the spectral radius of P C: the Runge–Kutta step is stable
#: on the imaginary axis up to √3 (three stages), and at 1 its time error stays below the
#: spatial one (a disc translating at u = 1, four stages: elongation +0.004 at ω h ≤ 1
#: against +0.010 at ≤ 2; three stages: +0.0045 at ≤ 1). The Taylor–Galerkin step at K = 2
#: is stable up to ω h ≈ 1.3 (the amplification matrix's spectral radius on a small
#: Delaunay channel, tests/test_mesh_advection.py).
COURANT = 1.0
#: Margin on the power-iteration estimate of ω (:func:`spectral_radius`).
SPECTRAL_MARGIN = 1.25


def corrected_inverse(y: np.ndarray, mass: sp.spmatrix, inverse_lumped: np.ndarray,
                      corrections: int = MASS_CORRECTIONS) -> np.ndarray:
    """P y = Σ_{k≤K} (I − M_L⁻¹M)^k M_L⁻¹ y: the lumped inverse with K Jacobi corrections
    toward M⁻¹ y (``inverse_lumped`` = 1/diag M_L); each correction one sparse product and
    one compiled pass (:func:`~femphase.fem.kernels.jacobi_correction`)."""
    from femphase.fem import kernels  # numba loads only where windows are solved at once

    z = y * inverse_lumped
    for _ in range(corrections):
        kernels.jacobi_correction(z, y, mass @ z, inverse_lumped)
    return z


def spectral_radius(apply: Callable[[np.ndarray], np.ndarray], size: int, iterations: int = 30,
                    start: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """(ω, the last iterate): ω the largest eigenvalue modulus of an operator with imaginary
    eigenvalues (``apply``: x ↦ A x, A skew in some inner product), by power iteration on A²
    from ``start`` or else a fixed random vector (reproducible). A is not normal in the
    Euclidean norm used here, so the estimate may land slightly on either side of ω, and it
    approaches ω more slowly where the largest eigenvalues lie close together;
    :data:`SPECTRAL_MARGIN` leaves room for both (within 2 % of the dense eigenvalue on a
    small channel, asserted in tests/test_mesh_advection.py). The last iterate lies near the
    dominant eigenvectors: a start for an operator that changed a little
    (:data:`WARM_ITERATIONS`)."""
    x = np.random.default_rng(0).standard_normal(size) if start is None else np.array(start, dtype=float)
    x /= np.linalg.norm(x)
    estimate = 0.0
    for _ in range(iterations):
        y = apply(apply(x))
        norm = float(np.linalg.norm(y))
        if norm == 0.0:
            return 0.0, x
        estimate, x = np.sqrt(norm), y / norm
    return estimate, x


#: Power iterations of ω for a flow whose operators change at every step (no fixed direction
#: field), from the last step's iterate instead of 30 from a random start. On
#: examples/straight_mesh.toml in a flow varying in space and time, 0.1–0.7 % short of 200
#: iterations' estimate (30 from random: 0.3–1.5 %), but up to 8.5 % short for a few steps
#: where the flow's fastest region moved and the iterate followed it late; the margin
#: (:data:`SPECTRAL_MARGIN`) keeps ω h ≤ 0.87 there, below both steps' limits. An oscillating
#: shear given without its profile took 0.79× the CPU under flow (benchmarks/mesh_unsteady.py).
WARM_ITERATIONS = 8


class ExplicitGalerkin(GalerkinAdvection):
    """What the explicit steps share: K (:data:`MASS_CORRECTIONS`), ω and the substeps they
    take of each step, at ω h ≤ :data:`COURANT`. ``numerics`` is taken for the advections'
    common signature; no setting of it applies."""

    def __init__(self, domain: Domain, flow: Flow, dt: float, numerics: Numerics) -> None:
        #: K (module docstring), read from :data:`MASS_CORRECTIONS` when built (so a study can
        #: set it, verification/mesh_advection.py)
        self.corrections = MASS_CORRECTIONS
        super().__init__(domain, flow, dt)

    @property
    def frequency(self) -> float:
        """ω, the spectral radius of the step's P C on the whole mesh (1/time units). The windows' P C are
        not estimated on their own: the margin and ω h ≤ 1 against the steps' limits (√3 and
        ≈ 1.3) leave them room."""
        def estimate() -> float:
            ops, advection = self.domain.operators, self.advection
            inverse_lumped = 1.0 / ops.lumped_mass

            def apply(x: np.ndarray) -> np.ndarray:
                return corrected_inverse(advection @ x, ops.mass, inverse_lumped, self.corrections)

            if self._when is None:  # the flow's operators, built once
                return spectral_radius(apply, self.domain.n_dofs)[0]
            # built at every step: from the last step's iterate, kept per flow
            key = ("frequency iterate", id(self.flow))
            kept = self.domain.advection_operators.get(key)
            warm = kept is not None and kept[0] is self.flow
            value, iterate = spectral_radius(apply, self.domain.n_dofs, WARM_ITERATIONS if warm else 30,
                                             kept[1] if warm else None)
            self.domain.advection_operators.put(key, (self.flow, iterate), iterate.nbytes)
            return value
        return abs(self._scale) * self._per_flow(f"frequency {self.corrections}", estimate)

    @property
    def substeps(self) -> int:
        """Substeps per step of dt."""
        return max(1, int(np.ceil(SPECTRAL_MARGIN * self.frequency * self.dt / COURANT)))

    def _inverse_lumped(self, layout: Layout, dtype: type) -> np.ndarray:
        """M_L⁻¹ on the layout's positions in ``dtype`` (the fields' precision: float32 in
        single-precision steps, where a float64 operand would promote every product), kept
        with its blocks."""
        return self.domain.per_layout(layout, ("inverse lumped mass", dtype), lambda: (1.0 / layout.mass).astype(dtype))


class GalerkinRungeKutta(ExplicitGalerkin):
    """Galerkin advection with an explicit Runge–Kutta step and a corrected lumped mass
    inverse (module docstring), on all windows at once: per layout the block-diagonal
    matrices of the windows' principal submatrices of C and M (:mod:`femphase.fem.blocks`),
    nothing per window.
    C, its entries aligned to the block pattern, its block-diagonal form on the current
    layout and ω are the flow's, shared by every dt."""

    def __init__(self, domain: Domain, flow: Flow, dt: float, numerics: Numerics) -> None:
        #: s (module docstring), read from :data:`STAGES` when built
        self.stages = STAGES
        super().__init__(domain, flow, dt, numerics)

    def advect(self, phi: np.ndarray, layout: Layout, time: float) -> tuple[np.ndarray, Layout]:
        from femphase.fem import kernels  # numba loads only where windows are solved at once

        self._step_from(time)
        # in the fields' precision (float32 in single-precision steps): matrices and vectors
        # alike, so that no product is promoted to double
        dtype = np.dtype(phi.dtype).type
        aligned = self._per_flow(f"aligned {dtype.__name__}", lambda: self.domain.aligned(self.advection).astype(dtype))
        advection = self.domain.window_matrix(layout, ("advection", dtype), aligned)
        mass = self.domain.window_operator(layout, "mass", dtype)
        inverse_lumped = self._inverse_lumped(layout, dtype)
        # Σ_{k≤s} (−hPC)^k/k! x by Horner (on a linear, autonomous equation every Runge–Kutta
        # method of s stages and order s is this polynomial) in one compiled pass per product,
        # C and M sharing the layout's pattern
        substeps = self.substeps
        pattern = self.domain.window_blocks(layout)
        return kernels.galerkin_runge_kutta(
            unsigned(pattern.indptr), unsigned(pattern.indices), advection.data, mass.data, inverse_lumped,
            np.ascontiguousarray(phi), self.dt / substeps * self._scale, substeps, self.stages,
            self.corrections), layout


class TaylorGalerkin(ExplicitGalerkin):
    """Galerkin advection with the third-order Taylor–Galerkin step (module docstring) on all
    windows at once: C and the streamline matrix S (:func:`streamline_matrix`) are the
    flow's, and so, per substep size h, are F = −h (C + (h/2) S) and B = M + (h²/6) S,
    aligned to the block pattern; per layout their block-diagonal forms, K + 1 products a
    substep where :class:`GalerkinRungeKutta` takes s (K + 1). For a flow of fixed direction
    field, v = f(t) w(x), the step is that of w at the amplitude f̄ (its mean over the
    step): C scales with f̄ and S with f̄², which is a substep of h f̄ with w's matrices."""

    @property
    def streamline(self) -> sp.csr_matrix:
        """S (full mesh, periodic dofs) at :attr:`_when`, of the flow's profile where it has one."""
        return self._per_flow("streamline", lambda: streamline_matrix(self.domain, self.flow.profile or self.flow,
                                                                      *(self._when or (0.0, 0.0))))

    def advect(self, phi: np.ndarray, layout: Layout, time: float) -> tuple[np.ndarray, Layout]:
        from femphase.fem import kernels  # numba loads only where windows are solved at once

        self._step_from(time)
        dtype = np.dtype(phi.dtype).type
        substeps = self.substeps
        step = self.dt / substeps * self._scale
        forward, implicit = (self.domain.window_matrix(layout, (name, step, dtype), aligned).data for name, aligned
                             in zip(("Taylor–Galerkin F", "Taylor–Galerkin B"), self._aligned_matrices(step, dtype)))
        pattern = self.domain.window_blocks(layout)
        return kernels.taylor_galerkin(unsigned(pattern.indptr), unsigned(pattern.indices), forward, implicit,
                                       self._inverse_lumped(layout, dtype), np.ascontiguousarray(phi), substeps,
                                       self.corrections), layout

    def _aligned_matrices(self, step: float, dtype: type) -> tuple[np.ndarray, np.ndarray]:
        """The entries of F = −h (C + (h/2) S) and B = M + (h²/6) S aligned to the block pattern,
        for substeps of h = ``step`` (:func:`~femphase.fem.kernels.taylor_galerkin`), formed in
        double and kept in ``dtype`` per flow and h (the adaptive scheme repeats a few h), so
        that a layout's blocks of each are one gather."""
        def build() -> tuple[np.ndarray, np.ndarray]:
            aligned = self.domain.aligned
            advection, streamline = aligned(self.advection), aligned(self.streamline)
            forward = -step * (advection + (0.5 * step) * streamline)
            implicit = self.domain.aligned_operator("mass") + (step * step / 6.0) * streamline
            return forward.astype(dtype), implicit.astype(dtype)
        return self._per_flow(f"Taylor–Galerkin {step!r} {dtype.__name__}", build)
