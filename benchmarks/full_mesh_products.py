"""Would the meshes' products be cheaper on the whole mesh, several windows to a vector?

    python benchmarks/full_mesh_products.py [--relax 400] [--flow 400]

A flow substep on a mesh spends most of its time in sparse products with the block-diagonal
matrix of all windows (docs/decisions/0029-mesh-solves-at-1e-3.md). The alternative: pack
windows whose dofs do not meet into one full-mesh vector (a colour), and multiply the
full-mesh matrix with all colours at once (one sparse times dense product, the matrix read
once for every colour). Fields on a colour's vector leak into their neighbours' dofs by
one graph edge per product, so windows of one colour must stay apart by as many edges as
products between two gathers (a flow substep's advection takes nine).

examples/straight_mesh.toml (N = 100, seed 1) relaxed ``--relax`` and run ``--flow`` time
units of its Stokes flow by the default scheme; at the end state's layout:

* the colours of a greedy colouring (largest window first) for windows kept 0, 1, 3 and 9
  edges apart;
* one product with the window solves' block-diagonal matrix (float32, as flow steps run:
  the stepper's own, from ``Domain.window_matrix``) against one product of the full-mesh
  system with k = 8 … 32 columns (float32; scipy, and a compiled row loop), best of
  several repeats in this process, twice.

Writes ``results/full_mesh_products.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import common  # pins BLAS threads before numpy loads
import numpy as np
import scipy.sparse as sp

RESULT = Path(__file__).parent / "results" / "full_mesh_products.json"
SEPARATIONS = (0, 1, 3, 9)
COLUMNS = (8, 16, 24, 32)


def colours(adjacency: sp.csr_matrix, window_dofs: list[np.ndarray], separation: int) -> int:
    """Colours of a greedy colouring (largest window first) of windows whose dofs, grown by
    ``separation`` graph edges, must not meet within a colour."""
    grown = []
    for dofs in window_dofs:
        mask = np.zeros(adjacency.shape[0], dtype=bool)
        mask[dofs] = True
        for _ in range(separation):
            mask = (adjacency @ mask.astype(np.int8)) > 0
        grown.append(mask)
    taken: list[np.ndarray] = []
    for mask in sorted(grown, key=lambda m: -int(m.sum())):
        for used in taken:
            if not (used & mask).any():
                used |= mask
                break
        else:
            taken.append(mask.copy())
    return len(taken)


def best_ms(product, repeats: int = 200) -> float:
    """The fastest of ``repeats`` calls of ``product`` (ms), after one warm-up call."""
    product()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        product()
        times.append(time.perf_counter() - started)
    return 1e3 * min(times)


def row_loop():
    """A compiled CSR times dense (n, k) product, the k columns of a row accumulated together."""
    import numba

    @numba.njit(fastmath=True, cache=True)
    def product(indptr, indices, data, x, out):
        rows, columns = out.shape
        for i in range(rows):
            for c in range(columns):
                out[i, c] = 0.0
            for entry in range(indptr[i], indptr[i + 1]):
                value, j = data[entry], indices[entry]
                for c in range(columns):
                    out[i, c] += value * x[j, c]
    return product


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--relax", type=float, default=400.0)
    parser.add_argument("--flow", type=float, default=400.0)
    args = parser.parse_args()

    scene = common.load_scene(common.STRAIGHT_MESH_SCENE, [f"phases.0.duration={args.relax}",
                                                           f"phases.1.duration={args.flow}", "output.fields=false"])
    state, _, _, stepper = common.run_phases(scene)
    layout, _ = state.flat()
    domain = stepper.domain
    window_dofs = [domain.window_dofs(window) for window in layout.windows]
    dt = stepper.dt / 3.0  # the default's substep under flow
    matrix = stepper.system(2.0 / dt, 0.0)[0]
    adjacency = (matrix != 0).astype(np.int8).tocsr()
    coloured = {str(s): colours(adjacency, window_dofs, s) for s in SEPARATIONS}
    print(f"{len(window_dofs)} windows, {sum(d.size for d in window_dofs)} window dofs on a mesh of "
          f"{domain.n_dofs}; colours at separations {SEPARATIONS}: {list(coloured.values())}", flush=True)

    aligned = domain.aligned(matrix).astype(np.float32)
    blocks = domain.window_matrix(layout, ("system", (2.0 / dt, 0.0), np.float32), aligned)
    full = matrix.astype(np.float32).tocsr()
    loop = row_loop()
    rng = np.random.default_rng(0)
    vector = rng.random(blocks.shape[0], dtype=np.float32)
    trials = []
    for _ in range(2):
        trial = {"windows": best_ms(lambda: blocks @ vector), "full": {}}
        for k in COLUMNS:
            x = rng.random((full.shape[0], k), dtype=np.float32)
            out = np.empty_like(x)
            trial["full"][str(k)] = {
                "scipy": best_ms(lambda: full @ x),
                "compiled": best_ms(lambda: loop(full.indptr, full.indices, full.data, x, out))}
        trials.append(trial)
        print(f"windows' block product {trial['windows']:.3f} ms; full mesh, k columns: "
              + ", ".join(f"k={k} {v['scipy']:.3f} (scipy) {v['compiled']:.3f} (compiled)"
                          for k, v in trial["full"].items()), flush=True)
    RESULT.parent.mkdir(exist_ok=True)
    RESULT.write_text(json.dumps({
        "scene": "examples/straight_mesh.toml", "relax": args.relax, "flow": args.flow,
        "windows": len(window_dofs), "window_dofs": int(sum(d.size for d in window_dofs)),
        "mesh_dofs": int(domain.n_dofs), "block_rows": int(blocks.shape[0]), "block_entries": int(blocks.nnz),
        "mesh_entries": int(full.nnz), "colours": coloured, "products_ms": trials,
        "command": "python benchmarks/full_mesh_products.py" + (
            "" if (args.relax, args.flow) == (400.0, 400.0) else f" --relax {args.relax:g} --flow {args.flow:g}")},
        indent=2) + "\n")


if __name__ == "__main__":
    main()
