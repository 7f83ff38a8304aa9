"""Write the straight channel, structured and unstructured: python meshes/make_straight.py

The paper's channel, 70 × 240 lattice units, one node per unit area (h = 1):

* straight_structured.vtu    femphase's structured mesh (right diagonals), tagged boundaries;
* straight_unstructured.vtu  a Delaunay mesh of a rotated, jittered hexagonal lattice
                             (femphase.domains.mesh.generation.delaunay_channel);
* straight_unstructured_h065.vtu  the same at h = 0.65 (39 772 dofs), for refining the
                             mesh path (verification/sweeps/poiseuille_mesh_rate1.toml).

Boundaries are line cells with cell data "boundary" = femphase.domains.mesh.domain.BOUNDARY_TAGS
(left 1, right 2, bottom 3, top 4); ``right`` is ``left`` moved by 70 in x (periodic pair).
"""

from pathlib import Path

from femphase.domains.mesh.domain import write_domain
from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing, mesh_quality, structured_channel

LENGTH, HEIGHT, SPACING = 70.0, 240.0, 1.0
HERE = Path(__file__).parent

if __name__ == "__main__":
    for name, (mesh, boundaries) in {
        "straight_structured.vtu": structured_channel(LENGTH, HEIGHT, SPACING),
        "straight_unstructured.vtu": delaunay_channel(
            LENGTH, edge_for_spacing(SPACING), lambda x: 0 * x, lambda x: 0 * x + HEIGHT, seed=1),
        "straight_unstructured_h065.vtu": delaunay_channel(
            LENGTH, edge_for_spacing(0.65), lambda x: 0 * x, lambda x: 0 * x + HEIGHT, seed=1),
    }.items():
        write_domain(HERE / name, mesh, boundaries)
        print(HERE / name, {k: round(v, 3) for k, v in mesh_quality(mesh).items()})
