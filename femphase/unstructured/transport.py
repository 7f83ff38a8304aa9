"""Flows on a meshed channel: the Stokes flow of a scene, and the advection operator.

A flow is either a :class:`femphase.stokes.StokesFlow` solved on the domain's own mesh or any
:class:`femphase.flows.Flow` (an analytic u(x, y), e.g. the structured solver's Poiseuille).

Advection is the Galerkin form of v·∇φ in its skew-symmetric variant,

    c(φ, ψ) = ½ ∫ (v·∇φ) ψ − ½ ∫ (v·∇ψ) φ
            = ∫ (v·∇φ) ψ + ½ ∫ (∇·v) φ ψ − ½ ∮ (v·n) φ ψ,

equal to the advective form for a divergence-free v with v·n = 0 on the walls (no-slip) and
periodic sides, and exactly antisymmetric for the discrete, only weakly divergence-free P2
Stokes velocity: the Crank–Nicolson step built on it conserves ∫φ² (mass-matrix norm) for any
dt. The velocity enters at the quadrature points (P2 Stokes field exactly, analytic flows by
evaluation), not through a nodal interpolant.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from skfem import Basis, BilinearForm, ElementTriP1, ElementTriP2, ElementVector
from skfem.helpers import dot, grad

from ..discretisation import fold_matrix
from ..errors import SceneError
from ..flows import Flow
from ..stokes import StokesFlow, solve_stokes
from .domain import MeshDomain

#: Keys of a scene's ``flow = {type = "stokes", ...}`` table; exactly one driving key.
STOKES_DRIVES = ("max_velocity", "flux", "pressure_drop")


@BilinearForm
def skew_advection(u, v, w):
    return 0.5 * (dot(w.velocity, grad(u)) * v - dot(w.velocity, grad(v)) * u)


def _check_same_mesh(domain: MeshDomain, flow: StokesFlow) -> None:
    if flow.mesh.p.shape != domain.mesh.p.shape or not np.array_equal(flow.mesh.t, domain.mesh.t):
        raise ValueError("the Stokes flow was solved on another mesh than the domain's")


def nodal_velocity(domain: MeshDomain, flow: Flow | StokesFlow) -> np.ndarray:
    """(2, n_dofs): the flow's velocity at every dof."""
    if isinstance(flow, StokesFlow):
        _check_same_mesh(domain, flow)
        out = np.empty((2, domain.n_dofs))
        out[:, domain.dof_map] = flow.velocity_at_nodes()  # periodic partners carry equal values
        return out
    x, y = domain.coordinates
    u, v = flow.velocity(x, y)
    return np.stack([np.broadcast_to(u, x.shape), np.broadcast_to(v, x.shape)]).astype(float)


def advection_matrix(domain: MeshDomain, flow: Flow | StokesFlow) -> sp.csr_matrix:
    """The skew-symmetric advection matrix C_ij = c(φ_j, φ_i) on the periodic dofs."""
    if isinstance(flow, StokesFlow):
        _check_same_mesh(domain, flow)
        basis = flow.pressure_basis  # P1 on the velocity basis' quadrature points
        velocity = np.asarray(flow.velocity_basis.interpolate(flow.velocity))
    else:
        basis = Basis(domain.mesh, ElementTriP1(), intorder=4)
        x, y = basis.mapping.F(basis.X)
        u, v = flow.velocity(x, y)
        velocity = np.stack([np.broadcast_to(u, x.shape), np.broadcast_to(v, x.shape)])
    fold = fold_matrix(domain.dof_map, domain.n_dofs)
    matrix = skew_advection.assemble(basis, velocity=velocity)
    return (fold.T @ matrix @ fold).tocsr()


def stokes_drive(spec: dict) -> tuple[str, float, float]:
    """(driving key, its value, viscosity) of a ``{type = "stokes", ...}`` flow table;
    raises SceneError naming a bad key or value."""
    allowed = {"type", "viscosity", *STOKES_DRIVES}
    for key in spec:
        if key not in allowed:
            raise SceneError(f"flow.{key}", spec[key], f"a stokes flow takes only {sorted(allowed)}")
    given = [k for k in STOKES_DRIVES if k in spec]
    if len(given) != 1:
        raise SceneError("flow", spec, f"exactly one of {list(STOKES_DRIVES)} for a stokes flow")
    value = spec[given[0]]
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not np.isfinite(value):
        raise SceneError(f"flow.{given[0]}", value, "a finite number")
    viscosity = spec.get("viscosity", 1.0)
    if not isinstance(viscosity, (int, float)) or isinstance(viscosity, bool) or not viscosity > 0:
        raise SceneError("flow.viscosity", viscosity, "a number > 0")
    return given[0], float(value), float(viscosity)


def stokes_flow(domain: MeshDomain, spec: dict, unit: StokesFlow | None = None,
                cache: str | Path | None = None) -> StokesFlow:
    """The Stokes flow a scene's ``flow = {type = "stokes", ...}`` table describes.

    Keys: exactly one of ``max_velocity`` (the largest nodal speed; on a straight channel
    the Poiseuille centre-line velocity, the ``rate`` of ``type = "poiseuille"``), ``flux``
    (period-averaged flux Q) or ``pressure_drop`` (Δp over one period), and optionally
    ``viscosity`` (default 1). Walls are no-slip. ``unit``, a flow already solved on this
    domain with the same viscosity, is rescaled instead of solving again (Stokes is linear);
    ``cache`` is passed on to :func:`unit_stokes_flow`.
    """
    drive, value, viscosity = stokes_drive(spec)
    if unit is None or unit.viscosity != viscosity:
        unit = unit_stokes_flow(domain, float(viscosity), cache)
    if drive == "pressure_drop":
        scale = value / unit.pressure_drop
    elif drive == "flux":
        scale = value / unit.flux
    else:
        scale = value / np.hypot(*unit.velocity_at_nodes()).max()
    return replace(unit, velocity=scale * unit.velocity, pressure=scale * unit.pressure,
                   pressure_drop=scale * unit.pressure_drop, flux=scale * unit.flux)


def unit_stokes_flow(domain: MeshDomain, viscosity: float = 1.0, cache: str | Path | None = None) -> StokesFlow:
    """The Stokes flow driven by a unit pressure drop, read from ``cache`` (an .npz file)
    when it holds this mesh's solution, else solved (and written there).

    A P2 Stokes solve on a ~20k-node channel takes about a minute with SuperLU, so scenes
    keep the unit solution next to their mesh; the file stores a checksum of the mesh and
    the viscosity, and a stale file is solved again and overwritten.
    """
    checksum = _mesh_checksum(domain, viscosity)
    if cache is not None and Path(cache).is_file():
        with np.load(cache) as data:
            if str(data["checksum"]) == checksum:
                velocity_basis = Basis(domain.mesh, ElementVector(ElementTriP2()))
                return StokesFlow(
                    mesh=domain.mesh, velocity_basis=velocity_basis,
                    pressure_basis=velocity_basis.with_element(ElementTriP1()),
                    velocity=data["velocity"], pressure=data["pressure"], period=domain.period,
                    viscosity=viscosity, pressure_drop=1.0, flux=float(data["flux"]),
                )
    flow = solve_stokes(domain.mesh, domain.period, wall_facets=domain.wall_facets,
                        pressure_drop=1.0, viscosity=viscosity)
    if cache is not None:
        np.savez(cache, checksum=checksum, velocity=flow.velocity, pressure=flow.pressure, flux=flow.flux)
    return flow


def _mesh_checksum(domain: MeshDomain, viscosity: float) -> str:
    digest = hashlib.sha256()
    for array in (domain.mesh.p, domain.mesh.t, domain.wall_facets):
        digest.update(np.ascontiguousarray(array).tobytes())
    digest.update(repr(float(viscosity)).encode())
    return digest.hexdigest()
