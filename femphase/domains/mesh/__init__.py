"""Meshed channels, ``[domain] kind = "mesh"``: any triangle mesh meshio reads, periodic in x,
with named boundaries.

=============== ========================================================================
``domain``      :class:`~femphase.domains.mesh.domain.MeshDomain`, registered as "mesh";
                reading and writing meshed channels with named boundaries
``shapes``      windows shaped to their particles and their policy (with the batched solves)
``boxes``       box windows and their policy (with per-window solvers)
``advection``   the Galerkin advection: explicit Runge–Kutta, or Padé with per-window solvers
``stokes``      Stokes flow on the mesh, registered as the flow "stokes"
``generation``  channel meshes in pure Python (Delaunay), for tests and examples
``kernels``     compiled loops for the refits (numba, imported on first use)
=============== ========================================================================
"""

from femphase.domains.mesh import stokes  # noqa: F401  (registers the flow "stokes")
from femphase.domains.mesh.domain import MeshDomain

__all__ = ["MeshDomain"]
