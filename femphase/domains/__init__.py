"""Domains: where the phase fields live, and what a time step asks of them.

A domain is a P1 space on a channel periodic in x with Neumann walls (the interface:
:class:`femphase.domains.base.Domain`); a window is the set of dofs one particle's field is
computed on, and a layout puts all windows in one flat vector
(:class:`femphase.domains.layout.Layout`). Two kinds, each a subpackage that registers
itself in :data:`DOMAINS` under the scene's ``[domain] kind``:

``grid``  the structured channel (:mod:`femphase.domains.grid`): rectangular windows of the
          node lattice, the exact tensor-product solver, exact row-shift advection
``mesh``  any meshio triangle mesh (:mod:`femphase.domains.mesh`): box windows,
          Galerkin advection, Stokes flows, mesh generation and files

Importing this package registers both (the grid first: registries list their entries, and
``docs/scenes.md`` documents them, in registration order).
"""

from __future__ import annotations

from pathlib import Path

from femphase.config import Numerics
from femphase.domains import grid, mesh  # noqa: F401  (register the two kinds, the grid first)
from femphase.domains.base import DOMAINS, Domain
from femphase.domains.layout import Layout

__all__ = ["DOMAINS", "Domain", "Layout", "domain_from_table"]


def domain_from_table(table: dict, base_dir: str | Path, numerics: Numerics) -> Domain:
    """The domain a scene's ``[domain]`` table describes (``kind`` names it, default "grid"),
    its caches' budget ``numerics.cache_mib``."""
    cls = DOMAINS.get(table.get("kind", "grid"))
    domain = cls.from_table(table, Path(base_dir), numerics)
    domain.caches.limit = int(numerics.cache_mib * 2**20)
    return domain
