"""Write the default structured channel mesh: python meshes/make_channel.py [Lx Ly h]

The paper's channel, 70 × 240 lattice units at spacing h = 1, as a non-periodic P1 mesh
(the x = Lx column duplicates x = 0; femphase identifies the two when it loads the mesh).
"""

import sys
from pathlib import Path

from femphase.domains.grid.lattice import channel_grid, structured_channel_mesh
from femphase.fem.meshfiles import save_mesh

length, width, spacing = (float(v) for v in (sys.argv[1:4] if len(sys.argv) > 3 else (70, 240, 1)))
path = Path(__file__).parent / f"channel_{length:g}x{width:g}_h{spacing:g}.vtu"
save_mesh(structured_channel_mesh(channel_grid(length, width, spacing)), path)
print(path)
