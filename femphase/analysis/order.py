"""Order observables of a frame: Ψ6, Ψ2^L, the lattice angle and the running T1 count.

ψ6_j = mean over the periodic-Delaunay neighbours k of e^{6iθ_jk} (bond angles) and
ψ2_j = mean of e^{2i(θ_j − θ_k)} (elongation axes; e^{2iθ}, see DEVELOPERS.md);
Ψ6 = |mean_j ψ6_j|, Ψ2 = |mean_j ψ2_j| for the frame (the paper's ⟨·⟩ over frames is taken
by the analysis of a run, :func:`femphase.analysis.lattice.frame_average`).
"""

from __future__ import annotations

import numpy as np

from .lattice import (
    T1Counter, bond_order, global_order, lattice_angle, nematic_order, periodic_delaunay_pairs,
)
from .shape import ShapeObservables


class OrderObserver:
    """Computes the order observables frame after frame; keeps the T1 count of the run."""

    def __init__(self, period_x: float, snapshot: dict[str, np.ndarray] | None = None) -> None:
        self.period_x = period_x
        # a resumed run continues the T1 count (and its pending flips) of the checkpoint
        self.t1: T1Counter | None = T1Counter.restore(snapshot, period_x) if snapshot else None

    def snapshot(self) -> dict[str, np.ndarray]:
        """What a checkpoint keeps to continue the T1 count (empty before the first frame)."""
        return self.t1.snapshot() if self.t1 is not None else {}

    def __call__(self, shape: ShapeObservables) -> dict:
        centroids = np.stack([shape.x, shape.y], axis=1)
        n = len(centroids)
        if n < 3:
            nan = np.full(n, np.nan + 0j)
            return {"psi6": nan, "psi2": nan, "Psi6": np.nan, "Psi2": np.nan, "lattice_angle": np.nan, "t1_count": 0}
        pairs = periodic_delaunay_pairs(centroids, self.period_x)
        if self.t1 is None:
            self.t1 = T1Counter(centroids, self.period_x)
        else:
            self.t1.update(centroids)
        psi6 = bond_order(centroids, self.period_x, pairs)
        psi2 = nematic_order(shape.orientation, pairs, n)
        return {
            "psi6": psi6,
            "psi2": psi2,
            "Psi6": global_order(psi6),
            "Psi2": global_order(psi2),
            "lattice_angle": lattice_angle(centroids, self.period_x, pairs),
            "t1_count": self.t1.count,
        }
