"""Triangle meshes from and to files, through meshio (gmsh ``.msh``, ``.vtu``, ``.xdmf``, …).

:func:`load_mesh` reads a file into a scikit-fem :class:`~skfem.MeshTri` (first-order
triangles; lengths in the file's unit, lattice units for femphase scenes),
:func:`save_mesh` writes one, :func:`read_meshio` reads any file meshio knows and turns
meshio's failures into one :class:`~femphase.errors.SceneError` naming the file. Named
boundaries and periodic pairs are the meshed domain's (:mod:`femphase.domains.mesh.domain`).
"""

from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path

import meshio
import numpy as np
from skfem import MeshTri

from femphase.errors import SceneError

__all__ = ["load_mesh", "read_meshio", "save_mesh"]


def save_mesh(mesh: MeshTri, path: str | Path) -> None:
    """Write a non-periodic triangular mesh in any format meshio knows by the file's suffix."""
    points = np.vstack([mesh.p, np.zeros(mesh.p.shape[1])]).T
    meshio.write(path, meshio.Mesh(points, [("triangle", mesh.t.T)]))


def read_meshio(path: str | Path) -> meshio.Mesh:
    """meshio.read, with a SceneError (key domain.mesh) naming the reason on any failure.

    meshio's readers raise many types on a damaged file, and some call ``sys.exit``; every
    one of them (SystemExit included, KeyboardInterrupt excepted) becomes the SceneError."""
    path = Path(path)
    if not path.is_file():
        raise SceneError("domain.mesh", str(path), "a mesh file that exists")
    said = io.StringIO()  # meshio prints its readers' reasons, then exits: keep them for the message
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            data = meshio.read(path)
    except (Exception, SystemExit) as exc:  # the user needs only the reason
        printed = " ".join(said.getvalue().split())  # one line, whatever the console's wrapping
        if isinstance(exc, SystemExit) or not str(exc):
            reason = printed[-400:] or type(exc).__name__
        else:
            reason = f"{type(exc).__name__}: {exc}"
        raise SceneError("domain.mesh", str(path), f"a mesh file meshio can read ({reason})") from None
    if said.getvalue().strip():  # meshio's gmsh reader prints an empty line on every read
        sys.stderr.write(said.getvalue())  # meshio's warnings about a file it did read
    if not isinstance(data, meshio.Mesh) or np.ndim(getattr(data, "points", None)) != 2:
        raise SceneError("domain.mesh", str(path), "a mesh file meshio can read (it holds no points)")
    return data


def load_mesh(path: str | Path) -> MeshTri:
    """Read a 2D triangular mesh with meshio (gmsh .msh, .vtu, .xdmf, …)."""
    data = read_meshio(path)
    triangles = [block.data for block in data.cells if block.type == "triangle"]
    if not triangles:
        raise SceneError("domain.mesh", str(path), "a mesh with triangle cells")
    try:
        points = np.asarray(data.points, dtype=float)
        triangles = np.vstack(triangles).astype(np.int64)
        if points.ndim != 2 or points.shape[1] < 2 or not np.isfinite(points).all():
            raise ValueError("the points are not finite (x, y) coordinates")
        if triangles.size and (triangles.min() < 0 or triangles.max() >= len(points)):
            raise ValueError("triangles refer to points that are not in the file")
        return MeshTri(points[:, :2].T.copy(), triangles.T.copy())
    except Exception as exc:
        raise SceneError("domain.mesh", str(path), f"a triangle mesh ({exc})") from None
