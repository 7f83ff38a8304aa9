"""Compiled loops over the structured channel's window fields (numba): scans and sums that
numpy expresses only with one call per window group or with a per-position dof table.

Each function is compiled on first use for the dtype it is given (float32 inside the
mixed-precision flow steps, float64 elsewhere) and cached on disk (numba's ``cache=True``),
so a run pays the compilation (~1 s) once per machine, not once per process. The module is
imported only where a scene needs it (the structured channel's windows).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["occupied_boxes", "others_squared", "row_values"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def occupied_boxes(phi: np.ndarray, offsets: np.ndarray, corners: np.ndarray, threshold: float) -> np.ndarray:
    """(windows, 4) int64: the first and last row and the first and last column (local
    nodes) where a window's field exceeds ``threshold``, −1 in all four for a window where
    it nowhere does. Window w's field is ``phi[offsets[w]:offsets[w + 1]]``, its ny × nx
    nodes (``corners[w]`` = iy0, ny, ix0, nx, as in :func:`others_squared`) stored row by
    row.

    Each row is scanned from both ends up to its first node above the threshold, so a
    particle's interior is not read: 0.1 ms on the random packing's 10⁵ positions, against
    0.4 ms for numpy's boolean reductions group by group 
    (docs/decisions/0013-compiled-window-loops.md). A NaN counts as below the threshold, as in numpy's ``>``."""
    n = corners.shape[0]
    boxes = np.full((n, 4), -1, dtype=np.int64)
    for window in range(n):
        ny, nx = corners[window, 1], corners[window, 3]
        first_row, last_row, first_column, last_column = -1, -1, nx, -1
        start = offsets[window]
        for row in range(ny):
            first = -1
            for column in range(nx):
                if phi[start + column] > threshold:
                    first = column
                    break
            if first >= 0:
                last = first
                for column in range(nx - 1, first, -1):
                    if phi[start + column] > threshold:
                        last = column
                        break
                if first_row < 0:
                    first_row = row
                last_row = row
                first_column = min(first_column, first)
                last_column = max(last_column, last)
            start += nx
        if first_row >= 0:
            boxes[window, 0], boxes[window, 1] = first_row, last_row
            boxes[window, 2], boxes[window, 3] = first_column, last_column
    return boxes


@numba.njit(cache=True, nogil=True, boundscheck=False)
def others_squared(squares: np.ndarray, offsets: np.ndarray, corners: np.ndarray,
                   lattice_ny: int, lattice_nx: int) -> np.ndarray:
    """Σ_{j≠i} φ_j² at every position of the structured channel's windows: ``squares``
    (φ_i² at every position, window w's from ``offsets[w]``, row by row) summed over all
    windows at every node of the (lattice_ny, lattice_nx) lattice, minus each position's
    own term. ``corners`` (windows, 4): iy0, ny, ix0, nx of every window (columns ix0 …
    ix0+nx−1 mod lattice_nx), in the order of ``offsets``.

    The sums are accumulated in double in position order and rounded to the fields' dtype
    once, then the own term is subtracted in that dtype: the operations, in the order, of
    ``np.bincount(dofs, weights=squares).astype(dtype)[dofs] − squares`` with every
    position's dof (bitwise equal, ``tests/test_kernels.py``), without that dof table,
    which a layout moved by the advection would build afresh at every substep. Each window
    row is one or two contiguous runs of lattice nodes (two across the periodic seam),
    walked as slices, which numba vectorises."""
    total = np.zeros(lattice_ny * lattice_nx)
    for window in range(corners.shape[0]):
        iy0, ny, ix0, nx = corners[window, 0], corners[window, 1], corners[window, 2], corners[window, 3]
        before_seam = min(nx, lattice_nx - ix0)
        position = offsets[window]
        for row in range(iy0, iy0 + ny):
            _add_into(total[row * lattice_nx + ix0:row * lattice_nx + ix0 + before_seam],
                      squares[position:position + before_seam])
            _add_into(total[row * lattice_nx:row * lattice_nx + nx - before_seam],
                      squares[position + before_seam:position + nx])
            position += nx
    rounded = total.astype(squares.dtype)
    out = np.empty_like(squares)
    for window in range(corners.shape[0]):
        iy0, ny, ix0, nx = corners[window, 0], corners[window, 1], corners[window, 2], corners[window, 3]
        before_seam = min(nx, lattice_nx - ix0)
        position = offsets[window]
        for row in range(iy0, iy0 + ny):
            _difference(out[position:position + before_seam],
                        rounded[row * lattice_nx + ix0:row * lattice_nx + ix0 + before_seam],
                        squares[position:position + before_seam])
            _difference(out[position + before_seam:position + nx],
                        rounded[row * lattice_nx:row * lattice_nx + nx - before_seam],
                        squares[position + before_seam:position + nx])
            position += nx
    return out


@numba.njit(inline="always", boundscheck=False)
def _add_into(target: np.ndarray, values: np.ndarray) -> None:
    for k in range(values.size):
        target[k] += values[k]


@numba.njit(inline="always", boundscheck=False)
def _difference(out: np.ndarray, minuend: np.ndarray, subtrahend: np.ndarray) -> None:
    for k in range(out.size):
        out[k] = minuend[k] - subtrahend[k]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def row_values(values: np.ndarray, offsets: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """A value per lattice row (``values``, (lattice_ny,)) at every position of the windows
    (``offsets``, ``corners`` as in :func:`others_squared`): e.g. the channel's lumped mass,
    which depends on the row alone. Each window row is one vectorised fill, where a gather
    through every position's row costs three passes over the positions."""
    out = np.empty(offsets[-1], dtype=values.dtype)
    for window in range(corners.shape[0]):
        iy0, ny, nx = corners[window, 0], corners[window, 1], corners[window, 3]
        position = offsets[window]
        for row in range(iy0, iy0 + ny):
            out[position:position + nx] = values[row]
            position += nx
    return out
