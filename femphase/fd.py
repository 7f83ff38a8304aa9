"""The paper's finite-difference scheme for the same model: an independent reference.

Space: the square lattice of the mesh nodes (spacing h), every particle's field on its own
window (the same :class:`~femphase.windows.WindowPolicy` as the finite-element stepper,
refitted after every step, data moved with :func:`~femphase.windows.transfer`). Derivatives
are array stencils on the window arrays, padded by :func:`~femphase.windows.pad_window`:
mirrored at the walls (∂yφ = 0), periodic across the seam of a full-width window, zero
beyond a window's artificial edge. They never touch the finite-element matrices, so
comparing the two methods is a real cross-check.

* Laplacian: the 5-point stencil (φ_E + φ_W + φ_N + φ_S − 4φ)/h².
* Potential terms: :func:`femphase.energy.explicit_derivative` at the nodes (shared model
  code); ∫φ² by the nodal quadrature (the trapezoid rule: weight h², h²/2 on the walls,
  which is the lumped mass of the structured mesh); Σ_{j≠i} φ_j² summed over the nodes
  where windows overlap (elsewhere it is zero).
* Advection v·∇φ: third-order upwind-biased differences in each direction,

      u ∂xφ ≈ u (φ_{i−2} − 8φ_{i−1} + 8φ_{i+1} − φ_{i+2})/(12h)
            + |u| (φ_{i−2} − 4φ_{i−1} + 6φ_i − 4φ_{i+1} + φ_{i+2})/(12h),

  i.e. the fourth-order central difference plus a fourth-difference dissipation |u|h³/12
  ∂x⁴φ that makes it upwind (for u > 0 the stencil is (φ_{i−2} − 6φ_{i−1} + 3φ_i +
  2φ_{i+1})/(6h)). Why not central differences: their symbol is purely imaginary, and
  Heun's stability region touches the imaginary axis only at 0, so central advection
  grows every mode (|amplification|² = 1 + (ω dt)⁴/4) unless the diffusion happens to damp
  it; the paper's cell Péclet number |u|h/D reaches ~1–8, so that cannot be relied on.
  Second-order upwind is stable too, but its leading error is dispersive and O(h²),
  (h²/3) u ∂x³φ, against the third-order scheme's dissipative (h³/12) |u| ∂x⁴φ; the
  interface (width ~2λ = 4 at h = 1) is only a few nodes wide, so the order matters.
  Row flows (u(y), 0) and general flows share the code: each velocity component is
  differenced along its own direction. ``numerics.fd_advection = "upwind1"`` selects
  first-order upwind instead (numerical diffusion |u| h/2), to test how much a cruder
  advection, which the paper does not exclude, changes the physics.
* Time: explicit predictor–corrector (Heun, second order), the paper's dt = 0.1 by default:

      k1 = f(φⁿ, tⁿ),  φ* = φⁿ + dt k1,  k2 = f(φ*, tⁿ⁺¹),  φⁿ⁺¹ = φⁿ + dt (k1 + k2)/2,
      f(φ, t) = −v·∇_h φ − J0 g(φ) + J0 2γλ Δ_h φ + s(x, y, t).

Stability (:func:`explicit_stability_limit`, enforced by the constructor): Heun's stability
region contains [−2, 0] on the real axis and, for third-order upwind advection, Courant
numbers up to ≈ 0.87 (von Neumann; ``tests/test_fd.py`` checks the combined symbol).
The region is convex, so a step is stable when twice each part's spectrum lies inside it:

    dt (8 J0 2γλ/h² + J0 L) ≤ 1        (diffusion + the explicit curvature bound L of
                                         :func:`femphase.model.explicit_curvature_bound`)
    dt (max|u| + max|v|)/h  ≤ 0.4      (advection Courant number)

At the paper's parameters and h = 1 the first gives dt ≤ 0.32 (so dt = 0.1 is safe); at
h = 0.5, dt ≤ 0.17; at h = 0.25, dt ≤ 0.057: the diffusion limit ∝ h² takes over below h ≈ 0.5.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .energy import explicit_derivative
from .errors import SceneError
from .flows import Flow, no_flow
from .mesh import ChannelGrid
from .model import ModelParameters, explicit_curvature_bound
from .state import State
from .stepping import Discretisation, Numerics, check_fields
from .windows import Layout, Window, WindowPolicy, pad_window, transfer

#: Largest dt·(diffusion + reaction spectral radius): half of Heun's real-axis limit 2.
DIFFUSION_NUMBER = 1.0
#: Largest advective Courant number dt (max|u| + max|v|)/h: about half of the ≈ 0.87 at
#: which Heun with third-order upwind differences becomes unstable.
COURANT_NUMBER = 0.4
#: Nodes of padding the widest stencil (the advection's φ_{i±2}) needs.
_PAD = 2


def explicit_stability_limit(
    params: ModelParameters, h: float, speed: float = 0.0, smallest_radius: float | None = None
) -> float:
    """The largest dt (time units) the finite-difference stepper accepts.

    ``speed`` is max|u| + max|v| of the flow over the nodes (lattice units per time unit),
    ``smallest_radius`` the smallest target radius (default: the model's R). See the
    module docstring for the derivation.
    """
    radius = params.radius if smallest_radius is None else smallest_radius
    rate = 8.0 * params.diffusivity / h**2 + params.mobility * explicit_curvature_bound(params, radius)
    limit = DIFFUSION_NUMBER / rate
    if speed > 0:
        limit = min(limit, COURANT_NUMBER * h / speed)
    return limit


def _flow_on_grid(flow: Flow, grid: ChannelGrid) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) at every node in grid order; zeros for a still flow."""
    x, y = grid.coordinates()
    if flow.is_still:
        return np.zeros(grid.n_nodes), np.zeros(grid.n_nodes)
    if flow.row_velocity is not None:
        u = np.broadcast_to(np.asarray(flow.row_velocity(y), dtype=float)[:, None], (grid.ny, grid.nx))
        return u.ravel().copy(), np.zeros(grid.n_nodes)
    xx, yy = np.meshgrid(x, y)
    u, v = flow.velocity(xx, yy)
    return (np.broadcast_to(u, xx.shape).ravel().astype(float),
            np.broadcast_to(v, xx.shape).ravel().astype(float))


def padded_index(layout: Layout, grid: ChannelGrid, width: int = _PAD) -> list[np.ndarray]:
    """For each group of ``layout``, an index (n_members, ny + 2·width, nx + 2·width) into the
    flat window vector extended by one zero at its end, that pads every field as
    :func:`~femphase.windows.pad_window` does (mirror at walls, periodic across the seam of a
    full-width window, zero beyond a window's edge).

    The padding rule depends only on a window's key, which all members of a group share, so
    pad_window is applied once per group to an array of node positions.
    """
    zero = layout.offsets[-1]
    out = []
    for group, (_key, members, start, _stop, size) in enumerate(layout.groups):
        window = layout.representative(group)
        positions = np.arange(1, size + 1).reshape(window.ny, window.nx)  # 0 stands for "zero"
        padded = pad_window(positions, window, grid, width)
        first = start + size * np.arange(members.size)[:, None, None]
        out.append(np.where(padded > 0, first + padded - 1, zero))
    return out


def _neighbours(padded: np.ndarray, axis: int) -> tuple[np.ndarray, ...]:
    """Views of padded (n, ny + 4, nx + 4) blocks: the values 2 and 1 nodes before and 1 and
    2 nodes after every unpadded node along ``axis`` (1: y, 2: x)."""
    if axis == 2:
        return tuple(padded[:, 2:-2, k:padded.shape[2] - 4 + k] for k in (0, 1, 3, 4))
    return tuple(padded[:, k:padded.shape[1] - 4 + k, 2:-2] for k in (0, 1, 3, 4))


def five_point_laplacian(padded: np.ndarray, h: float) -> np.ndarray:
    """(φ_E + φ_W + φ_N + φ_S − 4φ)/h² at the unpadded nodes of padded (n, ny + 4, nx + 4)."""
    _, west, east, _ = _neighbours(padded, 2)
    _, south, north, _ = _neighbours(padded, 1)
    out = west + east
    out += south
    out += north
    out -= 4.0 * padded[:, 2:-2, 2:-2]
    out /= h**2
    return out


def upwind_advection(padded: np.ndarray, velocity: np.ndarray, axis: int, h: float, order: int = 3) -> np.ndarray:
    """w ∂φ by upwind-biased differences along ``axis`` (1: y, 2: x); ``velocity`` w has the
    shape of the unpadded block. order 3: the fourth-order central difference plus |w| h³/12
    times the fourth difference (see the module docstring); order 1: the central difference
    plus |w| h/2 times the second difference, i.e. the one-sided w (φ_i − φ_{i−1})/h for
    w > 0, whose error is a numerical diffusion |w| h/2."""
    m2, m1, p1, p2 = _neighbours(padded, axis)
    centre = padded[:, 2:-2, 2:-2]
    if order == 1:
        return (velocity * (p1 - m1) - np.abs(velocity) * (p1 - 2.0 * centre + m1)) / (2.0 * h)
    central = (m2 - p2) + 8.0 * (p1 - m1)
    fourth = (m2 + p2) - 4.0 * (m1 + p1) + 6.0 * centre
    return (velocity * central + np.abs(velocity) * fourth) / (12.0 * h)


def laplacian(fields: list[np.ndarray], windows: list[Window], grid: ChannelGrid) -> list[np.ndarray]:
    """The 5-point Laplacian Δ_h φ_i of every field on its window (zero beyond the window's
    edge, mirrored at the walls, periodic across the seam of full-width windows)."""
    layout = Layout(windows, grid, False)
    extended = np.append(layout.gather(fields), 0.0)
    flat = np.empty(layout.offsets[-1])
    for (_, _, start, stop, _), index in zip(layout.groups, padded_index(layout, grid)):
        flat[start:stop] = five_point_laplacian(extended[index], grid.h).ravel()
    return layout.scatter(flat)


class FiniteDifferenceStepper:
    """Advances a :class:`State` by explicit Heun steps of fixed dt under a fixed flow.

    Same constructor and :meth:`step` as :class:`femphase.stepping.SemiImplicitStepper`;
    ``numerics.mass``, ``stabilisation``, ``solver``, ``tolerance`` and ``diagonals`` do not
    apply and are ignored; ``numerics.fd_advection`` picks the advection differences. Raises SceneError when dt exceeds
    :func:`explicit_stability_limit`.
    """

    def __init__(
        self,
        discretisation: Discretisation,
        params: ModelParameters,
        numerics: Numerics,
        dt: float,
        flow: Flow | None = None,
        radii: np.ndarray | None = None,
        source: Callable[[np.ndarray, np.ndarray, float], np.ndarray] | None = None,
    ) -> None:
        if not (dt > 0 and np.isfinite(dt)):
            raise SceneError("phases.dt", dt, "a time step > 0")
        grid = discretisation.grid
        self.disc, self.params, self.numerics, self.dt = discretisation, params, numerics, dt
        self.flow = flow or no_flow()
        self.source = source
        self.policy = WindowPolicy.for_spacing(
            grid.h, threshold=numerics.threshold, margin=numerics.margin, enabled=numerics.windows
        )
        self._advection_order = {"upwind3": 3, "upwind1": 1}[numerics.fd_advection]
        self._u, self._v = _flow_on_grid(self.flow, grid)
        self._advects = (bool(np.any(self._u)), bool(np.any(self._v)))
        speed = float(np.max(np.abs(self._u)) + np.max(np.abs(self._v)))
        smallest_radius = float(np.min(radii)) if radii is not None and len(radii) else params.radius
        self.dt_max = explicit_stability_limit(params, grid.h, speed, smallest_radius)
        if dt > self.dt_max * (1 + 1e-12):
            raise SceneError(
                "phases.dt", dt,
                f"a time step ≤ {self.dt_max:.4g} for the explicit finite-difference scheme at "
                f"h = {grid.h:g} (diffusion+reaction: dt·(8·J0·2γλ/h² + J0·L) ≤ {DIFFUSION_NUMBER:g}; "
                f"advection: dt·(max|u| + max|v|)/h ≤ {COURANT_NUMBER:g} with max|u| + max|v| = "
                f"{speed:.4g}); use the paper's dt = 0.1 at h = 1, or dt ≈ 0.1 h² on finer grids",
            )
        self._layout: Layout | None = None

    def layout(self, windows) -> Layout:
        if self._layout is None or self._layout.windows != tuple(windows):
            layout = Layout(windows, self.disc.grid, False)
            nodes = layout.node_index
            self._layout = layout
            self._index = padded_index(layout, self.disc.grid)
            self._mass = self.disc.operators.lumped_mass[nodes]
            self._velocity = [
                (axis, velocity[nodes]) for axis, velocity, on in ((2, self._u, self._advects[0]),
                                                                   (1, self._v, self._advects[1])) if on
            ]
        return self._layout

    # -- one step -------------------------------------------------------------------------
    def step(self, state: State) -> None:
        """Advance ``state`` by dt in place; raises BlowUpError (state unchanged) on failure."""
        grid, dt = state.grid, self.dt
        layout = self.layout(state.windows)
        phi = layout.gather(state.fields)
        k1 = self._rate(phi, layout, state.radii, state.time)
        k2 = self._rate(phi + dt * k1, layout, state.radii, state.time + dt)
        phi_new = phi + 0.5 * dt * (k1 + k2)
        check_fields(phi_new, self.numerics.blowup_margin, state.step + 1, state.time + dt)
        new_fields = layout.scatter(phi_new)
        new_windows = list(state.windows)
        for group, (_, members, *_) in enumerate(layout.groups):
            block = layout.group_block(phi_new, group)
            for i in members[self.policy.misfits(block, [state.windows[i] for i in members], grid)]:
                fitted = self.policy.fit(new_fields[i], state.windows[i], grid)
                if fitted != state.windows[i]:
                    new_fields[i] = transfer(new_fields[i], state.windows[i], fitted, grid)
                    new_windows[i] = fitted
        state.fields, state.windows = new_fields, new_windows
        state.time += dt
        state.step += 1

    def _rate(self, phi: np.ndarray, layout: Layout, radii: np.ndarray, time: float) -> np.ndarray:
        """f(φ, t) = −v·∇_h φ − J0 g(φ) + J0 2γλ Δ_h φ + s for the flat window vector φ."""
        params, grid = self.params, self.disc.grid
        nodes = layout.node_index
        squares = phi**2
        sizes = np.diff(layout.offsets)
        radius = np.asarray(radii, dtype=float)[layout.order]
        ratio = np.add.reduceat(self._mass * squares, layout.offsets[:-1]) / (np.pi * radius**2)
        # repulsion only where windows overlap: elsewhere Σ_{j≠i} φ_j² is exactly zero
        others = np.zeros_like(phi)
        shared = layout.overlap_positions
        if shared.size:
            total = np.bincount(nodes[shared], weights=squares[shared], minlength=grid.n_nodes)
            others[shared] = total[nodes[shared]] - squares[shared]
        rate = explicit_derivative(phi, others, np.repeat(ratio, sizes), np.repeat(radius, sizes), params)
        rate *= -params.mobility
        extended = np.append(phi, 0.0)
        for (_, members, start, stop, _), index in zip(layout.groups, self._index):
            padded = extended[index]
            block = rate[start:stop].reshape(padded.shape[0], padded.shape[1] - 4, padded.shape[2] - 4)
            block += params.diffusivity * five_point_laplacian(padded, grid.h)
            for axis, velocity in self._velocity:
                block -= upwind_advection(padded, velocity[start:stop].reshape(block.shape), axis, grid.h,
                                          self._advection_order)
        if self.source is not None:
            rate += self.source((nodes % grid.nx) * grid.h, (nodes // grid.nx) * grid.h, time)
        return rate
