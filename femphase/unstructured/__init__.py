"""Phase fields on any triangular mesh: channels with constrictions, obstacles, curved walls.

A user draws a channel in any mesher, saves it in a format meshio reads with named boundary
tags, and runs the paper's suspension through it:

* :mod:`.domain`     reading meshes, boundary names, periodic identification (MeshDomain)
* :mod:`.meshing`    pure-Python channel meshes (Delaunay of point sets) for ``meshes/``
* :mod:`.transport`  the Stokes flow of a scene, the skew-symmetric advection matrix
* :mod:`.windows`    windows as dof subsets inside boxes that follow the particles
* :mod:`.state`      MeshState, initial discs, checkpoints
* :mod:`.stepping`   UnstructuredStepper: Crank–Nicolson Galerkin advection + the core's
                     semi-implicit relaxation, per-window cached solvers
* :mod:`.shape`      shape observables (centroid, area, elongation, orientation)
* :mod:`.scene`      mesh scenes (``[domain] kind = "mesh"``), UnstructuredSimulation, runs

The file conventions and the decisions are in ``verification/MESHES.md``.
"""

from .domain import BOUNDARY_TAGS, MeshDomain, read_domain, write_domain
from .scene import MeshScene, UnstructuredSimulation, load_mesh_scene, mesh_scene_from_dict, run_mesh_scene
from .shape import mesh_shape_observables
from .state import MeshState, load_mesh_checkpoint, mesh_discs_state, save_mesh_checkpoint
from .stepping import UnstructuredStepper
from .transport import advection_matrix, nodal_velocity, stokes_flow, unit_stokes_flow
from .windows import Box, MeshWindowPolicy

__all__ = [
    "BOUNDARY_TAGS", "Box", "MeshDomain", "MeshScene", "MeshState", "MeshWindowPolicy",
    "UnstructuredSimulation", "UnstructuredStepper", "advection_matrix", "load_mesh_checkpoint",
    "load_mesh_scene", "mesh_discs_state", "mesh_scene_from_dict", "mesh_shape_observables",
    "nodal_velocity", "read_domain", "run_mesh_scene", "save_mesh_checkpoint", "stokes_flow",
    "unit_stokes_flow", "write_domain",
]
