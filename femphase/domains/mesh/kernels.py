"""Compiled loops over a mesh's window fields, boxes and shapes (numba), for the refits that
come at every substep as windows follow their particles.

Compiled on first use and cached on disk (numba's ``cache=True``), as the structured
channel's (:mod:`femphase.domains.grid.kernels`); imported only where a mesh scene refits.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["carry_over", "dilate", "dofs_in_boxes", "largest_made_distance", "occupied_dofs", "occupied_extents"]


@numba.njit(inline="always", boundscheck=False)
def _local_x(x: float, x0: float, period: float) -> float:
    """(x − x0) mod period as Python's float % rounds it, for |x − x0| < 2 period (dofs and
    box corners lie in one period): by additions, which fmod makes exact there, instead of
    the floored modulo's division (a third of :func:`occupied_extents`'s time)."""
    local = x - x0
    if local < 0.0:
        local += period
        if local < 0.0:
            local += period
    elif local >= period:
        local -= period
    return local


@numba.njit(cache=True, nogil=True, boundscheck=False)
def occupied_extents(phi: np.ndarray, node_index: np.ndarray, offsets: np.ndarray, x: np.ndarray,
                     y: np.ndarray, box_x0: np.ndarray, period: float, threshold: float) -> np.ndarray:
    """(windows, 4): per window (layout order) the least and greatest x, measured from its
    box's left edge ``box_x0[w]`` along +x modulo ``period`` (:func:`~femphase.domains.mesh.boxes.local_x`),
    and the least and greatest y of its positions where φ exceeds ``threshold``; NaN in all
    four where none does (a NaN φ counts as below, as in numpy's ``>``). Window w holds
    positions ``offsets[w]:offsets[w + 1]``, position p the dof ``node_index[p]`` at
    (``x``, ``y``)[dof].

    One pass over the positions, against ten for numpy's masked reductions window by window
    (0.9 s of 13.7 s of stepping in 710 time units of flow on examples/straight_mesh.toml)."""
    n = offsets.size - 1
    out = np.full((n, 4), np.nan)
    for window in range(n):
        low_x, high_x, low_y, high_y = np.inf, -np.inf, np.inf, -np.inf
        left = box_x0[window]
        for position in range(offsets[window], offsets[window + 1]):
            if phi[position] > threshold:
                dof = node_index[position]
                local = _local_x(x[dof], left, period)
                low_x, high_x = min(low_x, local), max(high_x, local)
                low_y, high_y = min(low_y, y[dof]), max(high_y, y[dof])
        if low_x <= high_x:
            out[window, 0], out[window, 1], out[window, 2], out[window, 3] = low_x, high_x, low_y, high_y
    return out


@numba.njit(cache=True, nogil=True, boundscheck=False)
def dofs_in_boxes(order: np.ndarray, keys: np.ndarray, span: float, y_low: float, pad: float, x: np.ndarray,
                  y: np.ndarray, boxes: np.ndarray, period: float, x_origin: float, strip_width: float,
                  count: int) -> tuple[np.ndarray, np.ndarray]:
    """(dofs, offsets): the dofs inside each box (rows of ``boxes``: x0, width, y0, y1; x0 +
    [0, width] mod ``period`` × [y0, y1]), sorted (a radix sort), box b's in
    ``dofs[offsets[b]:offsets[b + 1]]``. Tested among the dofs of the strips each box
    crosses, one more on each side (dofs on a strip's edge, rounding), all ``count`` strips
    for a box within one strip of the whole period: ``order`` holds the dofs sorted by
    ``keys`` = strip · span + (y − y_low)
    (:meth:`~femphase.domains.mesh.domain.MeshDomain._dofs_inside`), strips of
    ``strip_width`` from ``x_origin``, ``pad`` the keys' rounding. The test is
    :meth:`~femphase.domains.mesh.boxes.Box.contains`'s, to the bit."""
    n = boxes.shape[0]
    # the candidates of box b in strip s: order[begins[b, s]:ends[b, s]], empty where b does
    # not cross s (a set of strips: a box over the seam names no strip twice)
    begins = np.zeros((n, count), dtype=np.int64)
    ends = np.zeros((n, count), dtype=np.int64)
    for b in range(n):
        x0, width, y0, y1 = boxes[b, 0], boxes[b, 1], boxes[b, 2], boxes[b, 3]
        if width >= period - strip_width:
            first, crossed = 0, count
        else:
            first, crossed = int(np.floor((x0 - x_origin) / strip_width)) - 1, int(np.ceil(width / strip_width)) + 3
        for j in range(crossed):
            s = (first + j) % count
            begins[b, s] = np.searchsorted(keys, s * span + (y0 - y_low) - pad, side="left")
            ends[b, s] = max(np.searchsorted(keys, s * span + (y1 - y_low) + pad, side="right"), begins[b, s])
    dofs = np.empty(int((ends - begins).sum()), dtype=order.dtype)
    offsets = np.zeros(n + 1, dtype=np.int64)
    passes, digit_bits, counts = _radix_digits(order.size)
    largest = 0
    for b in range(n):
        size = 0
        for s in range(count):
            size += ends[b, s] - begins[b, s]
        largest = max(largest, size)
    scratch = np.empty(largest, dtype=order.dtype)
    filled = 0
    for b in range(n):
        x0, width, y0, y1 = boxes[b, 0], boxes[b, 1], boxes[b, 2], boxes[b, 3]
        for s in range(count):
            for k in range(begins[b, s], ends[b, s]):
                dof = order[k]
                if _local_x(x[dof], x0, period) <= width and y[dof] >= y0 and y[dof] <= y1:
                    dofs[filled] = dof
                    filled += 1
        _sort_indices(dofs[offsets[b]:filled], scratch, counts, passes, digit_bits)
        offsets[b + 1] = filled
    return dofs[:filled], offsets


@numba.njit(inline="always", boundscheck=False)
def _radix_digits(size: int) -> tuple[int, int, np.ndarray]:
    """(passes, digit bits, counts) of :func:`_sort_indices` for values below ``size``: as few
    passes as their bit length allows at ≤ 11 bits each, and the counts array they need."""
    bits = 1
    while (1 << bits) < size:
        bits += 1
    passes = (bits + 10) // 11
    digit_bits = (bits + passes - 1) // passes
    return passes, digit_bits, np.empty((1 << digit_bits) + 1, dtype=np.int64)


@numba.njit(inline="always", boundscheck=False)
def _counting_pass(source: np.ndarray, target: np.ndarray, counts: np.ndarray, shift: int, mask: int) -> None:
    """``source`` into ``target`` ordered by the digit (v >> shift) & mask, stably."""
    counts[:] = 0
    for i in range(source.size):
        counts[((source[i] >> shift) & mask) + 1] += 1
    for k in range(1, counts.size):
        counts[k] += counts[k - 1]
    for i in range(source.size):
        digit = (source[i] >> shift) & mask
        target[counts[digit]] = source[i]
        counts[digit] += 1


@numba.njit(inline="always", boundscheck=False)
def _sort_indices(values: np.ndarray, scratch: np.ndarray, counts: np.ndarray, passes: int, digit_bits: int) -> None:
    """Sort ``values`` (non-negative integers below 2^(passes·digit_bits)) in place by a
    least-significant-digit radix sort: ``passes`` stable counting passes of ``digit_bits``
    bits, ``scratch`` at least as long as ``values``, ``counts`` 2^digit_bits + 1 long. A box's
    thousand dofs in two passes of 8 bits take a tenth of a comparison sort's time (the sort
    was 85 % of :func:`dofs_in_boxes` on examples/straight_mesh.toml)."""
    spare = scratch[:values.size]
    mask = (1 << digit_bits) - 1
    for d in range(passes):  # back and forth between the two arrays: none reassigned in the loop
        if d % 2 == 0:
            _counting_pass(values, spare, counts, d * digit_bits, mask)
        else:
            _counting_pass(spare, values, counts, d * digit_bits, mask)
    if passes % 2 == 1:
        values[:] = spare


@numba.njit(cache=True, nogil=True, boundscheck=False)
def largest_made_distance(phi: np.ndarray, made: np.ndarray, offsets: np.ndarray, threshold: float) -> np.ndarray:
    """Per window (layout order, window w the positions ``offsets[w]:offsets[w + 1]``): the
    largest ``made`` (each position's distance to the set its shape was made for,
    :class:`~femphase.domains.mesh.shapes.Shape`) over its positions where φ exceeds
    ``threshold``; 0 where none does (a NaN φ counts as below, as in numpy's ``>``).
    One pass over the positions at every substep's refit."""
    out = np.zeros(offsets.size - 1)
    for window in range(offsets.size - 1):
        largest = 0.0
        for position in range(offsets[window], offsets[window + 1]):
            if phi[position] > threshold and made[position] > largest:
                largest = made[position]
        out[window] = largest
    return out


@numba.njit(cache=True, nogil=True, boundscheck=False)
def dilate(sets: np.ndarray, set_offsets: np.ndarray, indptr: np.ndarray, indices: np.ndarray, x: np.ndarray,
           y: np.ndarray, period: float, reaches: np.ndarray, motions: np.ndarray, scratch: tuple, dofs: np.ndarray,
           distances: np.ndarray, offsets: np.ndarray) -> int:
    """For each set of dofs (``sets[set_offsets[w]:set_offsets[w + 1]]``) swept along
    ``motions[w]`` (a length vector; each edge dof of the set then stands for the segment
    from it to it moved so), the dofs within ``reaches[w]`` of it, sorted, and their
    distances to it (0 in the set; where the set moves to, within 1.5 spacings on a
    Delaunay mesh: every point the set sweeps lies on the segment of the edge point its path
    crosses, and a dof is measured to the segment of the dof that reached it), written to
    ``dofs``, ``distances`` and ``offsets`` (set w's in ``[offsets[w], offsets[w + 1])``;
    ``offsets[0]`` is 0); returns how many, or −1 if ``dofs`` is too short.

    Distances grow ring by ring from the set's edge along the mesh's edges (the CSR pattern
    ``indptr``, ``indices``): each dof is measured, in a straight line (x periodic), to the
    edge dof nearest one of its neighbours, and revisited when a later ring finds a nearer
    one. So a dof's distance is never below its Euclidean one (on examples/straight_mesh.toml
    at most 0.3 above, with the same dofs within reach), and on a mesh with holes it goes
    around them. ``scratch`` is (best, nearest, queued, ring, following, sort scratch), int
    and float arrays of the dofs' size, best all inf and left so. Arrays are never
    reassigned inside the loops: numba then counts references at every use, and such a
    kernel ran 3–6× slower."""
    best, nearest, queued, ring, following, spare = scratch
    queued[:] = 0  # the pass that last queued each dof: counted from 1 in every call
    half = 0.5 * period
    passes, digit_bits, counts = _radix_digits(best.size)
    total = rounds = 0
    for w in range(set_offsets.size - 1):
        start, size = total, 0
        limit = reaches[w] * reaches[w]
        mx, my = motions[w, 0], motions[w, 1]
        swept = mx * mx + my * my
        for s in sets[set_offsets[w]:set_offsets[w + 1]]:
            best[s] = 0.0
            nearest[s] = s
        for s in sets[set_offsets[w]:set_offsets[w + 1]]:
            if total >= dofs.size:
                return -1
            dofs[total] = s
            total += 1
            for k in range(indptr[s], indptr[s + 1]):
                if best[indices[k]] == np.inf:  # an edge dof: the first ring
                    ring[size] = s
                    size += 1
                    break
        current, upcoming = ring, following
        while size:
            rounds += 1
            next_size = 0
            for r in range(size):
                u = current[r]
                source = nearest[u]
                for k in range(indptr[u], indptr[u + 1]):
                    v = indices[k]
                    if best[v] == 0.0:
                        continue
                    dx = x[v] - x[source]
                    if dx > half:
                        dx -= period
                    elif dx < -half:
                        dx += period
                    dy = y[v] - y[source]
                    if swept > 0.0:  # to the nearest point of the source's segment
                        along = min(max((dx * mx + dy * my) / swept, 0.0), 1.0)
                        dx -= along * mx
                        dy -= along * my
                    squared = dx * dx + dy * dy
                    if squared <= limit and squared < best[v]:
                        if best[v] == np.inf:
                            if total >= dofs.size:
                                return -1
                            dofs[total] = v
                            total += 1
                        best[v] = squared
                        nearest[v] = source
                        if queued[v] != rounds:
                            queued[v] = rounds
                            upcoming[next_size] = v
                            next_size += 1
            current, upcoming = upcoming, current
            size = next_size
        _sort_indices(dofs[start:total], spare, counts, passes, digit_bits)
        for i in range(start, total):
            distances[i] = np.sqrt(best[dofs[i]])
            best[dofs[i]] = np.inf
        offsets[w + 1] = total
    return total


@numba.njit(cache=True, nogil=True, boundscheck=False)
def occupied_dofs(phi: np.ndarray, node_index: np.ndarray, offsets: np.ndarray, slots: np.ndarray,
                  threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(dofs, set offsets): the dofs where φ exceeds ``threshold`` in each window of
    ``slots`` (layout order, window w the positions ``offsets[w]:offsets[w + 1]``), slot k's
    in ``dofs[set_offsets[k]:set_offsets[k + 1]]`` in the window's order."""
    total = 0
    for slot in slots:
        total += offsets[slot + 1] - offsets[slot]
    dofs = np.empty(total, dtype=np.int64)
    set_offsets = np.zeros(slots.size + 1, dtype=np.int64)
    filled = 0
    for k in range(slots.size):
        for position in range(offsets[slots[k]], offsets[slots[k] + 1]):
            if phi[position] > threshold:
                dofs[filled] = node_index[position]
                filled += 1
        set_offsets[k + 1] = filled
    return dofs[:filled], set_offsets


@numba.njit(cache=True, nogil=True, boundscheck=False)
def carry_over(phi: np.ndarray, node_index: np.ndarray, offsets: np.ndarray, slots: np.ndarray, dofs: np.ndarray,
               dof_offsets: np.ndarray, scratch: np.ndarray) -> np.ndarray:
    """The fields of the windows of ``slots`` (positions as in :func:`occupied_dofs`) on
    new dofs, slot k's ``dofs[dof_offsets[k]:dof_offsets[k + 1]]``: its values where the
    old window had the dof, zero elsewhere; concatenated. ``scratch`` (one entry per dof of
    the mesh, zero) is left zero."""
    out = np.empty(dof_offsets[-1], dtype=phi.dtype)
    for k in range(slots.size):
        for position in range(offsets[slots[k]], offsets[slots[k] + 1]):
            scratch[node_index[position]] = phi[position]
        for i in range(dof_offsets[k], dof_offsets[k + 1]):
            out[i] = scratch[dofs[i]]
        for position in range(offsets[slots[k]], offsets[slots[k] + 1]):
            scratch[node_index[position]] = 0.0
    return out
