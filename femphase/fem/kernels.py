"""Compiled loops for the block-diagonal window matrices (numba), built as boxes follow
their particles on a mesh, for the CG that solves them and the explicit advection that
applies them, for the windows' shape tensors, and for the repulsion's sums over the
windows that share a dof.

Compiled on first use and cached on disk (numba's ``cache=True``), as the domains' kernels;
imported only where windows are solved all at once (:mod:`femphase.fem.blocks`), their
shapes measured on a mesh (:func:`femphase.fem.operators.shape_tensors`) or their overlaps
summed (:meth:`femphase.domains.layout.Layout.others_squared`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["galerkin_runge_kutta", "gather", "jacobi_correction", "others_squared", "principal_blocks",
           "residual_start", "taylor_galerkin", "window_conjugate_gradient", "window_gradient_moments"]


@numba.njit(inline="always", boundscheck=False)
def _map_window(slot: np.ndarray, node_index: np.ndarray, start: int, stop: int, on: bool) -> None:
    """Set each dof of positions start:stop to its position in ``slot`` (``on``), or back to −1."""
    for p in range(start, stop):
        slot[node_index[p]] = p if on else -1


@numba.njit(cache=True, nogil=True, boundscheck=False)
def principal_blocks(indptr: np.ndarray, indices: np.ndarray, node_index: np.ndarray, offsets: np.ndarray,
                     slot: np.ndarray, out_indices: np.ndarray, source: np.ndarray) -> np.ndarray:
    """The block-diagonal matrix of every window's principal submatrix of the full-domain
    pattern (``indptr``, ``indices``: canonical CSR), in one pass: window w holds positions
    ``offsets[w]:offsets[w + 1]``, position p the dof ``node_index[p]``. Fills ``out_indices``
    (each entry's column: the position of its dof in the same window) and ``source`` (its
    place among the pattern's stored entries), each row's columns ascending, and returns the
    row pointer (positions + 1,). The two arrays must hold the pattern's rows of all
    positions whole (Σ_p of dof p's row length), an upper bound: a window cuts the rows at its
    edge. ``slot`` (n_dofs,) is scratch, all −1, and left so. (A pass that counted the rows
    first, to size the arrays exactly, took 1.4–1.6× as long.)"""
    out_indptr = np.empty(node_index.size + 1, dtype=np.int64)
    out_indptr[0] = 0
    at = 0
    for window in range(offsets.size - 1):
        start, stop = offsets[window], offsets[window + 1]
        _map_window(slot, node_index, start, stop, True)
        for p in range(start, stop):
            dof = node_index[p]
            first = at
            for k in range(indptr[dof], indptr[dof + 1]):
                column = slot[indices[k]]
                if column >= 0:
                    # insertion by position: already in order where the window's dofs ascend
                    # (a mesh box's), a few shifts where they do not (a window across the seam)
                    q = at
                    while q > first and out_indices[q - 1] > column:
                        out_indices[q] = out_indices[q - 1]
                        source[q] = source[q - 1]
                        q -= 1
                    out_indices[q] = column
                    source[q] = k
                    at += 1
            out_indptr[p + 1] = at
        _map_window(slot, node_index, start, stop, False)
    return out_indptr


@numba.njit(cache=True, nogil=True, boundscheck=False)
def gather(values: np.ndarray, index: np.ndarray, out: np.ndarray) -> None:
    """out[i] = values[index[i]] (``index`` unsigned, as :class:`~femphase.fem.blocks.BlockPattern`
    keeps its sources): a layout's blocks in half numpy's time (0.28 against 0.57 ms for
    7·10⁵ entries of 1.2·10⁵, float32)."""
    for i in range(index.size):
        out[i] = values[index[i]]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _block_rows(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, v: np.ndarray, out: np.ndarray,
                start: int, stop: int, moment: bool) -> float:
    """out = A v on the rows start:stop of the CSR matrix (``indptr``, ``indices``: unsigned;
    ``data``), in v's precision; returns Σ v_i out_i over those rows in double (the CG's
    pᵀAp) if ``moment``, else 0 (its chain of additions cost the advection 1.15× its
    time). Each row in two partial sums, even and odd entries: one chain of dependent
    additions per row (about 7 entries) bounded the loop, and two took the CG's pass to
    0.85× its time (four: 0.93×). A loop over rows, not a function per row: numba's calls
    per row, inlined or not, took 10× as long."""
    zero = v.dtype.type(0.0)
    one, two = indptr.dtype.type(1), indptr.dtype.type(2)
    total_moment = 0.0
    for i in range(start, stop):
        even, odd = zero, zero
        k, end = indptr[i], indptr[i + 1]
        while k + one < end:
            even += data[k] * v[indices[k]]
            odd += data[k + one] * v[indices[k + one]]
            k += two
        if k < end:
            even += data[k] * v[indices[k]]
        total = even + odd
        out[i] = total
        if moment:
            total_moment += np.float64(v[i] * total)
    return total_moment


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _corrected_inverse(indptr: np.ndarray, indices: np.ndarray, matrix: np.ndarray, rhs: np.ndarray,
                       inverse_lumped: np.ndarray, corrections: int, out: np.ndarray, scratch: np.ndarray) -> None:
    """out = Σ_{j≤K} (I − M_L⁻¹A)^j M_L⁻¹ rhs, the lumped inverse of A (``matrix``, on the
    CSR pattern ``indptr``, ``indices``) with K = ``corrections`` Jacobi corrections, each
    z ← z + M_L⁻¹(rhs − A z) from the whole z; ``scratch`` holds A z."""
    n = np.uint64(rhs.size)
    for i in range(n):
        out[i] = rhs[i] * inverse_lumped[i]
    for _ in range(corrections):
        _block_rows(indptr, indices, matrix, out, scratch, 0, n, False)
        jacobi_correction(out, rhs, scratch, inverse_lumped)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def galerkin_runge_kutta(indptr: np.ndarray, indices: np.ndarray, advection: np.ndarray, mass: np.ndarray,
                         inverse_lumped: np.ndarray, phi: np.ndarray, step: float, substeps: int, stages: int,
                         corrections: int) -> np.ndarray:
    """``substeps`` explicit Runge–Kutta substeps of φ' = −P C φ on a layout's positions, each
    Σ_{k≤s} (−step·PC)^k/k! φ by Horner (s = ``stages``), with P y = Σ_{j≤K} (I − M_L⁻¹M)^j
    M_L⁻¹ y (K = ``corrections``, ``inverse_lumped`` = M_L⁻¹): the block-diagonal C
    (``advection``) and M (``mass``) share one CSR pattern (``indptr``, ``indices``:
    unsigned). Each product one compiled pass (:func:`_block_rows`), each vector update
    another, into arrays made once; in φ's precision. On examples/straight_mesh.toml under
    flow 0.88× the time of scipy's products and numpy's passes (5.1 against 5.8 ms an
    advection, best of 20)."""
    dtype = phi.dtype.type
    n = np.uint64(phi.size)
    start = phi.copy()  # x, the substep's start
    y = phi.copy()
    product = np.empty_like(phi)
    z = np.empty_like(phi)
    corrected = np.empty_like(phi)
    for _ in range(substeps):
        start[:] = y
        for k in range(stages, 0, -1):
            _block_rows(indptr, indices, advection, y, product, 0, n, False)
            _corrected_inverse(indptr, indices, mass, product, inverse_lumped, corrections, z, corrected)
            factor = dtype(-step / k)
            for i in range(n):
                y[i] = z[i] * factor + start[i]
    return y


@numba.njit(cache=True, nogil=True, boundscheck=False)
def taylor_galerkin(indptr: np.ndarray, indices: np.ndarray, forward: np.ndarray, implicit: np.ndarray,
                    inverse_lumped: np.ndarray, phi: np.ndarray, substeps: int, corrections: int) -> np.ndarray:
    """``substeps`` third-order Taylor–Galerkin substeps of length h on a layout's positions,
    each

        Δ = P_B [F φ],   φ ← φ + Δ,

    F = −h (C + (h/2) S) (``forward``) and P_B r = Σ_{j≤K} (I − M_L⁻¹B)^j M_L⁻¹ r the lumped
    inverse of B = M + (h²/6) S (``implicit``) with K = ``corrections`` Jacobi corrections
    (``inverse_lumped`` = M_L⁻¹; S's rows sum to zero, so B lumps to M_L): the block-diagonal
    F and B share one CSR pattern (``indptr``, ``indices``: unsigned). Each product one
    compiled pass (:func:`_block_rows`), each vector update another, into arrays made once;
    in φ's precision: K + 1 products a substep."""
    n = np.uint64(phi.size)
    y = phi.copy()
    r = np.empty_like(phi)
    d = np.empty_like(phi)
    corrected = np.empty_like(phi)
    for _ in range(substeps):
        _block_rows(indptr, indices, forward, y, r, 0, n, False)
        _corrected_inverse(indptr, indices, implicit, r, inverse_lumped, corrections, d, corrected)
        for i in range(n):
            y[i] += d[i]
    return y


@numba.njit(cache=True, nogil=True, boundscheck=False)
def residual_start(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, inverse: np.ndarray, rhs: np.ndarray,
                   x: np.ndarray, r: np.ndarray, multiply: bool) -> tuple[float, float]:
    """A CG's start on a CSR matrix (unsigned index arrays): r = rhs − A x if ``multiply``
    (else ``r`` holds it already), in x's precision; returns (max|D⁻¹ rhs|, max|D⁻¹r|),
    ``inverse`` = D⁻¹. In two passes instead of numpy's seven and a scipy product."""
    n = np.uint64(x.size)
    if multiply:
        _block_rows(indptr, indices, data, x, r, 0, n, False)
        for i in range(n):
            r[i] = rhs[i] - r[i]
    scale = largest = x.dtype.type(0.0)
    for i in range(n):
        # a NaN stays, as in numpy's max: nothing compares above it
        scaled, residual = abs(inverse[i] * rhs[i]), abs(inverse[i] * r[i])
        if scaled > scale or scaled != scaled:
            scale = scaled
        if residual > largest or residual != residual:
            largest = residual
    return float(scale), float(largest)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def window_conjugate_gradient(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, offsets: np.ndarray,
                              inverse: np.ndarray, x: np.ndarray, r: np.ndarray, goal: float, maxiter: int,
                              iterations: np.ndarray) -> int:
    """Jacobi-preconditioned CG on each diagonal block of a block-diagonal CSR matrix (block
    w the rows and columns ``offsets[w]:offsets[w + 1]``), one block after the other, in
    place: ``x`` the start in and the solution out, ``r`` the start's residual in and the
    final one out. A block stops once its max|D⁻¹r| is at most ``goal`` (``inverse`` =
    D⁻¹); ``iterations[w]`` its iterations. Returns −1, or the first block w that did not
    stop in ``maxiter`` iterations, or −2 − w for one whose pᵀAp was not positive. Vectors
    in x's precision, sums of products in double.

    The index arrays and ``offsets`` are unsigned (views of scipy's int32 arrays): numba
    guards every signed index against wrapping around from the end, and with scipy's
    arrays as they are the product loop took 1.2–1.6× as long (10⁵ rows)."""
    dtype = x.dtype.type
    zero = dtype(0.0)
    p = np.zeros_like(x)
    q = np.empty_like(x)
    for w in range(offsets.size - 1):
        start, stop = offsets[w], offsets[w + 1]
        largest = zero
        rz = 0.0
        for i in range(start, stop):
            z = inverse[i] * r[i]
            p[i] = z
            rz += np.float64(r[i] * z)
            largest = max(largest, abs(z))
        count = 0
        while largest > goal:
            if count == maxiter:
                return w
            count += 1
            curvature = _block_rows(indptr, indices, data, p, q, start, stop, True)
            if not curvature > 0.0:
                return -2 - w
            # α and β in the vectors' precision: a double one made every float32 update a
            # double one, converted there and back (0.21 against 0.11 ms on 10⁵ positions)
            alpha = dtype(rz / curvature)
            largest = zero
            next_rz = 0.0
            for i in range(start, stop):
                x[i] += alpha * p[i]
                residual = r[i] - alpha * q[i]
                r[i] = residual
                z = inverse[i] * residual
                next_rz += np.float64(residual * z)
                largest = max(largest, abs(z))
            if largest <= goal:
                break
            beta = dtype(next_rz / rz)
            for i in range(start, stop):
                p[i] = inverse[i] * r[i] + beta * p[i]
            rz = next_rz
        iterations[w] = count
    return -1


@numba.njit(cache=True, nogil=True, boundscheck=False)
def jacobi_correction(z: np.ndarray, y: np.ndarray, product: np.ndarray, inverse: np.ndarray) -> None:
    """One Jacobi correction toward the solution of M z = y, in place: z += (y − M z) D⁻¹
    (``product`` = M z, ``inverse`` = D⁻¹), rounded as numpy's three passes round it."""
    for i in range(np.uint64(z.size)):
        z[i] += (y[i] - product[i]) * inverse[i]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def others_squared(squares: np.ndarray, node_index: np.ndarray, n_dofs: int) -> np.ndarray:
    """Σ_{j≠i} φ_j² at every position of a layout (``squares``: φ² by position, position p at
    the dof ``node_index[p]``): the sum over all positions at each dof, in double and in
    position order, rounded to φ's precision, minus the position's own square. Bitwise
    numpy's ``bincount``, ``take`` and subtraction, in two passes instead of five and no
    double-precision copy of the positions (0.16 against 0.28 ms on examples/straight_mesh.toml's
    10⁵ positions in float32)."""
    total = np.zeros(n_dofs)
    for p in range(node_index.size):
        total[node_index[p]] += squares[p]
    out = np.empty_like(squares)
    for p in range(node_index.size):
        out[p] = squares.dtype.type(total[node_index[p]]) - squares[p]
    return out


@numba.njit(cache=True, nogil=True, boundscheck=False)
def window_gradient_moments(indptr: np.ndarray, elements: np.ndarray, gx: np.ndarray, gy: np.ndarray,
                            area: np.ndarray, node_index: np.ndarray, offsets: np.ndarray, phi: np.ndarray,
                            slot: np.ndarray) -> np.ndarray:
    """(windows, 3): ∫(∂xφ)², ∫(∂yφ)², ∫∂xφ ∂yφ of every window's P1 field, exactly (∇φ is
    constant on each element). Window w holds positions ``offsets[w]:offsets[w + 1]``,
    position p the value ``phi[p]`` at the dof ``node_index[p]``; the field is zero at every
    other dof. The gradient by dof (CSC): the elements around a dof,
    ``elements[indptr[dof]:indptr[dof + 1]]``, and its hat function's gradient on each
    (``gx``, ``gy``); ``area`` per element. ``slot`` (n_elements,) is scratch, all −1, and
    left so. Sums in double whatever φ's precision."""
    n = offsets.size - 1
    out = np.zeros((n, 3))
    touched = np.empty(elements.size, dtype=np.int64)
    ax = np.empty(elements.size)
    ay = np.empty(elements.size)
    for window in range(n):
        count = 0
        for p in range(offsets[window], offsets[window + 1]):
            dof = node_index[p]
            value = float(phi[p])
            for k in range(indptr[dof], indptr[dof + 1]):
                element = elements[k]
                s = slot[element]
                if s < 0:
                    s = count
                    slot[element] = s
                    touched[s] = element
                    ax[s] = 0.0
                    ay[s] = 0.0
                    count += 1
                ax[s] += value * gx[k]
                ay[s] += value * gy[k]
        xx = yy = xy = 0.0
        for s in range(count):
            element = touched[s]
            weight = area[element]
            xx += weight * ax[s] * ax[s]
            yy += weight * ay[s] * ay[s]
            xy += weight * ax[s] * ay[s]
            slot[element] = -1
        out[window, 0], out[window, 1], out[window, 2] = xx, yy, xy
    return out
