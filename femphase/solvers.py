"""Linear solvers built once and reused, pyamg style.

Every window's system matrix is symmetric positive definite (the advection is split off,
see :mod:`femphase.advection`), so the iterative path is pyamg smoothed-aggregation AMG as
a preconditioner of CG (GMRES for a non-symmetric matrix). For small, mass-dominated systems
the per-call overhead of the Krylov loop dominates and a cached sparse LU factorisation
solves all right-hand sides of a group in one call; ``method="auto"`` picks LU up to
``DIRECT_MAX_DOFS`` unknowns (measured by ``benchmarks/solver_crossover.py``: the crossover
lies beyond every size measured, so the bound is set by memory).
"""

from __future__ import annotations

import numpy as np
import pyamg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import SceneError

#: Largest system solved by LU under method="auto". benchmarks/solver_crossover.py found the
#: cached LU faster than pyamg + CG per right-hand side at every size measured, 10² to 360,000
#: dofs (at least 4.6×, set-up amortised over 1000 steps), so the limit is the LU's memory
#: (~120 factor entries per dof, ~0.5 GB at 360,000 dofs), not its speed.
DIRECT_MAX_DOFS = 360_000

SOLVER_METHODS = ("auto", "direct", "amg")


class DirectSolver:
    """Sparse LU (SuperLU) of a fixed matrix; solves many right-hand sides in one call."""

    name = "direct"

    def __init__(self, matrix: sp.spmatrix) -> None:
        self.n = matrix.shape[0]
        self._lu = spla.splu(sp.csc_matrix(matrix))

    def solve(self, rhs: np.ndarray, guess: np.ndarray | None = None) -> np.ndarray:
        """Solve A X = rhs for rhs (n,) or (n, k); ``guess`` is ignored."""
        return self._lu.solve(rhs)


class AMGSolver:
    """pyamg smoothed-aggregation hierarchy, built once, accelerating CG (or GMRES)."""

    name = "amg"

    def __init__(self, matrix: sp.spmatrix, tol: float = 1e-10) -> None:
        matrix = sp.csr_matrix(matrix)
        self.n = matrix.shape[0]
        self.tol = tol
        symmetric = abs(matrix - matrix.T).max() <= 1e-12 * abs(matrix).max()
        self.accel = "cg" if symmetric else "gmres"
        self._hierarchy = pyamg.smoothed_aggregation_solver(
            matrix, symmetry="symmetric" if symmetric else "nonsymmetric"
        )

    def solve(self, rhs: np.ndarray, guess: np.ndarray | None = None) -> np.ndarray:
        """Solve column by column to relative residual ``tol``, warm-started from ``guess``."""
        columns = rhs.reshape(self.n, -1)
        start = np.zeros_like(columns) if guess is None else guess.reshape(self.n, -1)
        out = np.empty_like(columns)
        for j in range(columns.shape[1]):
            out[:, j] = self._hierarchy.solve(
                columns[:, j], x0=start[:, j], tol=self.tol, accel=self.accel, maxiter=200
            )
        return out.reshape(rhs.shape)


def make_solver(matrix: sp.spmatrix, method: str = "auto", tol: float = 1e-10):
    """A solver for ``matrix``: "direct" (LU), "amg" (pyamg + Krylov) or "auto"."""
    if method not in SOLVER_METHODS:
        raise SceneError("numerics.solver", method, f"one of {SOLVER_METHODS}")
    if method == "auto":
        method = "direct" if matrix.shape[0] <= DIRECT_MAX_DOFS else "amg"
    return DirectSolver(matrix) if method == "direct" else AMGSolver(matrix, tol)
