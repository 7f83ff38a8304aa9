"""Shaped windows of any mesh: the dofs within a reach of their particle.

A box window (:mod:`femphase.domains.mesh.boxes`) holds every dof of an axis-aligned box
around its particle; around a tilted, elongated particle most of them lie far from it. A
:class:`Shape` holds the dofs within ``margin + room`` of the set it was made for (the dofs
where φ > threshold at its making), distances measured along the mesh's edges
(:func:`~femphase.domains.mesh.kernels.dilate`), and every dof's distance to that set. It
fits while every dof where φ > threshold lies within ``room`` of that set, so that the
margin around the particle holds (:class:`ShapePolicy`). What a window is and why its system
is a principal submatrix: :mod:`femphase.domains.layout`.

On examples/straight_mesh.toml under flow the shapes hold three quarters of the boxes'
positions (docs/decisions/0057-shaped-mesh-windows.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Shape", "ShapePolicy"]


class Shape:
    """A window made of ``dofs`` (sorted, int64), with each dof's distance (length) to the
    set it was made for in ``distances`` (0 on the set) and ``reach``, how far beyond that
    set it was made to reach. ``serial`` numbers the shapes of a domain in the order they
    were made and orders them in a layout, so that a run resumed from a checkpoint, which
    stores it, lays its windows out as the run did. Shapes are equal when they are one
    shape: the same serial, dofs, distances and reach."""

    __slots__ = ("serial", "dofs", "distances", "reach")

    def __init__(self, serial: int, dofs: np.ndarray, distances: np.ndarray, reach: float) -> None:
        self.serial, self.dofs, self.distances, self.reach = serial, dofs, distances, reach

    def __eq__(self, other: object) -> bool:
        if self is other:
            return True
        return (isinstance(other, Shape) and self.serial == other.serial and self.reach == other.reach
                and np.array_equal(self.dofs, other.dofs) and np.array_equal(self.distances, other.distances))

    def __hash__(self) -> int:
        return hash(self.serial)

    def __lt__(self, other: "Shape") -> bool:
        return self.serial < other.serial

    def __repr__(self) -> str:
        return f"Shape({self.serial}, {self.dofs.size} dofs, reach {self.reach:g})"


@dataclass(frozen=True)
class ShapePolicy:
    """How shapes follow their fields (lengths in the mesh's unit).

    =========== ============================================================================
    threshold   φ above which a node belongs to the particle (the paper: 0.01)
    margin      length kept between the particle and the shape's edge (the paper: 4 sites)
    room        extra length a shape reaches beyond the margin: it fits while every dof
                where φ > threshold lies within ``room`` of the set it was made for
    early       when any shape must be made anew, every shape whose particle has moved
                more than ``room − early`` from its set is made anew with it, so that
                shapes change together in fewer layouts
    enabled     always True: a mesh without windows runs on the whole-domain box
    =========== ============================================================================

    Why ``early``: windows solved all at once (:mod:`femphase.fem.blocks`) build their block
    matrices for every new layout, whether one window changed or all. On
    examples/straight_mesh.toml under flow (400 time units of relaxation, then 800 of flow at
    max_velocity 0.1) shapes with room 2 made at one substep out of every one to two, 240
    layouts; refitted one spacing early, 63 layouts, with nearly every shape made anew at each
    (docs/decisions/0057-shaped-mesh-windows.md).
    """

    threshold: float = 0.01
    margin: float = 4.0
    room: float = 2.0
    early: float = 1.0
    enabled: bool = True

    #: ``room`` and ``early`` in spacings (docs/decisions/0057-shaped-mesh-windows.md)
    ROOM_SPACINGS = 2.0
    EARLY_SPACINGS = 1.0

    @classmethod
    def for_spacing(cls, h: float, *, threshold: float = 0.01, margin: float = 4.0) -> "ShapePolicy":
        """The policy at mesh spacing h: the margin rounded up to whole spacings, as the
        boxes' (:meth:`~femphase.domains.mesh.boxes.BoxPolicy.for_spacing`)."""
        margin = h * math.ceil(margin / h - 1e-9)
        return cls(threshold=threshold, margin=margin, room=cls.ROOM_SPACINGS * h, early=cls.EARLY_SPACINGS * h)

    def reach(self) -> float:
        """How far a shape made now reaches beyond its set (the set swept along the particle's
        motion over the coming span, where a fast flow asks for it): ``margin + room``."""
        return self.margin + self.room

    def to_remake(self, moved: np.ndarray, reaches: np.ndarray, motion: np.ndarray | float = 0.0) -> np.ndarray:
        """Which shapes to make anew, given how far each particle's set has ``moved`` from
        the set its shape was made for (the largest distance of a dof where φ > threshold,
        :func:`~femphase.domains.mesh.kernels.largest_made_distance`), the shapes' ``reaches``
        and the lengths of the particles' ``motion`` over the coming span: none while every
        one has moved less than its room, ``reach − margin − motion``, else every one within
        ``early`` of it (a particle that the flow carries past its room within the span
        gets a shape swept along that motion)."""
        room = reaches - self.margin - motion
        if not (moved > room).any():
            return np.zeros(moved.shape, dtype=bool)
        return moved > room - self.early
