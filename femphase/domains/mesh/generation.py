"""Channel meshes in pure Python (no external mesher): Delaunay triangulations of point sets.

:func:`delaunay_channel` meshes the channel ``0 ≤ x ≤ length`` between a bottom wall
y = bottom(x) and a top wall y = top(x), optionally around circular obstacles:

1. boundary nodes at the target edge length along the walls (by arc length), the obstacles'
   circles and the two sides x = 0 and x = length, the two sides with identical y (so they
   match periodically; the walls must have equal heights at both ends);
2. interior nodes from a hexagonal lattice of the target edge length, rotated by a random
   angle and jittered (so no mesh direction lines up with the channel), keeping those at
   least ``clearance`` edge lengths from every boundary node;
3. scipy's Delaunay triangulation of all nodes, minus the triangles whose centroid lies
   outside the domain (below the bottom, above the top wall, inside an obstacle);
4. checks: every boundary segment is an edge of the mesh (else the walls were not
   recovered: use a smaller edge length), no triangle is degenerate.

The lattice's node density equals the structured grid's at spacing h when the edge length is
``h·sqrt(2/√3)`` (:func:`edge_for_spacing`), so "h = 1" meshes have one node per unit area
like the structured channel. Boundary names: ``left``, ``right``, ``bottom``, ``top``,
``obstacle`` (:data:`femphase.domains.mesh.domain.BOUNDARY_TAGS`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.spatial import Delaunay, cKDTree
from skfem import MeshTri

from femphase.domains.grid.lattice import channel_grid, structured_channel_mesh
from femphase.domains.mesh.domain import channel_sides, facet_indices

__all__ = ["delaunay_channel", "edge_for_spacing", "mesh_quality", "structured_channel"]

Wall = Callable[[np.ndarray], np.ndarray]


def edge_for_spacing(h: float) -> float:
    """Edge length of a hexagonal lattice with one node per h² of area."""
    return h * np.sqrt(2.0 / np.sqrt(3.0))


def structured_channel(length: float, height: float, h: float) -> tuple[MeshTri, dict[str, np.ndarray]]:
    """femphase's structured channel mesh (right diagonals) with named boundaries."""
    mesh = structured_channel_mesh(channel_grid(length, height, h))
    sides = channel_sides(mesh)
    walls = sides.pop("wall")
    low = mesh.p[1, mesh.facets[0, walls]] < 0.5 * height
    return mesh, {**sides, "bottom": walls[low], "top": walls[~low]}


def delaunay_channel(
    length: float,
    edge: float,
    bottom: Wall,
    top: Wall,
    *,
    obstacles: Sequence[tuple[float, float, float]] = (),
    jitter: float = 0.15,
    clearance: float = 0.6,
    seed: int = 0,
) -> tuple[MeshTri, dict[str, np.ndarray]]:
    """Mesh of the channel between ``bottom`` and ``top`` (vectorised y(x)), periodic in x.

    edge        target edge length
    obstacles   circles (cx, cy, radius) inside the channel
    jitter      random displacement of the interior lattice nodes, in edge lengths
    clearance   interior nodes keep this many edge lengths from boundary nodes
    """
    x_ends = np.array([0.0, length])
    for name, wall in (("bottom", bottom), ("top", top)):
        ends = wall(x_ends)
        if not np.isclose(ends[0], ends[1]):
            raise ValueError(f"the {name} wall must have equal heights at x = 0 and x = {length} "
                             f"(periodic); got {ends[0]} and {ends[1]}")
    chains = {
        "bottom": _curve(lambda s: np.stack([s, bottom(s)]), 0.0, length, edge),
        "top": _curve(lambda s: np.stack([s, top(s)]), 0.0, length, edge),
    }
    y_low, y_high = bottom(x_ends[:1])[0], top(x_ends[:1])[0]
    side = _curve(lambda s: np.stack([np.zeros_like(s), s]), y_low, y_high, edge)
    chains["left"] = side
    chains["right"] = side + np.array([[length], [0.0]])
    holes = [_curve(lambda s, c=c: np.stack([c[0] + c[2] * np.cos(s), c[1] + c[2] * np.sin(s)]),
                    0.0, 2 * np.pi, edge, closed=True) for c in obstacles]

    boundary = np.hstack(list(chains.values()) + holes)
    rng = np.random.default_rng(seed)
    interior = _lattice(length, min(y_low, bottom(np.linspace(0, length, 200)).min()),
                        top(np.linspace(0, length, 200)).max(), edge, jitter, rng)
    keep = _inside(interior, bottom, top, obstacles, length)
    near, _ = cKDTree(boundary.T).query(interior[:, keep].T)
    interior = interior[:, keep][:, near >= clearance * edge]

    points, index = np.unique(np.round(np.hstack([boundary, interior]), 12), axis=1, return_inverse=True)
    index = index.ravel()
    triangles = Delaunay(points.T).simplices.T
    centroids = points[:, triangles].mean(axis=1)
    triangles = triangles[:, _inside(centroids, bottom, top, obstacles, length)]
    used, renumbered = np.unique(triangles, return_inverse=True)
    mesh = MeshTri(np.ascontiguousarray(points[:, used]),
                   np.ascontiguousarray(renumbered.reshape(triangles.shape)))
    new = np.full(points.shape[1], -1)
    new[used] = np.arange(used.size)

    boundaries, offset = {}, 0
    segments = {name: chain.shape[1] for name, chain in chains.items()}
    segments.update({f"obstacle{k}": h.shape[1] for k, h in enumerate(holes)})
    for name, count in segments.items():
        ids = new[index[offset:offset + count]]
        offset += count
        closed = name.startswith("obstacle")
        pairs = np.stack([ids, np.roll(ids, -1)]) if closed else np.stack([ids[:-1], ids[1:]])
        if (pairs < 0).any():
            raise ValueError(f"boundary nodes of {name!r} lost all triangles: use a smaller edge length")
        try:
            facets = facet_indices(mesh, pairs)
        except ValueError as exc:
            raise ValueError(f"the {name!r} boundary was not recovered by the triangulation "
                             f"(use a smaller edge length or a larger clearance): {exc}") from None
        key = "obstacle" if closed else name
        boundaries[key] = np.union1d(boundaries.get(key, np.zeros(0, int)), facets)
    unnamed = np.setdiff1d(mesh.boundary_facets(), np.concatenate(list(boundaries.values())))
    if unnamed.size:
        raise ValueError(f"{unnamed.size} boundary facets belong to no boundary: triangles "
                         "were lost inside the domain (use a smaller edge length)")
    return mesh, boundaries


def mesh_quality(mesh: MeshTri) -> dict[str, float]:
    """Smallest and median interior angle (degrees), edge lengths, and node/element counts."""
    p = mesh.p[:, mesh.t]
    angles = []
    for k in range(3):
        a, b, c = p[:, k], p[:, (k + 1) % 3], p[:, (k + 2) % 3]
        u, v = b - a, c - a
        cos = (u * v).sum(0) / np.hypot(*u) / np.hypot(*v)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    angles = np.concatenate(angles)
    ends = mesh.p[:, mesh.facets]
    edges = np.hypot(*(ends[:, 1] - ends[:, 0]))
    return {"nodes": int(mesh.p.shape[1]), "triangles": int(mesh.t.shape[1]),
            "min_angle": float(angles.min()), "median_angle": float(np.median(angles)),
            "max_angle": float(angles.max()),
            "min_edge": float(edges.min()), "median_edge": float(np.median(edges)), "max_edge": float(edges.max())}


def _curve(point: Callable[[np.ndarray], np.ndarray], start: float, stop: float, step: float,
           closed: bool = False) -> np.ndarray:
    """Nodes along the parametrised curve point(s), s from start to stop, equally spaced by
    arc length at about ``step``; a closed curve does not repeat its first node."""
    fine = np.linspace(start, stop, 4000)
    xy = point(fine)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=1)))])
    count = max(3 if closed else 1, int(np.ceil(arc[-1] / step)))
    targets = np.linspace(0.0, arc[-1], count + 1)
    return point(np.interp(targets[:-1] if closed else targets, arc, fine))


def _lattice(length: float, y_low: float, y_high: float, edge: float, jitter: float,
             rng: np.random.Generator) -> np.ndarray:
    """A jittered hexagonal lattice, rotated by a random angle, covering the bounding box."""
    angle = rng.uniform(0, np.pi / 3)
    size = np.hypot(length, y_high - y_low)
    n = int(np.ceil(size / edge)) + 2
    i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1))
    u = edge * (i + 0.5 * j)
    v = edge * np.sqrt(3) / 2 * j
    c, s = np.cos(angle), np.sin(angle)
    x = 0.5 * length + c * u - s * v
    y = 0.5 * (y_low + y_high) + s * u + c * v
    points = np.stack([x.ravel(), y.ravel()])
    points = points[:, (points[0] > 0) & (points[0] < length) & (points[1] > y_low) & (points[1] < y_high)]
    return points + jitter * edge * rng.uniform(-1, 1, points.shape)


def _inside(points: np.ndarray, bottom: Wall, top: Wall, obstacles, length: float) -> np.ndarray:
    x, y = points
    inside = (x > 0) & (x < length) & (y > bottom(x)) & (y < top(x))
    for cx, cy, r in obstacles:
        inside &= np.hypot(x - cx, y - cy) > r
    return inside
