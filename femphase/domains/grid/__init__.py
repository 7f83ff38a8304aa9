"""The structured channel, ``[domain] kind = "grid"``: a lattice of nodes of spacing h,
periodic in x, with rectangular windows and exact fast paths.

``domain``     :class:`~femphase.domains.grid.domain.GridDomain`, registered as "grid"
``lattice``    the node lattice and its triangulations (:class:`~femphase.domains.grid.lattice.ChannelGrid`)
``windows``    rectangular windows, their policy and layout
``advection``  exact row shifts and the semi-Lagrangian step
``kernels``    compiled loops over the windows' rows (numba, imported on first use)
"""

from femphase.domains.grid.domain import GridDomain

__all__ = ["GridDomain"]
