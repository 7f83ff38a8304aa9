"""Observables of phase-field states and run directories.

``shape``   per-particle centroid, area, shape tensor, elongation and orientation
``lattice`` periodic Delaunay neighbours, bond and nematic order, lattice angle, T1 events
``periods`` period of a shape oscillation and the (r, 2θ) limit cycle
``observables``  the frame observables a run computes by name (``output.observables``)
"""
