r"""Stokes flow in a 2D channel that is periodic in x.

Solves

.. math::
    -\nabla\cdot(2\eta\,\varepsilon(\boldsymbol u)) + \nabla p = G\,\hat{\boldsymbol x},
    \qquad \nabla\cdot\boldsymbol u = 0,

on a triangulated channel ``[x0, x0 + period] × walls`` with no-slip on the
walls and periodicity between ``x = x0`` and ``x = x0 + period``.

Conventions
-----------
* Units are consistent but arbitrary: lengths in the mesh's unit, viscosity
  ``η`` [pressure × time], pressure drop ``Δp`` [pressure], velocity
  [length / time], flux ``Q`` [length² / time] (2D: per unit depth).
* A pressure drop ``Δp = p(x0) - p(x0 + period) > 0`` drives flow towards
  +x.  The physical pressure is not periodic, but ``p_phys = p - G (x - x0)``
  with ``G = Δp / period`` splits it into a periodic part ``p`` and a uniform
  gradient, and ``-∇p_phys = G x̂ - ∇p``: the drop enters as the uniform
  body force ``G`` in x, and only the periodic part ``p`` is solved for.
* ``p`` is fixed to zero mean over the domain (periodicity plus no-slip
  leave it defined only up to a constant).
* The flux is the period-averaged flux ``Q = (1/period) ∫_Ω u_x dA``.  For a
  divergence-free field it equals the flux through every cross-section; for
  the discrete (weakly divergence-free) field it is the one section-
  independent choice, and ``G · period · Q`` is the power input.

Discretisation: Taylor–Hood P2/P1, inf-sup stable so no pressure
stabilisation is needed, assembled on the non-periodic mesh and folded with
:mod:`femphase.fem.periodic`.

Cache of unit solutions
-----------------------
A scene's Stokes flow is the solution for a unit pressure drop, rescaled
(Stokes flow is linear in the driving); that solution takes 10–14 CPU s of
SuperLU and about 1.5 GB on a 17k-node mesh (docs/scenes.md), so :func:`domain_stokes_flow`
keeps it in a user cache folder, :func:`cache_dir`:

* ``$FEMPHASE_CACHE`` if set (and not empty), else ``$XDG_CACHE_HOME/femphase``,
  else ``~/.cache/femphase``;
* one file per mesh and viscosity, ``stokes-<key>.npz``, ``<key>`` a digest of
  the mesh's nodes, triangles and walls and of the viscosity
  (:func:`cache_key`): the mesh's path plays no part, so a moved, copied or
  read-only mesh file finds its solution, and an edited one does not find a
  stale one;
* written atomically (a temporary file in the folder, then ``os.replace``), so
  concurrent runs and kills never leave half a file under the final name;
* validated on reading: a file that is truncated, corrupt, of another format
  version, or whose stored key, array sizes or values do not fit the mesh is
  solved again and replaced, with a :class:`StokesCacheWarning` naming the file;
* a cache folder that cannot be created or written (read-only, full, a path
  through a regular file) does not fail the run: a warning, and the run goes
  on without caching.

Deleting the folder is always safe.  Meshes built in memory (no file) are
not cached.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import warnings
import weakref
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import spsolve
from skfem import (
    Basis,
    BilinearForm,
    CellBasis,
    ElementTriP1,
    ElementTriP2,
    ElementVector,
    LinearForm,
    MeshTri,
    condense,
)
from skfem.helpers import ddot, div, sym_grad

from femphase.domains.base import Domain
from femphase.domains.mesh.domain import MeshDomain
from femphase.errors import SceneError
from femphase.fem.periodic import fold_matrix, periodic_dof_map
from femphase.flows import FLOWS, Flow

__all__ = ["STOKES_DRIVES", "StokesCacheWarning", "StokesFlow", "cache_dir", "cache_key", "cache_path",
           "build_stokes_flow", "channel_mesh", "check_open_channel", "domain_stokes_flow", "poiseuille_profile",
           "solve_stokes", "stokes_drive", "stokes_flow", "unit_stokes_flow"]


#: Keys of a scene's ``flow = {type = "stokes", ...}`` table; exactly one driving key.
STOKES_DRIVES = ("max_velocity", "flux", "pressure_drop")
#: A channel whose Stokes flux is below this fraction of an open channel's of its height is
#: closed: walls or obstacles span it. A slit of a hundredth of the height along the whole
#: period still passes (1/100)³ = 1e-6; a closed channel passes round-off, about 1e-17.
CLOSED_CHANNEL = 1e-9
#: Format version of the cache files (a file of another version is solved again).
CACHE_VERSION = 2


class StokesCacheWarning(UserWarning):
    """The Stokes cache could not be used (a damaged file was replaced, or the folder is
    not writable); the run goes on, solving the flow."""


@BilinearForm
def viscous(u, v, w):
    # stress form 2η ε(u):ε(v) rather than η ∇u:∇v: identical for constant η
    # on this domain, and the right one once η varies between phases
    return 2.0 * w.viscosity * ddot(sym_grad(u), sym_grad(v))


@BilinearForm
def divergence(u, q, w):
    return div(u) * q


@LinearForm
def streamwise(v, w):
    return v[0]


@LinearForm
def unit(q, w):
    return q


@dataclass(frozen=True)
class StokesFlow:
    """A periodic Stokes solution.

    Attributes
    ----------
    mesh
        The non-periodic mesh the problem was assembled on.
    velocity_basis, pressure_basis
        P2 vector and P1 scalar bases on `mesh`.
    velocity
        P2 dof values on every dof of `velocity_basis` (periodic partners
        carry equal values), length / time.
    pressure
        Periodic part of the pressure on the P1 dofs, zero mean; the physical
        pressure is ``pressure - (pressure_drop / period) * (x - x0)``.
    period
        Length of the periodic cell in x.
    viscosity
        Dynamic viscosity ``η``.
    pressure_drop
        ``Δp`` over one period driving the flow (given, or implied by a
        prescribed flux).
    flux
        Period-averaged flux ``(1/period) ∫ u_x dA`` (see module docstring).
    """

    mesh: MeshTri
    velocity_basis: CellBasis
    pressure_basis: CellBasis
    velocity: np.ndarray
    pressure: np.ndarray
    period: float
    viscosity: float
    pressure_drop: float
    flux: float

    def velocity_at_nodes(self) -> np.ndarray:
        """``(u, v)`` at the mesh vertices, shape ``(2, n_vertices)``."""
        return self.velocity[self.velocity_basis.nodal_dofs]

    def __call__(
        self, x: np.ndarray, y: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Evaluate the P2 velocity at points ``(x, y)``.

        `x` is wrapped into the periodic cell, so any x is accepted; `y` must
        lie inside the channel.  Returns ``(u, v)`` with the broadcast shape
        of `x` and `y`.
        """
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        x0 = self.mesh.p[0].min()
        points = np.vstack([x0 + np.mod(x.ravel() - x0, self.period),
                            y.ravel()])
        u, v = self.velocity_basis.interpolator(self.velocity)(points)
        return u.reshape(x.shape), v.reshape(x.shape)


def solve_stokes(
    mesh: MeshTri,
    period: float,
    *,
    wall_facets: np.ndarray | None = None,
    pressure_drop: float | None = None,
    flux: float | None = None,
    viscosity: float = 1.0,
) -> StokesFlow:
    """Solve periodic channel Stokes flow driven by a pressure drop or a flux.

    Parameters
    ----------
    mesh
        Triangular mesh of the channel; its x extent must equal `period`, and
        nodes on its two x sides must match (see
        :func:`femphase.fem.periodic.periodic_dof_map`).
    period
        Length of the periodic cell in x.
    wall_facets
        Facet indices carrying no-slip.  By default, every boundary facet not
        lying on either periodic side.
    pressure_drop
        ``Δp`` over one period (drives flow towards +x when positive).
    flux
        Prescribed period-averaged flux ``Q`` (towards +x when positive).
    viscosity
        Dynamic viscosity ``η > 0``.

    Exactly one of `pressure_drop` and `flux` must be given.  Stokes flow is
    linear in the driving, so the system is solved once for a unit body force
    and the solution scaled: by ``Δp / period``, or by ``Q / Q_unit``.
    """
    if (pressure_drop is None) == (flux is None):
        raise ValueError(
            "give exactly one of pressure_drop and flux; got "
            f"pressure_drop={pressure_drop}, flux={flux}"
        )
    drive = pressure_drop if flux is None else flux
    if not np.isfinite(drive):
        raise ValueError(
            f"driving must be finite; got pressure_drop={pressure_drop}, "
            f"flux={flux}"
        )
    if not (np.isfinite(viscosity) and viscosity > 0):
        raise ValueError(f"viscosity must be positive; got {viscosity}")
    x = mesh.p[0]
    extent = x.max() - x.min()
    if not (period > 0 and np.isclose(extent, period, rtol=1e-8, atol=0)):
        raise ValueError(
            f"period {period} does not match the mesh's x extent {extent} "
            f"(x from {x.min()} to {x.max()})"
        )
    if wall_facets is None:
        wall_facets = _wall_facets(mesh, period)
    if len(wall_facets) == 0:
        raise ValueError(
            "no wall facets: without no-slip the periodic velocity is "
            "defined only up to a constant"
        )

    velocity_basis = Basis(mesh, ElementVector(ElementTriP2()))
    # same quadrature as the velocity basis, as the divergence form needs
    pressure_basis = velocity_basis.with_element(ElementTriP1())
    load = streamwise.assemble(velocity_basis)
    velocity, pressure = _unit_force_solution(
        velocity_basis, pressure_basis, load, period, wall_facets, viscosity
    )
    # ∫ u_x dA is the unit load applied to the velocity
    unit_flux = load @ velocity / period
    scale = drive / period if flux is None else flux / unit_flux
    return StokesFlow(
        mesh=mesh,
        velocity_basis=velocity_basis,
        pressure_basis=pressure_basis,
        velocity=scale * velocity,
        pressure=scale * pressure,
        period=period,
        viscosity=viscosity,
        pressure_drop=scale * period,
        flux=scale * unit_flux,
    )


def poiseuille_profile(
    y: np.ndarray, Ly: float, max_velocity: float
) -> np.ndarray:
    """Plane Poiseuille profile ``u = 4 U y (Ly - y) / Ly²`` between walls
    at ``y = 0`` and ``y = Ly`` with centreline velocity ``U``.

    Driven by a pressure gradient ``G = Δp / Lx``, ``U = G Ly² / (8 η)``;
    the flux is ``Q = 2 U Ly / 3``.
    """
    y = np.asarray(y, dtype=float)
    return 4.0 * max_velocity * y * (Ly - y) / Ly**2


def channel_mesh(
    length: float,
    height: float,
    nx: int,
    ny: int,
    *,
    jitter: float = 0.0,
    seed: int | None = None,
) -> MeshTri:
    """Triangulated channel ``[0, length] × [0, height]`` with periodic-
    matching x sides.

    With ``jitter > 0`` the structured ``nx × ny`` mesh is made irregular by
    moving every node by up to ``jitter`` times the grid spacing in each
    direction: interior nodes freely, wall nodes along the wall, side nodes
    along the side, identically on ``x = 0`` and ``x = length`` so the sides
    still match; corners stay put.  ``jitter < 1/4`` keeps every triangle
    positively oriented (each edge vector changes by under half a spacing
    per component).
    """
    if not 0 <= jitter < 0.25:
        raise ValueError(f"jitter must be in [0, 0.25); got {jitter}")
    mesh = MeshTri.init_tensor(
        np.linspace(0.0, length, nx + 1), np.linspace(0.0, height, ny + 1)
    )
    if jitter == 0:
        return mesh
    x, y = mesh.p
    rng = np.random.default_rng(seed)
    dx = jitter * length / nx * rng.uniform(-1, 1, x.size)
    dy = jitter * height / ny * rng.uniform(-1, 1, y.size)
    # init_tensor keeps the linspace end points exactly
    dx[(x == 0.0) | (x == length)] = 0.0
    dy[(y == 0.0) | (y == height)] = 0.0
    dy = dy[periodic_dof_map(mesh.p, length)]
    return MeshTri(mesh.p + np.vstack([dx, dy]), mesh.t)


def _wall_facets(mesh: MeshTri, period: float) -> np.ndarray:
    """Boundary facets not on either periodic side.

    A boundary facet lies on a side exactly when its midpoint does, since
    the sides are the extremes of x.
    """
    facets = mesh.boundary_facets()
    x = mesh.p[0]
    midpoint = x[mesh.facets[:, facets]].mean(axis=0)
    tol = 1e-8 * period
    on_side = (np.abs(midpoint - x.min()) <= tol) | (
        np.abs(midpoint - (x.min() + period)) <= tol
    )
    return facets[~on_side]


def _periodic_map(basis: CellBasis, period: float) -> np.ndarray:
    """Periodic dof map of `basis`, matching each vector component only
    with itself (components share their dof locations)."""
    dof_map = np.arange(basis.N)
    for component in basis.split_indices():
        local = periodic_dof_map(basis.doflocs[:, component], period)
        dof_map[component] = component[local]
    return dof_map


def _unit_force_solution(
    velocity_basis: CellBasis,
    pressure_basis: CellBasis,
    load: np.ndarray,
    period: float,
    wall_facets: np.ndarray,
    viscosity: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and zero-mean periodic pressure for the unit body force
    whose load vector is `load`, on all (unfolded) dofs."""
    A = viscous.assemble(velocity_basis, viscosity=viscosity)
    B = divergence.assemble(velocity_basis, pressure_basis)
    K = sp.bmat([[A, -B.T], [-B, None]], format="csr")
    f = np.concatenate([load, np.zeros(pressure_basis.N)])

    P_u, compact_u = fold_matrix(_periodic_map(velocity_basis, period))
    P_p, _ = fold_matrix(_periodic_map(pressure_basis, period))
    P = sp.block_diag([P_u, P_p], format="csr")
    walls = np.unique(compact_u[velocity_basis.get_dofs(wall_facets).all()])
    # no-slip, plus one pressure dof pinned to remove the constant mode
    D = np.append(walls, P_u.shape[1])

    # the folded system is an indefinite saddle point solved once per call,
    # small enough in 2D for a sparse LU (SuperLU with pivoting handles the
    # zero pressure block); iterative solvers would need a block
    # preconditioner for no gain here
    K_fold, f_fold, solution, interior = condense(P.T @ K @ P, P.T @ f, D=D)
    solution[interior] = spsolve(K_fold.tocsc(), f_fold)
    velocity, pressure = np.split(P @ solution, [velocity_basis.N])

    weights = unit.assemble(pressure_basis)
    pressure -= weights @ pressure / weights.sum()
    return velocity, pressure


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
    if (not isinstance(viscosity, (int, float)) or isinstance(viscosity, bool) or not np.isfinite(viscosity)
            or not viscosity > 0):
        raise SceneError("flow.viscosity", viscosity, "a finite number > 0")
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
    """The Stokes flow driven by a unit pressure drop, read from ``cache`` (an .npz file,
    e.g. :func:`cache_path`) when it holds this mesh's solution, else solved and written
    there (see "Cache of unit solutions" in the module docstring: a damaged or stale file
    is solved again with a warning, an unwritable place only warns)."""
    key = cache_key(domain, viscosity)
    if cache is not None:
        flow = _read_cache(Path(cache), domain, viscosity, key)
        if flow is not None:
            return flow
    flow = solve_stokes(domain.mesh, domain.period, wall_facets=domain.wall_facets,
                        pressure_drop=1.0, viscosity=viscosity)
    if cache is not None:
        _write_cache(Path(cache), flow, key)
    return flow


def cache_dir() -> Path:
    """The folder of cached Stokes solutions: ``$FEMPHASE_CACHE``, else
    ``$XDG_CACHE_HOME/femphase``, else ``~/.cache/femphase`` (empty variables count as unset)."""
    if os.environ.get("FEMPHASE_CACHE"):
        return Path(os.environ["FEMPHASE_CACHE"]).expanduser()
    if os.environ.get("XDG_CACHE_HOME"):
        return Path(os.environ["XDG_CACHE_HOME"]).expanduser() / "femphase"
    return Path.home() / ".cache" / "femphase"


def cache_path(domain: MeshDomain, viscosity: float = 1.0, folder: str | Path | None = None) -> Path:
    """The cache file of the unit solution on ``domain`` at ``viscosity``, in ``folder``
    (default :func:`cache_dir`)."""
    return Path(cache_dir() if folder is None else folder) / f"stokes-{cache_key(domain, viscosity)[:32]}.npz"


def cache_key(domain: MeshDomain, viscosity: float) -> str:
    """A digest of the mesh's nodes, triangles and wall facets and of the viscosity."""
    digest = hashlib.sha256()
    for array in (domain.mesh.p, domain.mesh.t, domain.wall_facets):
        digest.update(np.ascontiguousarray(array).tobytes())
    digest.update(repr(float(viscosity)).encode())
    return digest.hexdigest()




def _read_cache(path: Path, domain: MeshDomain, viscosity: float, key: str) -> StokesFlow | None:
    """The unit flow stored in ``path``, or None (absent, or damaged/stale: then warned)."""
    if not path.exists():
        return None
    velocity_basis = Basis(domain.mesh, ElementVector(ElementTriP2()))
    pressure_basis = velocity_basis.with_element(ElementTriP1())
    try:
        with np.load(path, allow_pickle=False) as data:
            stored = {name: data[name] for name in ("version", "checksum", "velocity", "pressure", "flux")}
        if int(stored["version"]) != CACHE_VERSION:
            problem = f"format version {int(stored['version'])}, not {CACHE_VERSION}"
        elif str(stored["checksum"]) != key:
            problem = "it holds the solution of another mesh or viscosity"
        elif stored["velocity"].shape != (velocity_basis.N,) or stored["pressure"].shape != (pressure_basis.N,):
            problem = "its arrays do not fit the mesh"
        elif not (np.isfinite(stored["velocity"]).all() and np.isfinite(stored["pressure"]).all()
                  and np.isfinite(stored["flux"]) and float(stored["flux"]) > 0):
            problem = "it holds values that are not finite, or a flux that is not positive"
        else:
            problem = None
    except Exception as exc:  # truncated or corrupt: zipfile, pickle, KeyError, … all mean "unusable"
        problem = f"unreadable ({type(exc).__name__}: {exc})"
    if problem is not None:
        warnings.warn(f"the Stokes cache file {path} cannot be used ({problem}); solving the flow again and "
                      "replacing the file", StokesCacheWarning, stacklevel=3)
        return None
    return StokesFlow(
        mesh=domain.mesh, velocity_basis=velocity_basis, pressure_basis=pressure_basis,
        velocity=np.asarray(stored["velocity"], dtype=float), pressure=np.asarray(stored["pressure"], dtype=float),
        period=domain.period, viscosity=viscosity, pressure_drop=1.0, flux=float(stored["flux"]),
    )


def _write_cache(path: Path, flow: StokesFlow, key: str) -> None:
    """Write the unit flow to ``path`` atomically; a warning (never an error) when it cannot."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(handle, "wb") as file:
            np.savez(file, version=CACHE_VERSION, checksum=key, velocity=flow.velocity, pressure=flow.pressure,
                     flux=flow.flux)
            file.flush()
            os.fsync(file.fileno())
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would hide the file from a shared cache folder
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        warnings.warn(f"cannot write the Stokes cache file {path} ({exc.strerror or exc}); continuing without "
                      "caching (set FEMPHASE_CACHE to a writable folder to keep the solution)",
                      StokesCacheWarning, stacklevel=3)
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass


@FLOWS.register("stokes")
def build_stokes_flow(spec: dict, domain: Domain) -> Flow:
    """Stokes flow solved on the domain's mesh, no-slip on every wall (keys: exactly one of
    `max_velocity`, `flux`, `pressure_drop`; `viscosity`, default 1). Meshed domains only."""
    stokes_drive(spec)
    if not isinstance(domain, MeshDomain):
        raise SceneError("flow.type", "stokes", f"a flow of {FLOWS.names()} without 'stokes': a stokes flow "
                         f"needs a meshed domain ([domain] kind = \"mesh\")")
    flow = domain_stokes_flow(domain, spec)
    return Flow("stokes", lambda x, y, t: flow(x, y), stokes=flow)


_UNIT_FLOWS: "weakref.WeakKeyDictionary[MeshDomain, dict[float, StokesFlow]]" = weakref.WeakKeyDictionary()


def domain_stokes_flow(domain: MeshDomain, spec: dict) -> StokesFlow:
    """The Stokes flow of a ``{type = "stokes", …}`` table on ``domain``. Unit solutions are
    solved once per domain and viscosity and rescaled (Stokes is linear); those of meshes read
    from a file are also cached on disk, keyed by the mesh's content and the viscosity
    (:func:`cache_path`; "Cache of unit solutions" in the module docstring)."""
    _, _, viscosity = stokes_drive(spec)
    units = _UNIT_FLOWS.setdefault(domain, {})
    if viscosity not in units:
        check_open_channel(domain)  # before the solve, whose refused result would be cached
        cache = cache_path(domain, viscosity) if domain.source else None
        units[viscosity] = _open_channel(domain, unit_stokes_flow(domain, viscosity, cache))
    return stokes_flow(domain, spec, units[viscosity])


def check_open_channel(domain: MeshDomain) -> None:
    """SceneError (key ``flow.type``) when walls or obstacles close the channel from wall to
    wall, found from the mesh alone, before any solve: the channel is open when one piece of
    the mesh, its triangles joined across shared edges (not across the periodic seam),
    reaches both sides of the periodic pair. Otherwise every piece's net flux through its
    part of a side is zero, and so is the channel's: a pressure drop drives no flow."""
    mesh = domain.mesh
    pairs = mesh.f2t[:, (mesh.f2t >= 0).all(axis=0)]
    n = mesh.t.shape[1]
    graph = sp.coo_matrix((np.ones(pairs.shape[1]), (pairs[0], pairs[1])), shape=(n, n))
    _, piece = connected_components(graph, directed=False)
    low, high = (piece[mesh.f2t[0, domain.boundaries[name]]] for name in domain.periodic)
    if not np.intersect1d(low, high).size:
        raise SceneError("flow.type", "stokes", f"a flow through a channel open from side to side: walls or "
                         f"obstacles close it from wall to wall (no piece of {domain.source or 'the mesh'} reaches "
                         f"from its side {domain.periodic[0]!r} to its side {domain.periodic[1]!r}), so a pressure "
                         "drop drives no flow; a flow of another type, or none")


def _open_channel(domain: MeshDomain, unit: StokesFlow) -> StokesFlow:
    """``unit``, if a pressure drop drives a flux through the mesh; a SceneError if walls or
    obstacles close the channel (its flux is then round-off, and a flow scaled to a given
    velocity or flux would be that round-off magnified)."""
    low, high = domain.y_range
    open_flux = (high - low) ** 3 / (12 * unit.viscosity * unit.period) * unit.pressure_drop
    if not unit.flux > CLOSED_CHANNEL * open_flux:
        raise SceneError("flow.type", "stokes", f"a flow through a channel open from side to side; a pressure drop "
                         f"through {domain.source or 'the mesh'} drives a flux of {unit.flux:.3g}, "
                         f"{unit.flux / open_flux:.2g} of an open channel of its height's: walls or obstacles close it")
    return unit
