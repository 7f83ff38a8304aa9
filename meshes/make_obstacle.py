"""Write a channel with a circular obstacle: python meshes/make_obstacle.py

The paper's 70 × 240 channel with a disc of radius 16 (two particle radii) at its centre
(35, 120): the flow runs along x, so the particles go around the obstacle, through the two
gaps of 104 between it and the walls; along x the periodic images of the obstacle stand 38
apart, where the flow nearly stops (speed 0.0034 at (0, 120) against 0.1 at most).
Delaunay mesh at one node per unit area (h = 1); boundaries left, right, bottom, top and
obstacle (tag 5), written as .vtu.
"""

from pathlib import Path

from femphase.domains.mesh.domain import write_domain
from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing, mesh_quality

LENGTH, HEIGHT, SPACING = 70.0, 240.0, 1.0
OBSTACLE = (35.0, 120.0, 16.0)  # centre x, centre y, radius

if __name__ == "__main__":
    mesh, boundaries = delaunay_channel(LENGTH, edge_for_spacing(SPACING), lambda x: 0 * x,
                                        lambda x: 0 * x + HEIGHT, obstacles=[OBSTACLE], seed=3)
    path = Path(__file__).parent / "obstacle.vtu"
    write_domain(path, mesh, boundaries)
    print(path, {k: round(v, 3) for k, v in mesh_quality(mesh).items()})
