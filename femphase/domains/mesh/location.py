"""Point location on a triangulation: which triangle holds each of many points."""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree
from skfem import MeshTri

__all__ = ["barycentric", "centroid_tree", "locate"]

#: Triangles with the nearest centroids checked first for each point.
NEAREST = 6


def locate(mesh: MeshTri, points: np.ndarray, tree: cKDTree | None = None) -> np.ndarray:
    """The triangle containing each point (2, n), or −1 outside the mesh.

    Checks the barycentric coordinates in the 6 triangles with the nearest centroids, which
    hold almost every point of a Delaunay mesh, then, for the points they miss, in every
    triangle whose centroid lies within the largest distance from a centroid to its own
    corners: a triangle that holds a point is among those, however stretched it is (in a
    boundary layer of 4 × 0.125 cells, a fifth of the points lie in none of the 12 nearest).
    ``tree``: the centroids' k-d tree (:func:`centroid_tree`), for callers that locate often.
    """
    corners = mesh.p[:, mesh.t]  # (2, 3, n_elements)
    tree = centroid_tree(mesh) if tree is None else tree
    found = _locate_among(corners, tree, points, min(NEAREST, mesh.t.shape[1]))
    missed = np.flatnonzero(found < 0)
    if missed.size:
        found[missed] = _locate_within_reach(corners, tree, points[:, missed])
    return found


def centroid_tree(mesh: MeshTri) -> cKDTree:
    """The k-d tree of the triangles' centroids (:func:`locate`)."""
    return cKDTree(mesh.p[:, mesh.t].mean(axis=1).T)


def barycentric(a: np.ndarray, b: np.ndarray, c: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s, t): the coordinates of ``points`` in the triangles with corners a, b, c (each
    (2, …), broadcasting), points = a + s (b − a) + t (c − a); their weights are 1 − s − t, s, t."""
    e1, e2, d = b - a, c - a, points - a
    det = e1[0] * e2[1] - e1[1] * e2[0]
    return (d[0] * e2[1] - d[1] * e2[0]) / det, (e1[0] * d[1] - e1[1] * d[0]) / det


def _locate_among(corners: np.ndarray, tree: cKDTree, points: np.ndarray, candidates: int) -> np.ndarray:
    _, near = tree.query(points.T, k=candidates)
    near = near.reshape(points.shape[1], candidates)
    inside = _holds(corners, near, points[:, :, None])  # (n, candidates)
    found = inside.any(axis=1)
    return np.where(found, near[np.arange(len(near)), inside.argmax(axis=1)], -1)


def _locate_within_reach(corners: np.ndarray, tree: cKDTree, points: np.ndarray) -> np.ndarray:
    """Exact location among the triangles whose centroid is within the mesh's largest
    centroid-to-corner distance of each point."""
    reach = float(np.sqrt(((corners - corners.mean(axis=1, keepdims=True)) ** 2).sum(axis=0)).max())
    near_lists = tree.query_ball_point(points.T, reach * (1 + 1e-9))
    counts = np.fromiter(map(len, near_lists), dtype=np.int64, count=len(near_lists))
    near = np.fromiter(itertools.chain.from_iterable(near_lists), dtype=np.int64, count=int(counts.sum()))
    owner = np.repeat(np.arange(len(near_lists)), counts)
    inside = _holds(corners, near, points[:, owner])
    found = np.full(points.shape[1], -1)
    found[owner[inside]] = near[inside]
    return found


def _holds(corners: np.ndarray, elements: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Whether each of ``elements`` holds its point (broadcasting), edges included."""
    s, t = barycentric(*(corners[:, k][:, elements] for k in range(3)), points)
    eps = 1e-12
    return (s >= -eps) & (t >= -eps) & (s + t <= 1 + eps)
