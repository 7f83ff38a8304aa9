"""Every window's principal submatrix as one block-diagonal matrix, and Krylov solves on it.

A field lives on a window, a set of dofs, and its linear systems are the principal
submatrices of full-domain matrices on those dofs. On a structured channel windows share
shapes and a tensor solver; on a mesh every window (box) is its own submatrix. There,
instead of one factorisation per window, all windows are solved at once: their blocks form
one block-diagonal matrix over the concatenated vector of all windows ("layout order"),
and one compiled pass runs a preconditioned CG on each block in turn, nothing per window
in Python.

Why this fits: the window systems c·M + J0·D·K are mass-dominated, with condition number
≈ 1 + dt·J0·D·λmax(K)/m, a few units at the adaptive scheme's substeps, so Jacobi-
preconditioned CG converges in tens of iterations. The meshes' explicit advection applies
block-diagonal matrices of the same kind and solves nothing. Memory is the blocks' entries
(about 7 per position for P1), against ~100 per position for a sparse LU.

:class:`BlockPattern` maps a full-domain sparsity pattern onto all windows of a layout at
once, and :meth:`BlockPattern.block` then takes any matrix with that pattern
(:func:`aligned_data`) to its block-diagonal form by one gather.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from femphase.errors import FemphaseError

__all__ = ["RESIDUAL_REDUCTION", "BlockPattern", "KrylovError", "aligned_data", "conjugate_gradient",
           "pattern_entries", "unsigned"]


class KrylovError(FemphaseError, ArithmeticError):
    """A batched Krylov solve did not reach its tolerance."""


def pattern_entries(pattern: sp.csr_matrix, rows: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each (row, column) pair is stored among the entries of ``pattern`` (canonical
    CSR), and whether it is stored there at all (where not, the place is meaningless)."""
    n = pattern.shape[1]
    keys = np.repeat(np.arange(pattern.shape[0], dtype=np.int64), np.diff(pattern.indptr)) * n + pattern.indices
    wanted = np.asarray(rows, dtype=np.int64) * n + columns
    found = np.searchsorted(keys, wanted)
    return found, (found < keys.size) & (keys[np.minimum(found, keys.size - 1)] == wanted)


def aligned_data(matrix: sp.spmatrix, pattern: sp.csr_matrix) -> np.ndarray:
    """``matrix``'s entries at the stored entries of ``pattern`` (canonical CSR), zeros where
    ``matrix`` has none; raises ValueError if ``matrix`` has an entry outside the pattern."""
    matrix = sp.csr_matrix(matrix)
    if (matrix.shape == pattern.shape and np.array_equal(matrix.indptr, pattern.indptr)
            and np.array_equal(matrix.indices, pattern.indices)):  # built on the pattern: aligned as stored
        return np.array(matrix.data, dtype=np.result_type(matrix.dtype, np.float64))
    matrix.sum_duplicates()
    coo = matrix.tocoo()
    found, inside = pattern_entries(pattern, coo.row, coo.col)
    if not np.all(inside | (coo.data == 0)):
        raise ValueError("the matrix has entries outside the block pattern")
    data = np.zeros(pattern.nnz, dtype=np.result_type(matrix.dtype, np.float64))
    data[found[inside]] = coo.data[inside]
    return data


class BlockPattern:
    """The block-diagonal matrix of every window's principal submatrix of one full-domain
    pattern (canonical CSR), over the concatenated vector of all windows: window w holds
    positions ``offsets[w]:offsets[w + 1]``, position p the dof ``node_index[p]`` (a
    :class:`~femphase.domains.layout.Layout`'s). Entry (p, q) is the pattern's
    (node_index[p], node_index[q]) for p and q in one window; each row's columns ascend, so
    products sum in a fixed order whatever order windows number their dofs in.

    Built in one compiled pass over the windows' rows (:func:`femphase.fem.kernels.principal_blocks`),
    with ``source``, the place of every entry among the pattern's stored entries:
    :meth:`block` then takes any matrix with that pattern (:func:`aligned_data`) to its
    block-diagonal form by one gather. (Built from per-window maps concatenated per layout,
    the maps, their concatenation and its temporaries were 1.4 s of 13.7 s of stepping over
    710 time units of flow on examples/straight_mesh.toml.)"""

    def __init__(self, pattern: sp.csr_matrix, node_index: np.ndarray, offsets: np.ndarray) -> None:
        from femphase.fem import kernels  # numba loads only where windows are solved at once

        slot = np.full(pattern.shape[0], -1, dtype=np.int64)
        node_index, offsets = np.asarray(node_index, dtype=np.int64), np.asarray(offsets, dtype=np.int64)
        bound = int(np.diff(pattern.indptr)[node_index].sum())  # the positions' whole rows
        size = node_index.size
        self.shape = (size, size)
        # scipy stores CSR indices as int32 where they fit and converts (copies) any other
        # kind at every construction, i.e. at every :meth:`block`
        index = np.int32 if max(size, bound) < np.iinfo(np.int32).max else np.int64
        # the sources unsigned and as narrow as the pattern allows: gathered by a compiled
        # loop at every block (:func:`femphase.fem.kernels.gather`), and kept per layout
        source_type = np.uint32 if pattern.nnz < np.iinfo(np.uint32).max else np.uint64
        indices, source = np.empty(bound, dtype=index), np.empty(bound, dtype=source_type)
        indptr = kernels.principal_blocks(pattern.indptr, pattern.indices, node_index, offsets, slot, indices, source)
        # the entries as prefixes of the bound's arrays (3.7 % longer on examples/straight_mesh.toml),
        # not copied: views cost nothing, and nbytes counts the arrays whole
        self.indices, self.source = indices[:indptr[-1]], source[:indptr[-1]]
        self.indptr = indptr.astype(index)

    @property
    def nbytes(self) -> int:
        return int(self.source.base.nbytes + self.indices.base.nbytes + self.indptr.nbytes)

    def block(self, data: np.ndarray) -> sp.csr_matrix:
        """The block-diagonal matrix whose entries come from ``data``, the full-domain
        matrix's entries aligned to the pattern (:func:`aligned_data`)."""
        from femphase.fem import kernels  # numba loads only where windows are solved at once

        entries = np.empty(self.source.size, dtype=data.dtype)
        kernels.gather(np.ascontiguousarray(data), self.source, entries)
        return sp.csr_matrix((entries, self.indices, self.indptr), shape=self.shape)


#: The least factor by which :func:`conjugate_gradient` reduces its starting residual. The
#: relative goal alone, tolerance × max|D⁻¹ rhs|, is a bound in φ, and a mass-dominated
#: system's rhs scales with 1/dt while a step's change scales with dt: on a mesh in an
#: oscillating shear (examples/straight_mesh.toml, N = 1, phase dt 0.5) substeps of 0.005
#: started inside the goal, so every solve returned its start, the relaxation stood still,
#: the estimate read 0, and the run took 15869 substeps in 100 time units and ended 21 % off in
#: elongation. With a tenfold reduction the same time unit takes 65 substeps and lies 2.9e-5
#: from solves to 1e-10 (3.4e-3 without); at the default substeps (3.33 under flow) the goal is
#: the smaller of the two, and examples/straight_mesh.toml's relaxation 400 + Stokes flow 400
#: takes the same iterations (5926 + 1069) to the same bits.
RESIDUAL_REDUCTION = 0.1


def conjugate_gradient(matrix: sp.csr_matrix, offsets: np.ndarray, inverse_diagonal: np.ndarray, rhs: np.ndarray,
                       guess: np.ndarray, tolerance: float, maxiter: int = 1000,
                       guess_product: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve A x = rhs for a real symmetric positive definite, block-diagonal A (block w the
    rows and columns ``offsets[w]:offsets[w + 1]``, no entry outside the blocks; offsets
    [0, n] for any one matrix) by CG with the Jacobi preconditioner, ``inverse_diagonal`` =
    D⁻¹ = 1/diag A (a caller that solves with one A many times keeps it), from ``guess``
    (``guess_product``: A·guess, where the caller knows it without a product).

    The goal is one bound for the whole vector: the preconditioned residual's max-norm,
    max|D⁻¹ r|, at most ``tolerance`` times max|D⁻¹ rhs| and at most
    :data:`RESIDUAL_REDUCTION` times its value at the start (for a mass-dominated A, D⁻¹r
    is the solution's error up to the condition number, in the solution's units). Each
    block runs its own CG to that goal, in one compiled pass over the blocks
    (:func:`femphase.fem.kernels.window_conjugate_gradient`): its own Krylov space and its own
    stop, where one CG on the whole vector iterated every block until the slowest one's
    residual was in. On examples/straight_mesh.toml's windows under flow that takes 3.1
    instead of 4.2 products of the whole vector a solve, to the same goal.
    Returns (x, iterations of each block, r), r the final residual rhs − A x as CG updated
    it; raises KrylovError if a block has not stopped after ``maxiter`` iterations."""
    from femphase.fem import kernels  # numba loads only where windows are solved at once

    if getattr(matrix, "format", None) != "csr":
        raise TypeError(f"conjugate_gradient takes a CSR matrix, not {type(matrix).__name__}")
    x = np.array(guess, dtype=np.result_type(rhs, guess), copy=True)
    rhs = np.ascontiguousarray(rhs, dtype=x.dtype)
    inverse = np.ascontiguousarray(inverse_diagonal, dtype=x.dtype)
    indptr, indices = unsigned(matrix.indptr), unsigned(matrix.indices)
    r = np.empty_like(x) if guess_product is None else (rhs - guess_product).astype(x.dtype, copy=False)
    scale, largest = kernels.residual_start(indptr, indices, matrix.data, inverse, rhs, x, r, guess_product is None)
    goal = tolerance * scale if scale > 0.0 else np.inf  # a zero rhs: the reduction alone sets the goal
    goal = min(goal, RESIDUAL_REDUCTION * largest)
    offsets = np.asarray(offsets).astype(np.uint64)
    iterations = np.zeros(offsets.size - 1, dtype=np.int64)
    status = kernels.window_conjugate_gradient(indptr, indices, matrix.data, offsets, inverse, x, r, goal, maxiter,
                                               iterations)
    if status <= -2:
        raise KrylovError(f"CG broke down in window {-2 - status} (pᵀAp ≤ 0, goal {goal:.3g}): the windows' "
                          "systems are not positive definite")
    if status >= 0:
        part = slice(int(offsets[status]), int(offsets[status + 1]))
        raise KrylovError(f"CG did not reach the relative residual {tolerance:g} (or {RESIDUAL_REDUCTION:g} of its "
                          f"start, whichever is smaller) in {maxiter} iterations in window {status} "
                          f"(max |D⁻¹r| {np.abs(inverse[part] * r[part]).max():.3g}, goal {goal:.3g}): the "
                          "windows' systems are not mass-dominated; lower the phase's dt")
    return x, iterations, r


def unsigned(index: np.ndarray) -> np.ndarray:
    """An integer index array seen as unsigned, without a copy: numba guards every signed
    index against wrapping around from the end, and the compiled loops over the blocks
    (:mod:`femphase.fem.kernels`) took 1.2–1.6× as long with scipy's int32 arrays."""
    return index.view(np.dtype(f"u{index.dtype.itemsize}"))
