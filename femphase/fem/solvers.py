"""Linear solvers built once and reused, pyamg style.

Every window's system matrix is symmetric positive definite (the advection is split off,
see :mod:`femphase.domains.advection`), so the iterative path is pyamg smoothed-aggregation AMG as
a preconditioner of CG (GMRES for a non-symmetric matrix). For small, mass-dominated systems
the per-call overhead of the Krylov loop dominates and a cached sparse LU factorisation
solves all right-hand sides of a group in one call; ``method="auto"`` picks LU up to
``DIRECT_MAX_DOFS`` unknowns (measured by ``benchmarks/solver_crossover.py``: the crossover
lies beyond every size measured, so the bound is set by memory).

On the structured mesh with one diagonal direction and the lumped mass, a window's matrix is
a tensor product, A = a My⊗Mx + b (Ky⊗Mx + My⊗Kx), of 1D P1 lumped masses M and stiffnesses
K (see :func:`femphase.fem.operators.line_operators`). :class:`TensorSolver` then solves
exactly with the 1D generalised eigenvectors: four dense matrix products per batch of
right-hand sides, 1.5–3.7× faster than the LU's triangular solves up to 256 × 256 nodes and
no faster beyond (``benchmarks/solver_crossover.py``). The stepper uses it there
(``femphase.domains.grid.domain.TENSOR_MAX_SIDES``) when it has verified the tensor form against the
assembled matrix.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import pyamg
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from femphase.config import SOLVER_METHODS
from femphase.errors import SceneError

__all__ = ["DIRECT_MAX_DOFS", "AMGSolver", "DirectSolver", "TensorBasis", "TensorSolver", "make_solver"]

#: Largest system solved by LU under method="auto". benchmarks/solver_crossover.py found the
#: cached LU faster than pyamg + CG per right-hand side at every size measured, 10² to 360,000
#: dofs (at least 4.6×, set-up amortised over 1000 steps), so the limit is the LU's memory
#: (~120 factor entries per dof, ~0.5 GB at 360,000 dofs), not its speed.
DIRECT_MAX_DOFS = 360_000


class DirectSolver:
    """Sparse LU (SuperLU) of a fixed matrix; solves many right-hand sides in one call."""

    name = "direct"

    def __init__(self, matrix: sp.spmatrix) -> None:
        self.n = matrix.shape[0]
        self._lu = spla.splu(sp.csc_matrix(matrix))
        self._entry_bytes = np.dtype(matrix.dtype).itemsize + 4  # a value and its row index

    @property
    def nbytes(self) -> int:
        """The LU factors' entries and row indices (bytes); SuperLU's own storage makes the
        resident memory 1–5× that (measured: ~2 MB per ~1000-dof window of a mesh)."""
        return self._entry_bytes * int(self._lu.nnz)

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

    @property
    def nbytes(self) -> int:
        """The hierarchy's operators (entries and indices, bytes)."""
        matrices = [getattr(level, name) for level in self._hierarchy.levels for name in ("A", "P", "R")
                    if hasattr(level, name)]
        return int(sum(m.data.nbytes + m.indices.nbytes + m.indptr.nbytes for m in matrices))

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


class TensorBasis:
    """The 1D generalised eigenpairs K V = M V Λ, Vᵀ M V = I, of a window's two directions:
    everything of :class:`TensorSolver` that does not depend on a and b, so a window shape
    computes it once and every time step size reuses it (:meth:`solver`)."""

    def __init__(self, y: tuple[np.ndarray, np.ndarray], x: tuple[np.ndarray, np.ndarray]) -> None:
        (mass_y, stiffness_y), (mass_x, stiffness_x) = y, x
        self.lam_y, self.vy = scipy.linalg.eigh(stiffness_y, mass_y)
        self.lam_x, self.vx = scipy.linalg.eigh(stiffness_x, mass_x)
        # contiguous transposes: a transposed view as a product's operand costs ~50 % more
        self.vy_t, self.vx_t = np.ascontiguousarray(self.vy.T), np.ascontiguousarray(self.vx.T)

    @property
    def nbytes(self) -> int:
        """Bytes of its eigenpairs (and their single-precision copies, once made)."""
        arrays = [self.lam_y, self.lam_x, self.vy, self.vx, self.vy_t, self.vx_t, *self.__dict__.get("single", ())]
        return sum(int(a.nbytes) for a in arrays)

    @cached_property
    def single(self) -> tuple[np.ndarray, ...]:
        """(vy, vx, vyᵀ, vxᵀ) in single precision, made on first use."""
        return tuple(np.ascontiguousarray(v, dtype=np.float32) for v in (self.vy, self.vx, self.vy_t, self.vx_t))

    def solver(self, a: float, b: float) -> "TensorSolver":
        return TensorSolver(a, b, self)


class TensorSolver:
    """Exact solver of A = a My⊗Mx + b (Ky⊗Mx + My⊗Kx) on an ny × nx node block (x fastest).

    My, Mx are 1D masses (symmetric positive definite, usually diagonal), Ky, Kx symmetric
    positive semi-definite 1D stiffnesses, a > 0, b ≥ 0. With the generalised eigenpairs
    of ``basis`` (:class:`TensorBasis`), A⁻¹ = (Vy⊗Vx) diag(1/(a + b(λy + λx))) (Vy⊗Vx)ᵀ.

    It computes in the right-hand side's precision: a float32 right-hand side (the stepper's
    working copy under ``numerics.precision = "mixed"``) gets float32 products, 2× faster
    (docs/decisions/0012-single-precision-flow-steps.md), and a solution with relative error ~1e-6 instead
    of ~1e-15.
    """

    name = "tensor"

    #: Bytes of right-hand sides transformed at once: the four products and their
    #: temporaries then stay in the core's L2 cache (1 MiB here). Measured on this machine,
    #: 36 × 36 windows: 9.5 µs a window in chunks, 18–20 µs in one stack of 100 windows.
    CHUNK_BYTES = 2**18

    def __init__(self, a: float, b: float, basis: TensorBasis) -> None:
        self._basis = basis
        self.shape = (basis.lam_y.size, basis.lam_x.size)
        self.n = self.shape[0] * self.shape[1]
        self._inverse = 1.0 / (a + b * (basis.lam_y[:, None] + basis.lam_x[None, :]))
        # as many windows a chunk in single precision: twice as many ran 3× slower here
        self._chunk = max(1, self.CHUNK_BYTES // (8 * self.n))

    @cached_property
    def _single_inverse(self) -> np.ndarray:
        return self._inverse.astype(np.float32)

    @property
    def nbytes(self) -> int:
        """Its own array (bytes); the eigenvectors are the window shape's, shared."""
        return int(self._inverse.nbytes)

    def solve(self, rhs: np.ndarray, guess: np.ndarray | None = None) -> np.ndarray:
        """Solve A X = rhs for rhs (n,) or (n, k); ``guess`` is ignored."""
        ny, nx = self.shape
        # (k, ny, nx) with x fastest: a free view of the stepper's Fortran-ordered (n, k)
        block = rhs.T.reshape(-1, ny, nx)
        out = np.empty_like(block)
        basis = self._basis
        if block.dtype == np.float32:
            (vy, vx, vy_t, vx_t), inverse = basis.single, self._single_inverse
        else:
            (vy, vx, vy_t, vx_t), inverse = (basis.vy, basis.vx, basis.vy_t, basis.vx_t), self._inverse
        for start in range(0, block.shape[0], self._chunk):
            chunk = slice(start, start + self._chunk)
            spectral = np.matmul(vy_t, block[chunk] @ vx)
            spectral *= inverse
            np.matmul(np.matmul(vy, spectral), vx_t, out=out[chunk])
        return out.reshape(-1, self.n).T.reshape(rhs.shape)


def make_solver(matrix: sp.spmatrix, method: str = "auto", tol: float = 1e-10) -> DirectSolver | AMGSolver:
    """A solver for ``matrix``: "direct" (LU), "amg" (pyamg + Krylov) or "auto" (LU up to
    DIRECT_MAX_DOFS). "tensor" needs the matrix's factors: build a :class:`TensorSolver`."""
    if method not in SOLVER_METHODS:
        raise SceneError("numerics.solver", method, f"one of {SOLVER_METHODS}")
    if method == "tensor":
        raise SceneError("numerics.solver", method,
                         '"auto", "direct" or "amg" here: this matrix has no tensor-product form '
                         "(the tensor solver needs the structured mesh with right or left diagonals "
                         "and the lumped mass)")
    if method == "batched":
        raise SceneError("numerics.solver", method, '"auto", "direct" or "amg" for one matrix: "batched" solves '
                         "all windows at once (femphase.fem.blocks), not a matrix of its own")
    if method == "auto":
        method = "direct" if matrix.shape[0] <= DIRECT_MAX_DOFS else "amg"
    return DirectSolver(matrix) if method == "direct" else AMGSolver(matrix, tol)
