"""Write a channel with a smooth constriction: python meshes/make_constriction.py

The paper's 70 × 240 channel whose walls bulge inwards by a cosine bump centred at x = 35,

    bottom(x) = A (1 + cos(2π (x − 35)/70)) / 2,   top(x) = 240 − bottom(x),   A = 48,

so the channel narrows from 240 (at the periodic sides) to 144 at its throat; the walls are
smooth across the periodic seam. Delaunay mesh at one node per unit area (h = 1), written as a
gmsh 2.2 file with physical names (left, right, bottom, top) to exercise the .msh reader.
"""

from pathlib import Path

import numpy as np

from femphase.domains.mesh.domain import write_domain
from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing, mesh_quality

LENGTH, HEIGHT, DEPTH, SPACING = 70.0, 240.0, 48.0, 1.0


def bottom(x):
    return DEPTH * (1 + np.cos(2 * np.pi * (x - 0.5 * LENGTH) / LENGTH)) / 2


def top(x):
    return HEIGHT - bottom(x)


if __name__ == "__main__":
    mesh, boundaries = delaunay_channel(LENGTH, edge_for_spacing(SPACING), bottom, top, seed=2)
    path = Path(__file__).parent / "constriction.msh"
    write_domain(path, mesh, boundaries)
    print(path, {k: round(v, 3) for k, v in mesh_quality(mesh).items()})
