"""Every window's principal submatrix as one block-diagonal matrix, and Krylov solves on it.

A field lives on a window, a set of dofs, and its linear systems are the principal
submatrices of full-domain matrices on those dofs. On a structured channel windows share
shapes and a tensor solver; on a mesh every window (box) is its own submatrix. There,
instead of one factorisation per window, all windows are solved at once: their blocks form
one block-diagonal matrix over the concatenated vector of all windows ("layout order"),
and a preconditioned Krylov method runs on that one vector, one sparse product per
iteration for all windows.

Why this fits: the window systems c·M + J0·D·K are mass-dominated, with condition number
≈ 1 + dt·J0·D·λmax(K)/m, a few units at the adaptive scheme's substeps, so Jacobi-
preconditioned CG converges in tens of iterations. The meshes' explicit advection applies
block-diagonal matrices of the same kind and solves nothing. Memory is the blocks' entries
(about 7 per position for P1), against ~100 per position for a sparse LU.

:func:`local_block` maps a full-domain sparsity pattern onto one window (kept while the
window lives); :class:`BlockPattern` concatenates the windows' maps, and
:meth:`BlockPattern.block` then takes any matrix with that pattern (:func:`aligned_data`) to
its block-diagonal form by one gather.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from femphase.errors import FemphaseError

__all__ = ["BlockPattern", "KrylovError", "LocalBlock", "aligned_data", "conjugate_gradient", "local_block"]


class KrylovError(FemphaseError, ArithmeticError):
    """A batched Krylov solve did not reach its tolerance."""


def aligned_data(matrix: sp.spmatrix, pattern: sp.csr_matrix) -> np.ndarray:
    """``matrix``'s entries at the stored entries of ``pattern`` (canonical CSR), zeros where
    ``matrix`` has none; raises ValueError if ``matrix`` has an entry outside the pattern."""
    matrix = sp.csr_matrix(matrix)
    matrix.sum_duplicates()
    n = pattern.shape[1]
    rows = np.repeat(np.arange(pattern.shape[0], dtype=np.int64), np.diff(pattern.indptr))
    keys = rows * n + pattern.indices
    coo = matrix.tocoo()
    found = np.searchsorted(keys, coo.row.astype(np.int64) * n + coo.col)
    inside = (found < keys.size) & (keys[np.minimum(found, keys.size - 1)] == coo.row.astype(np.int64) * n + coo.col)
    if not np.all(inside | (coo.data == 0)):
        raise ValueError("the matrix has entries outside the block pattern")
    data = np.zeros(pattern.nnz, dtype=np.result_type(matrix.dtype, np.float64))
    data[found[inside]] = coo.data[inside]
    return data


class LocalBlock(NamedTuple):
    """One window's principal submatrix of a pattern, in the window's own numbering: CSR
    ``indptr`` and ``indices`` (sorted columns within a row: canonical, so products sum in a
    fixed order whatever order windows were met in) and ``source``, the position of every
    entry among the full-domain pattern's stored entries."""

    indptr: np.ndarray
    indices: np.ndarray
    source: np.ndarray

    @property
    def nbytes(self) -> int:
        return int(self.indptr.nbytes + self.indices.nbytes + self.source.nbytes)


def local_block(pattern: sp.csr_matrix, dofs: np.ndarray) -> LocalBlock:
    """The principal submatrix of ``pattern`` (canonical CSR) on ``dofs`` (distinct) as a
    :class:`LocalBlock`; entry (p, q) is the pattern's (dofs[p], dofs[q])."""
    begin = pattern.indptr[dofs].astype(np.int64)
    length = pattern.indptr[dofs + 1].astype(np.int64) - begin
    rows = np.repeat(np.arange(dofs.size, dtype=np.int64), length)
    source = np.arange(rows.size, dtype=np.int64) - np.repeat(np.cumsum(length) - length - begin, length)
    position = np.full(pattern.shape[1], -1, dtype=np.int64)  # each dof's place in the window, −1 outside
    position[dofs] = np.arange(dofs.size, dtype=np.int64)
    columns = position[pattern.indices[source]]
    inside = columns >= 0
    rows, columns, source = rows[inside], columns[inside], source[inside]
    key = rows * dofs.size + columns
    # rows come in order and the pattern's columns are sorted, so each row's local columns are
    # too wherever ``dofs`` ascends (a mesh box's); windows numbered otherwise are sorted here
    if key.size and np.any(key[1:] <= key[:-1]):
        canonical = np.argsort(key, kind="stable")
        columns, source = columns[canonical], source[canonical]
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=dofs.size))])
    return LocalBlock(indptr.astype(np.int64), columns, source)


class BlockPattern:
    """The block-diagonal matrix of windows' principal submatrices of one full-domain
    pattern, over the concatenated vector of all windows.

    ``blocks`` lists each distinct window's :class:`LocalBlock` and ``counts`` how many
    consecutive windows share it (windows of one key on the structured channel); the
    windows follow each other in that order. :meth:`block` fills it from any matrix's
    entries aligned to the pattern (:func:`aligned_data`) by one gather."""

    def __init__(self, blocks: Sequence[LocalBlock], counts: Sequence[int]) -> None:
        # every window's arrays side by side (a block repeated for each window sharing it),
        # each shifted by its window's first entry and position before one concatenation
        # into the final type: temporaries the size of the whole pattern (a shift array, a
        # cast) are fresh pages every layout, and faulting them in was 3/5 of the build
        windows = [block for block, count in zip(blocks, counts) for _ in range(count)]
        sizes = np.array([block.indptr.size - 1 for block in windows], dtype=np.int64)
        entries = np.array([block.indices.size for block in windows], dtype=np.int64)
        offset = int(sizes.sum())
        self.shape = (offset, offset)
        # scipy stores CSR indices as int32 where they fit and converts (copies) any other
        # kind at every construction, i.e. at every :meth:`block`
        index = np.int32 if max(offset, int(entries.sum())) < np.iinfo(np.int32).max else np.int64
        starts, shifts = np.cumsum(entries) - entries, np.cumsum(sizes) - sizes
        self.indptr = np.concatenate([np.zeros(1, dtype=index)]
                                     + [block.indptr[1:] + start for block, start in zip(windows, starts)], dtype=index)
        self.indices = np.concatenate([block.indices + shift for block, shift in zip(windows, shifts)]
                                      or [np.zeros(0, dtype=index)], dtype=index)
        self.source = np.concatenate([block.source for block in windows] or [np.zeros(0, dtype=np.int64)])

    @property
    def nbytes(self) -> int:
        return int(self.source.nbytes + self.indices.nbytes + self.indptr.nbytes)

    def block(self, data: np.ndarray) -> sp.csr_matrix:
        """The block-diagonal matrix whose entries come from ``data``, the full-domain
        matrix's entries aligned to the pattern (:func:`aligned_data`)."""
        return sp.csr_matrix((data[self.source], self.indices, self.indptr), shape=self.shape)


def conjugate_gradient(apply: Callable[[np.ndarray], np.ndarray], diagonal: np.ndarray, rhs: np.ndarray,
                       guess: np.ndarray, tolerance: float, maxiter: int = 1000) -> tuple[np.ndarray, int]:
    """Solve A x = rhs for a symmetric positive definite A (``apply``: x ↦ A x) by CG with
    the Jacobi preconditioner ``diagonal``, from ``guess``. Stops when the preconditioned
    residual's max-norm, max|D⁻¹ r|, is at most ``tolerance`` times max|D⁻¹ rhs|: for a
    mass-dominated A, D⁻¹r is the solution's error up to the condition number, in the
    solution's units. Returns (x, iterations); raises KrylovError after ``maxiter``."""
    x = np.array(guess, dtype=np.result_type(rhs, guess), copy=True)
    inverse = 1.0 / diagonal
    goal = tolerance * max(float(np.max(np.abs(inverse * rhs))), np.finfo(float).tiny)
    r = rhs - apply(x)
    z = inverse * r
    if np.max(np.abs(z)) <= goal:
        return x, 0
    p = z.copy()
    rz = np.vdot(r, z).real
    for iteration in range(1, maxiter + 1):
        q = apply(p)
        alpha = rz / np.vdot(p, q).real
        x += alpha * p
        r -= alpha * q
        z = inverse * r
        if np.max(np.abs(z)) <= goal:
            return x, iteration
        rz, previous = np.vdot(r, z).real, rz
        p *= rz / previous
        p += z
    raise KrylovError(f"CG did not reach the relative residual {tolerance:g} in {maxiter} iterations "
                      f"(max |D⁻¹r| {np.max(np.abs(z)):.3g}, goal {goal:.3g}): the windows' systems are "
                      "not mass-dominated; lower the phase's dt")
