"""Cached LU against AMG-preconditioned CG for the relaxation matrix: where AMG wins.

    python benchmarks/solver_crossover.py [--quick]

The matrix is the stepper's own, A = M_L/dt + J0 S M_L + D K (D = J0·2γλ = 0.12, dt = 1, the
stabilisation S = 0.17 "auto" gives at dt = 1), taken as the principal submatrix of square windows of m × m
nodes (Dirichlet on the window's edges, as every window is) and on the paper's full
70 × 240 channel at h = 1, 0.5, 0.25 (periodic in x, Neumann walls: full-mesh mode).
Right-hand sides are real relaxation steps: b = M_L φ/dt − J0 M_L g(φ) for discs of radius
R/2 (the lattice scene's initial fields on the channel), with φ itself as the warm start,
which is what the stepper passes.

Per size, in one run (ratios are meaningful on the shared machine, absolute times less so):

* direct: femphase's DirectSolver (SuperLU, COLAMD), factorised once, k = 100 right-hand
  sides in one call (the full-mesh mode's N = 100 fields);
* tensor: femphase's TensorSolver (exact; the 1D generalised eigenvectors of the window's
  tensor-product factors, verified against the assembled matrix), k right-hand sides in one
  call; what ``solver = "auto"`` uses on the structured mesh up to ny + nx = TENSOR_MAX_SIDES
  (set from this measurement: the largest size at which it was still faster than the LU);
* amg: femphase's AMGSolver (pyamg smoothed aggregation built once, CG to relative residual
  1e-10, the default numerics.tolerance), one right-hand side at a time, warm-started from
  the previous step's field (as the stepper does) and cold-started from zero.

Cost per right-hand side = solve time + set-up / (1000 steps · k): the set-up amortised
over 1000 steps. The crossover is the smallest size from which AMG (warm) is cheaper at
every larger size measured, interpolated log–log; DIRECT_MAX_DOFS is set to it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np
from common import markdown_table, update_readme

from femphase.domains.grid.domain import TENSOR_MAX_SIDES, GridDomain, tensor_solver
from femphase.model.energy import FreeEnergy, WindowedFields
from femphase.domains.grid.lattice import channel_grid
from femphase.model.parameters import ModelParameters
from femphase.fem.solvers import DIRECT_MAX_DOFS, make_solver
from femphase.config import Numerics
from femphase.timestepping.stepper import Stepper
from femphase.domains.grid.windows import Window

RESULTS = Path(__file__).parent / "results"
PARAMS = ModelParameters()
DT = 1.0
STEPS = 1000  # set-up cost amortised over this many steps
RHS = 100  # right-hand sides per direct solve (N = 100 fields)
# the explicit forces of isolated discs: the paper's terms without the repulsion (no overlap)
ISOLATED = FreeEnergy([term for term in FreeEnergy.paper(PARAMS).terms if term.name != "repulsion"])


# -- the measurement ----------------------------------------------------------------------------
def relaxation_rhs(phi: np.ndarray, domain: GridDomain, window: Window) -> np.ndarray:
    """b = M_L φ/dt − J0 M_L g(φ) for fields phi (n, k) of isolated discs (no overlap), all on
    ``window``."""
    n, k = phi.shape
    layout = domain.layout([window] * k)  # one group: the flat vector is the columns in order
    flat = phi.T.ravel()
    g = ISOLATED.explicit_derivative(WindowedFields(flat, layout, np.full(k, PARAMS.radius)))
    return (layout.mass * (flat / DT - PARAMS.mobility * g)).reshape(k, n).T.copy()


def window_problem(domain: GridDomain, system, window: Window, k: int, rng) -> tuple:
    """(matrix, rhs (n, k), warm start (n, k)) on ``window``: discs of radius R/2 at random
    centres inside the window (clipped by its edge when the window is small)."""
    nodes = domain.window_dofs(window)
    h = domain.spacing
    size_x, size_y = window.nx * h, window.ny * h
    phi = np.empty((nodes.size, k))
    for j in range(k):
        centre = (window.ix0 * h + rng.uniform(0.3, 0.7) * size_x, window.iy0 * h + rng.uniform(0.3, 0.7) * size_y)
        phi[:, j] = domain.disc_field(window, centre, 0.5 * PARAMS.radius, PARAMS.interface_width)
    matrix = system[nodes][:, nodes]
    return matrix, relaxation_rhs(phi, domain, window), phi


def block_jacobi_cg(matrix, rhs: np.ndarray, guess: np.ndarray, tol: float, maxiter: int = 500) -> tuple[np.ndarray, int]:
    """Jacobi-preconditioned CG on all columns at once (one sparse product per iteration for
    every right-hand side); stops when every column's residual is below tol·|b|.

    Not in femphase: the candidate the measurement suggests for these well-conditioned,
    mass-dominated matrices (cond(A) ≤ 1 + 8 D dt/h²). Returns (solution, iterations)."""
    diagonal = matrix.diagonal()[:, None]
    x = guess.copy()
    r = rhs - matrix @ x
    z = r / diagonal
    p = z.copy()
    rz = np.einsum("ij,ij->j", r, z)
    limit = tol * np.linalg.norm(rhs, axis=0)
    for iteration in range(maxiter):
        if np.all(np.linalg.norm(r, axis=0) <= limit):
            return x, iteration
        ap = matrix @ p
        alpha = rz / np.einsum("ij,ij->j", p, ap)
        x += alpha * p
        r -= alpha * ap
        z = r / diagonal
        rz_new = np.einsum("ij,ij->j", r, z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    return x, maxiter


def best_time(function, repeats: int) -> float:
    """Smallest CPU time of ``repeats`` calls (the least disturbed by other processes)."""
    times = []
    for _ in range(repeats):
        started = time.process_time()
        function()
        times.append(time.process_time() - started)
    return min(times)


def stepper_matrix(stepper: Stepper):
    """The stepper's full-domain matrix M_L/dt + J0 S M_L + J0 D K."""
    return stepper.system(1.0 / stepper.dt, stepper.scheme.stabilisation)[0]


def tensor_for(stepper: Stepper, matrix, window: Window):
    """The stepper's TensorSolver for ``window`` (asserting the matrix is a tensor product)."""
    a = 1.0 / stepper.dt + stepper.mobility * stepper.scheme.stabilisation
    solver = tensor_solver(matrix, window, stepper.domain.grid, a, stepper.mobility * stepper.energy.diffusivity)
    assert solver is not None, "the relaxation matrix is not a tensor product"
    return solver


def measure(label: str, matrix, rhs: np.ndarray, guess: np.ndarray, amg_columns: int, tensor) -> dict:
    n, k = rhs.shape
    repeats = 3 if n < 100_000 else 1
    started = time.process_time()
    tensor = tensor()
    tensor_setup = time.process_time() - started
    rhs = np.asfortranarray(rhs)  # the stepper's layout
    tensor_solve = best_time(lambda: tensor.solve(rhs), repeats) / k
    started = time.process_time()
    direct = make_solver(matrix, "direct")
    direct_setup = time.process_time() - started
    direct_solve = best_time(lambda: direct.solve(rhs), repeats) / k
    started = time.process_time()
    amg = make_solver(matrix, "amg", Numerics().tolerance)
    amg_setup = time.process_time() - started
    cols = slice(0, amg_columns)
    warm = best_time(lambda: amg.solve(rhs[:, cols], guess[:, cols]), repeats) / amg_columns
    cold = best_time(lambda: amg.solve(rhs[:, cols]), repeats) / amg_columns
    tol = Numerics().tolerance
    jacobi = best_time(lambda: block_jacobi_cg(matrix, rhs, guess, tol), repeats) / k
    _, iterations = block_jacobi_cg(matrix, rhs, guess, tol)
    error = np.abs(amg.solve(rhs[:, :1], guess[:, :1])[:, 0] - direct.solve(rhs[:, 0])).max()
    tensor_error = np.abs(tensor.solve(rhs[:, 0]) - direct.solve(rhs[:, 0])).max()
    fill = direct._lu.L.nnz + direct._lu.U.nnz
    del direct
    per_rhs_setup = STEPS * k
    row = {
        "case": label, "dofs": n, "rhs": k, "amg_rhs": amg_columns, "lu_fill": int(fill),
        "levels": len(amg._hierarchy.levels),
        "direct_setup_s": direct_setup, "direct_solve_ms": 1e3 * direct_solve,
        "direct_ms": 1e3 * (direct_solve + direct_setup / per_rhs_setup),
        "amg_setup_s": amg_setup, "amg_warm_solve_ms": 1e3 * warm, "amg_cold_solve_ms": 1e3 * cold,
        "amg_ms": 1e3 * (warm + amg_setup / per_rhs_setup),
        "amg_cold_ms": 1e3 * (cold + amg_setup / per_rhs_setup),
        "max_difference": float(error),
        "jacobi_cg_ms": 1e3 * jacobi, "jacobi_cg_iterations": iterations,
        "tensor_setup_s": tensor_setup, "tensor_solve_ms": 1e3 * tensor_solve,
        "tensor_ms": 1e3 * (tensor_solve + tensor_setup / per_rhs_setup), "tensor_max_difference": float(tensor_error),
        "sides": None,
    }
    row["amg_over_direct"] = row["amg_ms"] / row["direct_ms"]
    row["direct_over_tensor"] = row["direct_ms"] / row["tensor_ms"]
    print(f"{label:<22} n={n:>7} LU {row['direct_ms']:8.3f} ms/rhs (setup {direct_setup:6.2f} s)  "
          f"AMG warm {row['amg_ms']:8.3f} cold {row['amg_cold_ms']:8.3f} ms/rhs (setup {amg_setup:6.2f} s)  "
          f"ratio {row['amg_over_direct']:.2f}  tensor {row['tensor_ms']:8.3f} (LU/tensor {row['direct_over_tensor']:.2f})  block Jacobi-CG {row['jacobi_cg_ms']:8.3f} ({iterations} it)", flush=True)
    return row


def square_windows(sizes: list[int]) -> list[dict]:
    """Interior m × m windows of one large mesh at h = 1 (every window's submatrix has the
    same entries, so one assembly serves all sizes)."""
    side = max(sizes) + 4
    domain = GridDomain(channel_grid(float(side), float(side), 1.0))
    stepper = Stepper(domain, PARAMS, Numerics(), DT)
    system = stepper_matrix(stepper)
    rng = np.random.default_rng(0)
    rows = []
    for m in sizes:
        k = RHS
        window = Window(2, m, 2, m)
        matrix, rhs, guess = window_problem(domain, system, window, k, rng)
        rows.append(measure(f"window {m}×{m}", matrix, rhs, guess, amg_columns=k if m * m < 40_000 else 10,
                            tensor=lambda: tensor_for(stepper, matrix, window)))
        rows[-1]["sides"] = 2 * m
    return rows


def channels(spacings: list[float]) -> list[dict]:
    """The paper's 70 × 240 channel, full mesh, the lattice scene's 100 initial discs."""
    rows = []
    for h in spacings:
        scene = common.lattice_scene(h=h, windows=False)
        domain = scene.domain
        stepper = Stepper(domain, scene.model, scene.numerics, DT)
        system = stepper_matrix(stepper)
        state = scene.initial_state()
        phi = state.global_fields().T.copy()
        window = domain.full_window()
        assert state.windows[0] == window
        rhs = relaxation_rhs(phi, domain, window)
        rows.append(measure(f"channel h = {h:g}", system, rhs, phi, amg_columns=10,
                            tensor=lambda: tensor_for(stepper, system, window)))
        rows[-1]["sides"] = window.nx + window.ny
    return rows


def crossover(rows: list[dict]) -> float | None:
    """Dofs (interpolated log–log on amg/direct) from which AMG is cheaper at every larger
    size; None if it never is."""
    rows = sorted(rows, key=lambda r: r["dofs"])
    n = np.array([r["dofs"] for r in rows], dtype=float)
    ratio = np.array([r["amg_over_direct"] for r in rows])
    if ratio[-1] >= 1:
        return None
    above = np.flatnonzero(ratio >= 1)
    if not above.size:
        return float(n[0])
    i = above[-1]
    x0, x1, y0, y1 = np.log(n[i]), np.log(n[i + 1]), np.log(ratio[i]), np.log(ratio[i + 1])
    return float(np.exp(x0 + (0.0 - y0) * (x1 - x0) / (y1 - y0)))


def report(result: dict) -> str:
    rows = [[r["case"], f"{r['dofs']:,}", f"{r['lu_fill'] / r['dofs']:.0f}", f"{r['direct_setup_s']:.2f}",
             f"{r['direct_solve_ms']:.3g}", f"{r['amg_setup_s']:.2f}", f"{r['amg_warm_solve_ms']:.3g}",
             f"{r['amg_cold_solve_ms']:.3g}", f"{r['amg_over_direct']:.2f}",
             f"{r['jacobi_cg_ms']:.3g} ({r['jacobi_cg_iterations']})", f"{r['tensor_setup_s']:.2f}",
             f"{r['tensor_solve_ms']:.3g}", f"{r['direct_over_tensor']:.2f}"]
            for r in result["windows"] + result["channels"]]
    table = markdown_table(
        ["case", "dofs", "LU fill / dof", "LU set-up s", "LU ms/rhs (k = 100)", "AMG set-up s",
         "AMG+CG warm ms/rhs", "AMG+CG cold ms/rhs", "AMG warm / LU (set-up / 1000 steps)",
         "block Jacobi-CG ms/rhs (iterations), not in femphase", "tensor set-up s", "tensor ms/rhs",
         "LU / tensor"], rows)
    cross = result["crossover_dofs"]
    verdict = (f"AMG (warm-started, set-up amortised over {STEPS} steps) becomes cheaper than the cached LU at "
               f"**≈ {cross:,.0f} dofs** (square windows); set `DIRECT_MAX_DOFS = {result['recommended']:_}` "
               f"(currently {result['current']:_})." if cross else
               f"AMG never became cheaper than the cached LU up to {max(r['dofs'] for r in result['windows']):,} dofs "
               f"(AMG/LU ≥ {min(r['amg_over_direct'] for r in result['windows']):.1f} at every size, flattening at the "
               f"largest): set `DIRECT_MAX_DOFS = {result['recommended']:_}` (currently {result['current']:_}), the "
               f"largest size measured. Beyond it the LU's memory, not its speed, is the limit: "
               f"{result['windows'][-1]['lu_fill'] / result['windows'][-1]['dofs']:.0f} stored factor entries per dof "
               f"(~{12 * result['windows'][-1]['lu_fill'] / 2**20:.0f} MB at {result['windows'][-1]['dofs']:,} dofs).")
    rows = result["windows"] + result["channels"]
    faster = [r for r in rows if r["direct_over_tensor"] > 1]
    tensor = (f"The tensor solver (exact, structured mesh with one diagonal direction and the lumped mass) beat the "
              f"cached LU in {len(faster)} of {len(rows)} cases (LU/tensor {min(r['direct_over_tensor'] for r in rows):.2f}–"
              f"{max(r['direct_over_tensor'] for r in rows):.2f}; largest difference from the LU "
              f"{max(r['tensor_max_difference'] for r in rows):.1e}); `solver = \"auto\"` uses it up to "
              f"ny + nx = {TENSOR_MAX_SIDES} nodes. LU/tensor where ny + nx ≤ {TENSOR_MAX_SIDES}: "
              + ", ".join(f"{r['case']} {r['direct_over_tensor']:.1f}" for r in rows if r["sides"] <= TENSOR_MAX_SIDES))
    beyond = [f"{r['case']} {r['direct_over_tensor']:.1f}" for r in rows if r["sides"] > TENSOR_MAX_SIDES]
    tensor += ("; beyond (LU or AMG used): " + ", ".join(beyond) if beyond else "") + "."
    return f"{table}\n\n{verdict}\n\n{tensor}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="windows up to 128² and the h = 1 channel only")
    parser.add_argument("--report", action="store_true", help="only rewrite the README section from the JSON")
    args = parser.parse_args()
    if args.report:
        update_readme("solver_crossover", report(json.loads((RESULTS / "solver_crossover.json").read_text())))
        return
    sizes = [10, 16, 24, 32, 48, 64, 96, 128] + ([] if args.quick else [192, 256, 384, 512, 600])
    started = time.process_time()
    result = {"dt": DT, "diffusivity": PARAMS.diffusivity, "steps_amortised": STEPS,
              "tolerance": Numerics().tolerance, "current": DIRECT_MAX_DOFS}
    result["windows"] = square_windows(sizes)
    result["channels"] = channels([1.0] if args.quick else [1.0, 0.5, 0.25])
    cross = crossover(result["windows"])
    result["crossover_dofs"] = cross
    # rounded down to two significant figures: below the crossover LU is the faster choice
    largest = max(r["dofs"] for r in result["windows"])
    value = cross if cross is not None else largest
    magnitude = 10 ** (np.floor(np.log10(value)) - 1)
    result["recommended"] = int(value // magnitude * magnitude)
    result["cpu_seconds"] = time.process_time() - started
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "solver_crossover.json").write_text(json.dumps(result, indent=1) + "\n")
    markdown = report(result)
    print(markdown)
    if not args.quick:
        update_readme("solver_crossover", markdown)
    print(f"{result['cpu_seconds'] / 60:.1f} CPU-min")


if __name__ == "__main__":
    main()
