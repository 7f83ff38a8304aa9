"""Compiled loops over window fields (numba), for scans numpy cannot express without one
call per window group.

Each function is compiled on first use for the dtype it is given (float32 inside the
mixed-precision flow steps, float64 elsewhere) and cached on disk (numba's ``cache=True``),
so a run pays the compilation (~1 s) once per machine, not once per process. The module is
imported only where a scene needs it (the structured channel's windows).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, boundscheck=False)
def occupied_boxes(phi: np.ndarray, offsets: np.ndarray, shapes: np.ndarray, threshold: float) -> np.ndarray:
    """(windows, 4) int64: the first and last row and the first and last column (local
    nodes) where a window's field exceeds ``threshold``, −1 in all four for a window where
    it nowhere does. Window w's field is ``phi[offsets[w]:offsets[w + 1]]``, ``shapes[w]``
    = (ny, nx) nodes stored row by row.

    Each row is scanned from both ends up to its first node above the threshold, so a
    particle's interior is not read: 0.1 ms on the random packing's 10⁵ positions, against
    0.4 ms for numpy's boolean reductions group by group (benchmarks/README.md, "Session
    15"). A NaN counts as below the threshold, as in numpy's ``>``."""
    n = shapes.shape[0]
    boxes = np.full((n, 4), -1, dtype=np.int64)
    for window in range(n):
        ny, nx = shapes[window, 0], shapes[window, 1]
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
