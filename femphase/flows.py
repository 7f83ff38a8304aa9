"""Imposed velocity fields v(x, y) (lattice units per time unit).

Conventions (see DEVELOPERS.md): γ̇ ("rate") is a velocity scale, not a rate in lattice
units. Linear shear is u = γ̇ y/Ly with the bottom wall at rest and the top wall moving at
γ̇; ``scale="shear_rate"`` gives the plain u = γ̇ y (γ̇ is then ∂u/∂y). Poiseuille is
u = 4 γ̇ y (Ly − y)/Ly², so γ̇ is the centre-line velocity.

A flow whose velocity is (u(y), 0) is a *row flow*: its advection is an exact shift of
every row of nodes (:mod:`femphase.advection`). Any other flow is advected semi-Lagrangian.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .errors import SceneError

FLOW_TYPES = ("none", "shear", "poiseuille", "python")
SHEAR_SCALES = ("wall_velocity", "shear_rate")


@dataclass(frozen=True)
class Flow:
    """A steady velocity field. ``row_velocity`` is set for flows (u(y), 0)."""

    name: str
    velocity: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None
    row_velocity: Callable[[np.ndarray], np.ndarray] | None = None

    @property
    def is_still(self) -> bool:
        return self.velocity is None


def no_flow() -> Flow:
    return Flow("none", None)


def _row_flow(name: str, u: Callable[[np.ndarray], np.ndarray]) -> Flow:
    return Flow(name, lambda x, y: (u(np.asarray(y) + 0 * np.asarray(x)), 0 * np.asarray(x) * np.asarray(y)), u)


def linear_shear(rate: float, width: float, scale: str = "wall_velocity") -> Flow:
    """u = γ̇ y/Ly (scale="wall_velocity", default) or u = γ̇ y (scale="shear_rate")."""
    if scale not in SHEAR_SCALES:
        raise SceneError("flow.scale", scale, f"one of {SHEAR_SCALES}")
    gradient = rate / width if scale == "wall_velocity" else rate
    return _row_flow("shear", lambda y: gradient * y)


def poiseuille(rate: float, width: float) -> Flow:
    """u = 4 γ̇ y (Ly − y)/Ly²: γ̇ is the centre-line velocity; the walls are at rest."""
    return _row_flow("poiseuille", lambda y: 4.0 * rate * y * (width - y) / width**2)


def python_flow(function: Callable, row_flow: bool = False) -> Flow:
    """Any callable. With row_flow=True, ``function(y)`` is u(y) and v = 0; otherwise
    ``function(x, y)`` returns (u, v) for arrays x, y of the same shape."""
    if row_flow:
        return _row_flow("python", function)
    return Flow("python", function)


def flow_from_spec(spec: dict, width: float) -> Flow:
    """The flow a scene's ``flow`` table describes, e.g. {type = "shear", rate = 0.1487}."""
    kind = spec.get("type", "none")
    if kind not in FLOW_TYPES:
        raise SceneError("flow.type", kind, f"one of {FLOW_TYPES}")
    allowed = {"none": {"type"}, "shear": {"type", "rate", "scale"},
               "poiseuille": {"type", "rate"}, "python": {"type", "function", "row_flow"}}[kind]
    for key in spec:
        if key not in allowed:
            raise SceneError(f"flow.{key}", spec[key], f"a {kind} flow takes only {sorted(allowed)}")
    if kind == "none":
        return no_flow()
    if kind == "python":
        target = spec.get("function", "")
        module, _, attribute = str(target).partition(":")
        try:
            function = getattr(importlib.import_module(module), attribute)
        except (ImportError, AttributeError, ValueError):
            raise SceneError("flow.function", target, "an importable 'module:function'") from None
        return python_flow(function, bool(spec.get("row_flow", False)))
    rate = spec.get("rate")
    if not isinstance(rate, (int, float)) or not np.isfinite(rate):
        raise SceneError("flow.rate", rate, "a finite number (the velocity scale γ̇)")
    if kind == "shear":
        return linear_shear(float(rate), width, spec.get("scale", "wall_velocity"))
    return poiseuille(float(rate), width)
