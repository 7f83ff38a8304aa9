"""The discrete free energy as a list of terms, and its variational derivative.

Each term is an object with its energy, the derivative of its explicitly treated part, the
coefficient of its implicitly treated gradient part, and a bound on the curvature of its
explicit part (for the stabilisation of the time scheme). :class:`FreeEnergy` is the list;
δF/δφ, the stability bound and the output columns (``free_energy`` and one column per term)
are derived from it. A new term is one subclass of :class:`EnergyTerm` (``docs/architecture.md``).

The paper's functional (:meth:`FreeEnergy.paper`) discretised with P1 elements: potential
terms use the nodal (lumped-mass) quadrature, the gradient term is exact,

    F_h = Σ_i (γ/λ) [Σ_k m_k W(φ_ik) + λ² φ_iᵀ K φ_i]                interface
        + Σ_i μ (1 − a_i)²,      a_i = Σ_k m_k φ_ik² / (π R_i²)         area (squared)
        + (κ/λ) Σ_k m_k Σ_i Σ_{j≠i} φ_ik² φ_jk²                         repulsion

with m the lumped mass and W(φ) = 4φ²(1 − φ)². The repulsion sums over ordered pairs i ≠ j
as printed, so every unordered pair counts twice (docs/model.md). The variational derivative
in the lumped metric, δF/δφ_ik = (∂F_h/∂φ_ik) / m_k, is

    δF/δφ_i = g_i + D M_L⁻¹ K φ_i,   D = 2γλ,
    g_i     = (γ/λ) W'(φ_i) − (4μ/(πR_i²)) (1 − a_i) φ_i + (4κ/λ) φ_i Σ_{j≠i} φ_j²,

where g (:meth:`FreeEnergy.explicit_derivative`) is what time schemes treat explicitly.

Every quantity is computed window by window (:class:`WindowedFields`): cost and memory are
linear in the number of particles.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Callable, ClassVar, Iterator, Protocol

import numpy as np

from femphase.model.parameters import (
    ModelParameters,
    double_well,
    double_well_derivative,
)

__all__ = ["AREA_RATIO_MAX", "AreaTerm", "EnergyParts", "EnergyTerm", "FieldLayout", "FreeEnergy", "InterfaceTerm",
           "RepulsionTerm", "WindowedFields"]


class FieldLayout(Protocol):
    """What the free energy reads of the windows its fields live on: the model declares it,
    :class:`femphase.domains.layout.Layout` implements it (so the model depends on no
    discretisation). Arrays are per position of the flat vector ("layout order") unless
    stated; a window is one particle's set of dofs."""

    sizes: np.ndarray        # (N,) positions per window, layout order
    mass: np.ndarray         # lumped mass of every position's dof (length²)
    node_index: np.ndarray   # the dof of every position

    def per_slot(self, values: np.ndarray) -> np.ndarray:
        """Per-particle values (particle order) → per window (layout order)."""

    def reduce(self, ufunc: np.ufunc, values: np.ndarray) -> np.ndarray:
        """``ufunc`` reduced over every window's positions → one value per window."""

    def mass_like(self, values: np.ndarray) -> np.ndarray:
        """:attr:`mass` in the precision of ``values``."""

    def others_squared(self, squares: np.ndarray) -> np.ndarray:
        """Σ_{j≠i} φ_j² at every position of window i, from every position's φ²."""


#: Largest particle area ∫φ² / (πR²) for which the area term's curvature bound holds.
AREA_RATIO_MAX = 1.25


class WindowedFields:
    """All fields on their windows (the flat vector ``phi`` in layout order) and the
    quantities several terms share, each computed once.

    radii           target radius R_i of every particle (particle order)
    stiffness_apply K φ window by window (the principal submatrices), needed for energies only
    """

    def __init__(self, phi: np.ndarray, layout: FieldLayout, radii: np.ndarray,
                 stiffness_apply: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self.phi, self.layout = phi, layout
        self.radius = layout.per_slot(np.asarray(radii, dtype=float))
        self._stiffness_apply = stiffness_apply

    @cached_property
    def squares(self) -> np.ndarray:
        return self.phi**2

    @cached_property
    def others_squared(self) -> np.ndarray:
        """Σ_{j≠i} φ_j² at every position (exactly zero where no other window overlaps)."""
        return self.layout.others_squared(self.squares)

    @cached_property
    def areas(self) -> np.ndarray:
        """∫φ_i² per window (layout order; nodal quadrature)."""
        return self.layout.reduce(np.add, self.layout.mass_like(self.squares) * self.squares)

    @cached_property
    def area_ratio(self) -> np.ndarray:
        """a_i = ∫φ_i² / (πR_i²) per window (layout order)."""
        return self.areas / (np.pi * self.radius**2)

    def on_positions(self, per_window: np.ndarray) -> np.ndarray:
        """Per-window values (layout order) repeated onto every position of the window."""
        return np.repeat(per_window, self.layout.sizes)

    @cached_property
    def stiffness_product(self) -> np.ndarray:
        """K φ_i on every window."""
        if self._stiffness_apply is None:
            raise ValueError("this WindowedFields has no stiffness operator (energies need one)")
        return self._stiffness_apply(self.phi)

    def integral(self, values: np.ndarray) -> float:
        """Σ_k m_k values_k over all positions: the nodal quadrature."""
        return float(self.layout.mass @ values)


class EnergyTerm(ABC):
    """One term of the free energy.

    name             its output column (global.csv) and its key in :class:`EnergyParts`
    diffusivity      D of the implicitly treated part D M_L⁻¹ K φ of δF/δφ (0: none)
    """

    name: ClassVar[str]
    diffusivity: float = 0.0
    #: True when the term's δ/δφ_i is c φ_i with c ≥ 0 independent of φ_i (:meth:`decay_rate`):
    #: a pointwise linear decay of each field, which a scheme may integrate in exponential form
    decays: ClassVar[bool] = False
    #: True when the Hessian of the term's explicit part (lumped metric) contains, for every
    #: particle, a stiff rank-one part β_i φ_i (M_L φ_i)ᵀ (:meth:`rank_one_coefficient`),
    #: which a scheme may treat linearly implicitly
    rank_one: ClassVar[bool] = False
    #: True when the term's explicit derivative at a window's positions depends on that
    #: window's field alone (no sums over other windows): a scheme may then evaluate it on
    #: a few windows at a time (:meth:`femphase.domains.layout.Layout.parts`)
    window_local: ClassVar[bool] = False

    @abstractmethod
    def energy(self, fields: WindowedFields) -> float:
        """The term's energy (energy units)."""

    @abstractmethod
    def explicit_derivative(self, fields: WindowedFields) -> np.ndarray:
        """δ/δφ (lumped metric) of the explicitly treated part, at every position."""

    def explicit_energy(self, fields: WindowedFields) -> float:
        """The energy of the explicitly treated part (the whole term unless it has an
        implicit part): what a scalar-auxiliary-variable scheme tracks."""
        return self.energy(fields)

    def implicit_energy(self, fields: WindowedFields) -> float:
        """The energy of the implicitly treated part, (D/2) φᵀKφ: :meth:`energy` minus
        :meth:`explicit_energy` (zero without an implicit part)."""
        return 0.0

    @abstractmethod
    def curvature_bound(self, smallest_radius: float, pairs: bool) -> float:
        """An upper bound on the Hessian of the explicit part per unit lumped mass, for fields
        in [0, 1] with areas ∫φ² ≤ AREA_RATIO_MAX πR²; ``pairs`` False: one particle."""

    def decay_rate(self, fields: WindowedFields) -> np.ndarray:
        """c ≥ 0 at every position, for a term that ``decays``."""
        raise NotImplementedError(f"the {self.name} term is not a pointwise decay")

    def rank_one_coefficient(self, fields: WindowedFields) -> np.ndarray:
        """β_i ≥ 0 per window (layout order; energy/length⁴ in lattice units), for a term
        with a ``rank_one`` part."""
        raise NotImplementedError(f"the {self.name} term has no rank-one part")


@dataclass(frozen=True)
class InterfaceTerm(EnergyTerm):
    """(γ/λ) ∫ [4φ²(1 − φ)² + λ²|∇φ|²]: double well explicit, gradient implicit (D = 2γλ)."""

    tension: float
    interface_width: float
    name: ClassVar[str] = "interface"
    window_local: ClassVar[bool] = True

    @property
    def diffusivity(self) -> float:  # type: ignore[override]
        return 2.0 * self.tension * self.interface_width

    def energy(self, fields: WindowedFields) -> float:
        return self.explicit_energy(fields) + self.implicit_energy(fields)

    def explicit_derivative(self, fields: WindowedFields) -> np.ndarray:
        return double_well_derivative(fields.phi, self.tension / self.interface_width)

    def explicit_energy(self, fields: WindowedFields) -> float:
        return self.tension / self.interface_width * fields.integral(double_well(fields.phi))

    def implicit_energy(self, fields: WindowedFields) -> float:
        # (γ/λ) λ² φᵀKφ = (D/2) φᵀKφ
        return self.tension * self.interface_width * float(fields.phi @ fields.stiffness_product)

    def curvature_bound(self, smallest_radius: float, pairs: bool) -> float:
        # (γ/λ) W'' = (γ/λ) 8(1 − 6φ + 6φ²) ≤ 8γ/λ on [0, 1]
        return 8.0 * self.tension / self.interface_width


@dataclass(frozen=True)
class AreaTerm(EnergyTerm):
    """μ (1 − ∫φ²/πR²)² per particle: the soft area constraint (squared; docs/model.md)."""

    area_stiffness: float
    name: ClassVar[str] = "area"
    rank_one: ClassVar[bool] = True
    window_local: ClassVar[bool] = True

    def energy(self, fields: WindowedFields) -> float:
        return self.area_stiffness * float(np.sum((1.0 - fields.area_ratio) ** 2))

    def explicit_derivative(self, fields: WindowedFields) -> np.ndarray:
        force = 4.0 * self.area_stiffness / (np.pi * fields.radius**2) * (fields.area_ratio - 1.0)
        out = fields.on_positions(force.astype(fields.phi.dtype, copy=False))
        out *= fields.phi
        return out

    def curvature_bound(self, smallest_radius: float, pairs: bool) -> float:
        # the rank-one part 8μ a/(πR²) plus −4μ(1 − a)/(πR²), with a ≤ AREA_RATIO_MAX
        return 4.0 * self.area_stiffness / (np.pi * smallest_radius**2) * (3.0 * AREA_RATIO_MAX - 1.0)

    def rank_one_coefficient(self, fields: WindowedFields) -> np.ndarray:
        # a_i = (M_L φ_i)ᵀφ_i/(πR_i²), so ∂/∂φ of −(4μ/πR_i²)(1 − a_i) φ_i contains
        # (8μ/(πR_i²)²) φ_i (M_L φ_i)ᵀ: the area relaxing back at J0·8μ a_i/(πR_i²) ≈ 0.4 per
        # time unit at the paper's values, the stiffest explicit mode once the repulsion is split
        return 8.0 * self.area_stiffness / (np.pi * fields.radius**2) ** 2


@dataclass(frozen=True)
class RepulsionTerm(EnergyTerm):
    """Σ_i Σ_{j≠i} (κ/λ) ∫φ_i²φ_j² over ordered pairs (each unordered pair twice), so
    δF/δφ_i ∋ (4κ/λ) φ_i Σ_{j≠i} φ_j²."""

    repulsion: float
    interface_width: float
    name: ClassVar[str] = "repulsion"
    decays: ClassVar[bool] = True

    def energy(self, fields: WindowedFields) -> float:
        return self.repulsion / self.interface_width * fields.integral(fields.squares * fields.others_squared)

    def explicit_derivative(self, fields: WindowedFields) -> np.ndarray:
        return 4.0 * self.repulsion / self.interface_width * fields.phi * fields.others_squared

    def decay_rate(self, fields: WindowedFields) -> np.ndarray:
        # the derivative above is linear in φ_i: (4κ/λ) Σ_{j≠i} φ_j² times φ_i
        return 4.0 * self.repulsion / self.interface_width * fields.others_squared

    def curvature_bound(self, smallest_radius: float, pairs: bool) -> float:
        # one pair at a node: (2κ/λ)[[2φ_j², 4φ_iφ_j], [4φ_iφ_j, 2φ_i²]] ≤ 12κ/λ
        return 12.0 * self.repulsion / self.interface_width if pairs else 0.0


class EnergyParts(Mapping):
    """The free energy's parts by term name (energy units); ``total`` is their sum, and each
    part is also an attribute (``parts.interface``)."""

    def __init__(self, parts: dict[str, float]) -> None:
        self._parts = dict(parts)

    @property
    def total(self) -> float:
        return float(sum(self._parts.values()))

    def __getitem__(self, name: str) -> float:
        return self._parts[name]

    def __getattr__(self, name: str) -> float:
        try:
            return self.__dict__["_parts"][name]
        except KeyError:
            raise AttributeError(name) from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._parts)

    def __len__(self) -> int:
        return len(self._parts)

    def __repr__(self) -> str:
        return f"EnergyParts(total={self.total!r}, {self._parts!r})"


class FreeEnergy:
    """The free energy F = Σ terms, and what follows from the list of terms."""

    def __init__(self, terms: list[EnergyTerm] | tuple[EnergyTerm, ...]) -> None:
        self.terms = tuple(terms)
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names):
            raise ValueError(f"energy terms need distinct names, got {names}")

    @classmethod
    def paper(cls, params: ModelParameters) -> "FreeEnergy":
        """Interface, area and repulsion terms with the scene's parameters."""
        lam = params.interface_width
        return cls([InterfaceTerm(params.tension, lam), AreaTerm(params.area_stiffness),
                    RepulsionTerm(params.repulsion, lam)])

    @property
    def columns(self) -> tuple[str, ...]:
        """Output columns: the total, then one per term."""
        return ("free_energy",) + tuple(t.name for t in self.terms)

    @property
    def diffusivity(self) -> float:
        """D of the implicit part D M_L⁻¹ K φ of δF/δφ (length² per time per mobility)."""
        return float(sum(t.diffusivity for t in self.terms))

    def explicit_derivative(self, fields: WindowedFields) -> np.ndarray:
        """g: the explicitly treated part of δF/δφ at every position."""
        if not self.terms:
            return np.zeros_like(fields.phi)
        g = self.terms[0].explicit_derivative(fields)
        for term in self.terms[1:]:
            g += term.explicit_derivative(fields)
        return g

    def split_decay(self) -> tuple["FreeEnergy", tuple[EnergyTerm, ...]]:
        """(the energy of the other terms, the terms that are pointwise linear decays
        (:meth:`EnergyTerm.decay_rate`)): the split of sav2's flow step."""
        decaying = tuple(t for t in self.terms if t.decays)
        return FreeEnergy([t for t in self.terms if t not in decaying]), decaying

    def rank_one_coefficient(self, fields: WindowedFields) -> np.ndarray | None:
        """Σ β_i of the terms with a rank-one part (:meth:`EnergyTerm.rank_one_coefficient`),
        per window; None when no term has one."""
        coefficients = [t.rank_one_coefficient(fields) for t in self.terms if t.rank_one]
        return sum(coefficients[1:], coefficients[0]) if coefficients else None

    def explicit_energy(self, fields: WindowedFields) -> float:
        """E1: the energy of the explicitly treated parts (F minus its implicit gradient part)."""
        return float(sum(t.explicit_energy(fields) for t in self.terms))

    def implicit_energy(self, fields: WindowedFields) -> float:
        """F − E1: the energy of the implicitly treated parts (needs ``fields.stiffness_product``)."""
        return float(sum(t.implicit_energy(fields) for t in self.terms))

    def curvature_bound(self, smallest_radius: float, pairs: bool = True) -> float:
        """L: bound on the Hessian of the explicit energy per unit lumped mass."""
        return float(sum(t.curvature_bound(smallest_radius, pairs) for t in self.terms))

    def parts(self, fields: WindowedFields) -> EnergyParts:
        return EnergyParts({t.name: t.energy(fields) for t in self.terms})
