"""Periodic identification of degrees of freedom by geometry.

A periodic problem is assembled on an ordinary (non-periodic) mesh whose two
opposite sides carry matching nodes.  The dofs on the "max" side are then
identified with their partners on the "min" side:

* :func:`periodic_dof_map` finds, for every dof location, the index of its
  representative (itself, or its partner on the min side);
* :func:`fold_matrix` turns that map into the 0/1 matrix ``P`` with which a
  system assembled on the non-periodic mesh folds into the periodic one,
  ``A_per = P.T @ A @ P``, ``b_per = P.T @ b``, and a periodic solution
  unfolds back onto every dof, ``x = P @ x_per``.

Points follow the scikit-fem convention: an array of shape ``(dim, n)``, one
column per point, as in ``mesh.p`` and ``basis.doflocs``.  Coordinates and
tolerances are in the mesh's length unit.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

__all__ = ["fold_matrix", "periodic_dof_map"]

# how many unmatched points an error message lists before eliding the rest
_SHOWN = 5


def periodic_dof_map(
    points: np.ndarray,
    period: float,
    axis: int = 0,
    tol: float | None = None,
) -> np.ndarray:
    """Map every point to its periodic representative.

    Parameters
    ----------
    points
        Dof locations, shape ``(dim, n)`` (scikit-fem's ``mesh.p`` /
        ``basis.doflocs`` layout).
    period
        Length of the period along `axis`; the min side is at
        ``points[axis].min()`` and the max side at that plus `period`.
    axis
        The periodic direction (0 for x).
    tol
        Matching tolerance, in length units, both for "lies on a side" and for
        "same position in the other coordinates" (max norm).  Defaults to
        ``1e-8 * period``.

    Returns
    -------
    np.ndarray
        Integer array ``dof_map`` of length ``n``: ``dof_map[k]`` is the index
        of the min-side partner when point ``k`` lies on the max side,
        otherwise ``k``.

    Raises
    ------
    ValueError
        If `points` is not ``(dim, n)``, `period` is not positive, or a point
        on either side has no partner (or shares one) on the other side.
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or not 0 <= axis < points.shape[0]:
        raise ValueError(
            f"points must have shape (dim, n) with axis < dim; got shape "
            f"{points.shape} and axis={axis}"
        )
    if not period > 0:
        raise ValueError(f"period must be positive; got {period}")
    tol = 1e-8 * period if tol is None else tol

    along = points[axis]
    across = np.delete(points, axis, axis=0).T
    low = np.flatnonzero(np.abs(along - along.min()) <= tol)
    high = np.flatnonzero(np.abs(along - (along.min() + period)) <= tol)

    partner = _nearest_within(across[low], across[high], tol)
    _raise_if_unmatched(points, high, partner == len(low), "max", tol)
    back = _nearest_within(across[high], across[low], tol)
    _raise_if_unmatched(points, low, back == len(high), "min", tol)
    # a bijection needs both directions to agree: two max-side points
    # matching one min-side point would silently merge distinct dofs
    one_to_one = len(low) == len(high) and np.all(
        back[partner] == np.arange(len(high))
    )
    if not one_to_one:
        raise ValueError(
            f"periodic matching is not one-to-one at tolerance {tol:g}: "
            f"{len(low)} points on the min side and {len(high)} on the max "
            f"side along axis {axis}, some sharing a partner"
        )

    dof_map = np.arange(points.shape[1])
    dof_map[high] = low[partner]
    return dof_map


def fold_matrix(dof_map: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Build the folding matrix of a periodic dof map.

    Parameters
    ----------
    dof_map
        Output of :func:`periodic_dof_map` (or a concatenation of such maps
        for several fields, in global numbering).

    Returns
    -------
    P : scipy.sparse.csr_matrix
        Shape ``(n, n_unique)``, ``P[k, compact[k]] = 1`` and zero elsewhere,
        where ``n_unique`` is the number of distinct representatives.
    compact : np.ndarray
        Length ``n``: the periodic (compact) index of every original dof.
        Compact indices number the representatives in increasing order of
        their original index, so ``compact[D]`` translates dof sets such as
        Dirichlet dofs into the periodic numbering.
    """
    dof_map = np.asarray(dof_map)
    representatives, compact = np.unique(dof_map, return_inverse=True)
    n = len(dof_map)
    P = sp.csr_matrix(
        (np.ones(n), (np.arange(n), compact)),
        shape=(n, len(representatives)),
    )
    return P, compact


def _nearest_within(
    targets: np.ndarray, queries: np.ndarray, tol: float
) -> np.ndarray:
    """Index of the nearest target to each query (max norm), or
    ``len(targets)`` when none lies within `tol`."""
    if len(queries) == 0:
        return np.zeros(0, dtype=int)
    if len(targets) == 0:
        return np.full(len(queries), len(targets))
    _, index = cKDTree(targets).query(
        queries, p=np.inf, distance_upper_bound=tol
    )
    return index


def _raise_if_unmatched(
    points: np.ndarray,
    side: np.ndarray,
    unmatched: np.ndarray,
    name: str,
    tol: float,
) -> None:
    if not np.any(unmatched):
        return
    bad = points[:, side[unmatched]].T
    shown = ", ".join(
        "(" + ", ".join(f"{c:.6g}" for c in p) + ")" for p in bad[:_SHOWN]
    )
    more = f" and {len(bad) - _SHOWN} more" if len(bad) > _SHOWN else ""
    raise ValueError(
        f"{len(bad)} of {len(side)} points on the {name} side have no "
        f"periodic partner within tolerance {tol:g}: {shown}{more}"
    )
