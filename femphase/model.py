"""The multi-phase-field model of Hadjifrangiskou, Valani & Pinto: parameters and pointwise terms.

Each particle i is a field φ_i(x) ∈ [0, 1] obeying

    ∂t φ_i + v·∇φ_i = −J0 δF/δφ_i,   F = F_interface + F_area + F_repulsion,

    F_interface = Σ_i (γ/λ) ∫ [4 φ_i² (1 − φ_i)² + λ² |∇φ_i|²]
    F_area      = Σ_i μ (1 − ∫φ_i² / (π R_i²))²
    F_repulsion = Σ_i Σ_{j≠i} (κ/λ) ∫ φ_i² φ_j²

Conventions (decisions on defects of the printed paper, see DEVELOPERS.md):

* the area term is squared (the printed equation lacks the square, which would make F
  unbounded below);
* the repulsion double sum runs over ordered pairs, so every unordered pair is counted
  twice and δF/δφ_i contains 4κ/λ · φ_i Σ_{j≠i} φ_j²;
* lengths are in lattice units (the paper's Δx = 1), times in the paper's time units.

The discrete free energy and its gradient live in :mod:`femphase.energy`; this module holds
only parameters and pointwise functions of φ.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .errors import SceneError

#: Paper symbol → parameter name; scenes accept either spelling.
PAPER_SYMBOLS = {
    "lambda": "interface_width",
    "gamma": "tension",
    "kappa": "repulsion",
    "mu": "area_stiffness",
    "J0": "mobility",
    "R": "radius",
}


@dataclass(frozen=True)
class ModelParameters:
    """Model constants, with the paper's values as defaults (lattice units).

    interface_width  λ   interface thickness ~2λ (length)
    tension          γ   γ/λ is the interface energy scale
    repulsion        κ   κ/λ is the overlap energy scale
    area_stiffness   μ   strength of the soft area constraint (energy)
    mobility         J0  relaxation rate (1 / (energy · time))
    radius           R   target radius of every particle unless a scene sets radii per particle
    """

    interface_width: float = 2.0
    tension: float = 0.06
    repulsion: float = 0.5
    area_stiffness: float = 20.0
    mobility: float = 0.5
    radius: float = 8.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(value) or value < 0:
                raise SceneError(f"model.{name}", value, "must be a finite number ≥ 0")
        for name in ("interface_width", "radius", "mobility"):
            if getattr(self, name) <= 0:
                raise SceneError(f"model.{name}", getattr(self, name), "must be > 0")

    @property
    def diffusivity(self) -> float:
        """J0 · 2γλ: the coefficient of the Laplacian in the equation of motion (length²/time)."""
        return 2.0 * self.mobility * self.tension * self.interface_width


def double_well(phi: np.ndarray) -> np.ndarray:
    """4 φ² (1 − φ)²: zero at φ = 0 and φ = 1."""
    return 4.0 * phi**2 * (1.0 - phi) ** 2


def double_well_derivative(phi: np.ndarray) -> np.ndarray:
    """d/dφ of :func:`double_well`: 8 φ (1 − φ)(1 − 2φ)."""
    return 8.0 * phi * (1.0 - phi) * (1.0 - 2.0 * phi)


def interface_profile(signed_distance: np.ndarray, interface_width: float) -> np.ndarray:
    """The flat-interface equilibrium (1 + tanh(d/λ))/2, d > 0 inside the particle."""
    return 0.5 * (1.0 + np.tanh(signed_distance / interface_width))


def explicit_curvature_bound(params: ModelParameters, smallest_radius: float, pairs: bool = True) -> float:
    """Upper bound L on the Hessian of the explicitly treated energy, per unit (lumped) mass.

    The semi-implicit step treats the gradient term implicitly and everything else
    explicitly; it decreases the discrete energy whenever the stabilisation S satisfies
    S ≥ L/2 − c/(J0 dt) (see :func:`stabilisation_for`). The bound holds for fields in
    [0, 1] and particle areas ∫φ² ≤ 1.25 πR²:

    * double well: (γ/λ) · 8 (1 − 6φ + 6φ²) ≤ 8γ/λ;
    * area: the rank-one term 8μ a/(πR²) plus −4μ(1 − a)/(πR²), with a = ∫φ²/πR² ≤ 1.25;
    * repulsion, one pair at a node: (2κ/λ)[[2φ_j², 4φ_iφ_j], [4φ_iφ_j, 2φ_i²]] ≤ 12κ/λ
      (absent when ``pairs`` is False: a single particle).
    """
    lam = params.interface_width
    area_ratio_max = 1.25
    area_scale = 4.0 * params.area_stiffness / (np.pi * smallest_radius**2)
    return (
        8.0 * params.tension / lam
        + area_scale * (3.0 * area_ratio_max - 1.0)
        + (12.0 * params.repulsion / lam if pairs else 0.0)
    )


def stabilisation_for(
    params: ModelParameters, dt: float, smallest_radius: float, mass_lower_bound: float, pairs: bool = True
) -> float:
    """The smallest stabilisation S that makes the no-flow step energy-decreasing.

    With the scheme (G/dt + J0 S M_L + J0 A) φ¹ = (G/dt + J0 S M_L) φ⁰ − J0 M_L g(φ⁰)
    and G ≥ c M_L (c = 1 for lumped mass, 1/4 for the consistent P1 mass matrix), one has
    F(φ¹) − F(φ⁰) ≤ −(c/(J0 dt) + S − L/2) |φ¹ − φ⁰|²_{M_L}, so S = max(0, L/2 − c/(J0 dt)).
    The time derivative itself carries the stabilisation at small dt: at the paper's
    parameters S = 0 for dt ≤ dt* = 2c/(J0 L) ≈ 0.92 (lumped mass, several particles).
    Above dt*, G/dt + J0 S M_L = (J0 L/2) M_L no longer depends on dt: the explicit forces
    advance by dt* per step however large dt is (advection and diffusion by the full dt).
    Large steps are therefore stable but slow the relaxation by dt/dt*.
    """
    half_bound = 0.5 * explicit_curvature_bound(params, smallest_radius, pairs)
    return max(0.0, half_bound - mass_lower_bound / (params.mobility * dt))
