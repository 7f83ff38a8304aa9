"""The multi-phase-field model of Hadjifrangiskou, Valani & Pinto: parameters and pointwise terms.

Each particle i is a field φ_i(x) ∈ [0, 1] obeying ::

    ∂t φ_i + v·∇φ_i = −J0 δF/δφ_i,   F = F_interface + F_area + F_repulsion,

    F_interface = Σ_i (γ/λ) ∫ [4 φ_i² (1 − φ_i)² + λ² |∇φ_i|²]
    F_area      = Σ_i μ (1 − ∫φ_i² / (π R_i²))²
    F_repulsion = Σ_i Σ_{j≠i} (κ/λ) ∫ φ_i² φ_j²

Conventions (decisions on defects of the printed paper, see docs/model.md):

* the area term is squared (the printed equation lacks the square, which would make F
  unbounded below);
* the repulsion double sum runs over ordered pairs, so every unordered pair is counted
  twice and δF/δφ_i contains 4κ/λ · φ_i Σ_{j≠i} φ_j²;
* lengths are in lattice units (the paper's Δx = 1), times in the paper's time units.

The discrete free energy, its terms and its gradient live in :mod:`femphase.model.energy`; this
module holds only parameters and pointwise functions of φ.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from femphase.errors import SceneError

__all__ = ["PAPER_SYMBOLS", "double_well", "double_well_derivative", "interface_profile", "ModelParameters"]

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
    tension          γ   line tension (energy / length); γ/λ is the interface energy density
    repulsion        κ   overlap strength (energy / length); κ/λ is the overlap energy density
    area_stiffness   μ   strength of the soft area constraint (energy)
    mobility         J0  in ∂tφ = −J0 δF/δφ, δF/δφ an energy per area (length² / (energy · time))
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
            real = (int, float, np.integer, np.floating)
            number = isinstance(value, real) and not isinstance(value, (bool, np.bool_))
            if not number or not np.isfinite(value) or value < 0:
                raise SceneError(f"model.{name}", value, "must be a finite number ≥ 0")
        for name in ("interface_width", "radius", "mobility"):
            if getattr(self, name) <= 0:
                raise SceneError(f"model.{name}", getattr(self, name), "must be > 0")

    @property
    def diffusivity(self) -> float:
        """J0 · 2γλ: the coefficient of the Laplacian in the equation of motion (length²/time)."""
        return 2.0 * self.mobility * self.tension * self.interface_width

    def area_rate(self, radius: float) -> float:
        """c = J0·8μ/(πR²): the rate (1/time) at which a particle of target radius R relaxes
        back to its area, 1/τ_A (0.4 at the paper's values)."""
        return 8.0 * self.mobility * self.area_stiffness / (np.pi * radius**2)

    def repulsion_rate(self) -> float:
        """c = 4·J0·κ/λ: the rate (1/time) at which the repulsion decays a field where a
        neighbour's φ is 1, its largest (0.5 at the paper's values)."""
        return 4.0 * self.mobility * self.repulsion / self.interface_width


def double_well(phi: np.ndarray) -> np.ndarray:
    """4 φ² (1 − φ)²: zero at φ = 0 and φ = 1."""
    return 4.0 * phi**2 * (1.0 - phi) ** 2


def double_well_derivative(phi: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """``scale`` times d/dφ of :func:`double_well`: 8 φ (1 − φ)(1 − 2φ) = φ (8 − 24 φ + 16 φ²)."""
    # Horner's rule in place: five passes over φ instead of eight, the scale folded into the
    # coefficients (the adaptive scheme evaluates this force twice per substep)
    out = phi * (16.0 * scale)
    out -= 24.0 * scale
    out *= phi
    out += 8.0 * scale
    out *= phi
    return out


def interface_profile(signed_distance: np.ndarray, interface_width: float) -> np.ndarray:
    """The flat-interface equilibrium (1 + tanh(d/λ))/2, d > 0 inside the particle."""
    return 0.5 * (1.0 + np.tanh(signed_distance / interface_width))
