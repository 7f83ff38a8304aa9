"""The paper's finite-difference scheme for the same model: an independent reference.

Space: the square lattice of the mesh nodes (spacing h), every particle's field on its own
window (the same :class:`~femphase.domains.grid.windows.WindowPolicy` as the finite-element stepper,
refitted before every step, data moved with :func:`~femphase.domains.grid.windows.transfer`). Derivatives
are array stencils on the window arrays, padded by :func:`~femphase.domains.grid.windows.pad_window`:
mirrored at the walls (∂yφ = 0), periodic across the seam of a full-width window, zero
beyond a window's artificial edge. They never touch the finite-element matrices, so
comparing the two methods is a real cross-check. To compare with a finite-difference code
of one's own on the whole lattice, run with ``numerics.windows = false``: then an
independent numpy implementation of this docstring agreed to 2e-15 in φ (one and two discs,
three at both walls, relaxation, shear, oscillating shear, Poiseuille); with windows (margin
4) the cut tails put 7e-5 to 4.4e-4 into φ and 2e-4 into centroids, falling geometrically
with ``numerics.margin`` (1.9e-6 at 8 for one disc).

* Laplacian: the 5-point stencil (φ_E + φ_W + φ_N + φ_S − 4φ)/h².
* Potential terms: :meth:`femphase.model.energy.FreeEnergy.explicit_derivative` at the nodes (shared
  model code); ∫φ² by the nodal quadrature (the trapezoid rule: weight h², h²/2 on the walls,
  which is the lumped mass of the structured mesh); Σ_{j≠i} φ_j² summed over the nodes
  where windows overlap (elsewhere it is zero).
* Advection v·∇φ: third-order upwind-biased differences in each direction, ::

      u ∂xφ ≈ u (φ_{i−2} − 8φ_{i−1} + 8φ_{i+1} − φ_{i+2})/(12h)
            + |u| (φ_{i−2} − 4φ_{i−1} + 6φ_i − 4φ_{i+1} + φ_{i+2})/(12h),

  i.e. the fourth-order central difference plus a fourth-difference dissipation ``|u|h³/12
  ∂x⁴φ`` that makes it upwind (for u > 0 the stencil is (φ_{i−2} − 6φ_{i−1} + 3φ_i +
  2φ_{i+1})/(6h)). Why not central differences: their symbol is purely imaginary, and
  Heun's stability region touches the imaginary axis only at 0, so central advection
  grows every mode (``|amplification|² = 1 + (ω dt)⁴/4``) unless the diffusion happens to damp
  it; the paper's cell Péclet number ``|u|h/D`` reaches ~1–8, so that cannot be relied on.
  Second-order upwind is stable too, but its leading error is dispersive and O(h²),
  (h²/3) u ∂x³φ, against the third-order scheme's dissipative ``(h³/12) |u| ∂x⁴φ``; the
  interface (width ~2λ = 4 at h = 1) is only a few nodes wide, so the order matters.
  Row flows (u(y), 0) and general flows share the code: each velocity component is
  differenced along its own direction. ``numerics.fd_advection = "upwind1"`` selects
  first-order upwind instead (numerical diffusion ``|u| h/2``), to test how much a cruder
  advection, which the paper does not exclude, changes the physics.
* Time: explicit predictor–corrector (Heun, second order); dt is the phase's (the paper runs dt = 0.1)::

      k1 = f(φⁿ, tⁿ),  φ* = φⁿ + dt k1,  k2 = f(φ*, tⁿ⁺¹),  φⁿ⁺¹ = φⁿ + dt (k1 + k2)/2,
      f(φ, t) = −v·∇_h φ − J0 g(φ) + J0 2γλ Δ_h φ + s(x, y, t).

Stability (:func:`explicit_stability_limit`, enforced by the constructor): Heun's stability
region contains [−2, 0] on the real axis and, for third-order upwind advection, Courant
numbers up to ≈ 0.87 (von Neumann; ``tests/test_fd.py`` checks the combined symbol).
The region is convex, so a step is stable when twice each part's spectrum lies inside it::

    dt (8 J0 2γλ/h² + J0 L) ≤ 1        (diffusion + the explicit curvature bound L of
                                         :meth:`femphase.model.energy.FreeEnergy.curvature_bound`)
    dt (max|u| + max|v|)/h  ≤ 0.4      (advection Courant number)

At the paper's parameters and h = 1 the first gives dt ≤ 0.3197 (so dt = 0.1 is safe); at
h = 0.5, dt ≤ 0.1664; at h = 0.25, dt ≤ 0.05705 (limits rounded down, as the messages give
them): the diffusion limit ∝ h² takes over below h ≈ 0.5. The bound is sufficient, not
sharp (twice each part's worst case): with it lifted, examples/single.toml with its shear
rate set to 0.1 (relaxation 300, then shear 1500) ran at dt = 1.7 with the area and r of
dt = 0.1, and blew up at 1.9; at the example's rate 1 it ran at 0.75 and blew up at 0.9.
"""

from __future__ import annotations

import math

import numpy as np

from femphase.domains.grid.domain import GridDomain
from femphase.domains.grid.windows import pad_window
from femphase.domains.layout import Layout
from femphase.errors import SceneError, UnstableStepError
from femphase.model.energy import FreeEnergy, WindowedFields
from femphase.model.parameters import ModelParameters
from femphase.state import State
from femphase.timestepping.base import SCHEMES, StepperProtocol, TimeScheme

__all__ = ["COURANT_NUMBER", "DIFFUSION_NUMBER", "FiniteDifferenceHeun", "explicit_stability_limit", "fem_schemes",
           "five_point_laplacian", "laplacian", "padded_index", "upwind_advection"]


#: Largest dt·(diffusion + reaction spectral radius): half of Heun's real-axis limit 2.
DIFFUSION_NUMBER = 1.0
#: Largest advective Courant number dt (max|u| + max|v|)/h: about half of the ≈ 0.87 at
#: which Heun with third-order upwind differences becomes unstable.
COURANT_NUMBER = 0.4
#: Nodes of padding the widest stencil (the advection's φ_{i±2}) needs.
_PAD = 2


def _speed(u: np.ndarray, v: np.ndarray) -> float:
    """max|u| + max|v| of nodal velocities: the speed of the advective Courant number."""
    return float(np.max(np.abs(u)) + np.max(np.abs(v)))


def explicit_stability_limit(
    params: ModelParameters, h: float, speed: float = 0.0, smallest_radius: float | None = None,
    energy: FreeEnergy | None = None,
) -> float:
    """The largest dt (time units) the finite-difference scheme accepts.

    ``speed`` is max|u| + max|v| of the flow over the nodes (lattice units per time unit),
    ``smallest_radius`` the smallest target radius (default: the model's R), ``energy`` the
    free energy (default: the paper's terms with ``params``). See the module docstring.
    """
    energy = energy or FreeEnergy.paper(params)
    radius = params.radius if smallest_radius is None else smallest_radius
    rate = params.mobility * (8.0 * energy.diffusivity / h**2 + energy.curvature_bound(radius))
    limit = DIFFUSION_NUMBER / rate
    if speed > 0:
        limit = min(limit, COURANT_NUMBER * h / speed)
    return limit


def rounded_down(value: float, digits: int = 4) -> str:
    """``value`` > 0 to ``digits`` significant digits, rounded down: a limit that a value
    copied from the message keeps (0.3197856 is "0.3197", not "0.3198")."""
    unit = 10.0 ** (math.floor(math.log10(value)) - digits + 1)
    # a limit of 0.01 is 0.009999999999999998 / 1e-5 in doubles: floored, "0.00999"
    return f"{math.floor(value / unit * (1 + 1e-12)) * unit:.{digits}g}"


def padded_index(layout: Layout, lattice: tuple[int, int], width: int = _PAD) -> list[np.ndarray]:
    """For each group of ``layout``, an index (n_members, ny + 2·width, nx + 2·width) into the
    flat window vector extended by one zero at its end, that pads every field as
    :func:`~femphase.domains.grid.windows.pad_window` does (mirror at walls, periodic across the seam of a
    full-width window, zero beyond a window's edge).

    The padding rule depends only on a window's key, which all members of a group share, so
    pad_window is applied once per group to an array of node positions.
    """
    zero = layout.offsets[-1]
    out = []
    for group, (_key, members, start, _stop, size) in enumerate(layout.groups):
        window = layout.representative(group)
        positions = np.arange(1, size + 1).reshape(window.ny, window.nx)  # 0 stands for "zero"
        padded = pad_window(positions, window, lattice, width)
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
    shape of the unpadded block. order 3: the fourth-order central difference plus ``|w| h³/12``
    times the fourth difference (see the module docstring); order 1: the central difference
    plus ``|w| h/2`` times the second difference, i.e. the one-sided w (φ_i − φ_{i−1})/h for
    w > 0, whose error is a numerical diffusion ``|w| h/2``."""
    m2, m1, p1, p2 = _neighbours(padded, axis)
    centre = padded[:, 2:-2, 2:-2]
    if order == 1:
        return (velocity * (p1 - m1) - np.abs(velocity) * (p1 - 2.0 * centre + m1)) / (2.0 * h)
    central = (m2 - p2) + 8.0 * (p1 - m1)
    fourth = (m2 + p2) - 4.0 * (m1 + p1) + 6.0 * centre
    return (velocity * central + np.abs(velocity) * fourth) / (12.0 * h)


def laplacian(fields: list[np.ndarray], windows: list, domain: GridDomain) -> list[np.ndarray]:
    """The 5-point Laplacian Δ_h φ_i of every field (flat, on its window; zero beyond the
    window's edge, mirrored at the walls, periodic across the seam of full-width windows)."""
    layout = domain.layout(windows)
    extended = np.append(layout.gather(fields), 0.0)
    flat = np.empty(layout.offsets[-1])
    for (_, _, start, stop, _), index in zip(layout.groups, padded_index(layout, domain.lattice)):
        flat[start:stop] = five_point_laplacian(extended[index], domain.grid.h).ravel()
    return [f.copy() for f in layout.scatter(flat)]


@SCHEMES.register("fd-heun")
class FiniteDifferenceHeun(TimeScheme):
    """The paper's finite-difference reference: explicit Heun (second order) with the
    5-point Laplacian and upwind-biased advection differences (`numerics.fd_advection`),
    unsplit. Structured channel only; dt must satisfy the explicit stability limit."""

    name = "fd-heun"
    order = 2
    mixed_precision = False  # the reference computes in double whatever numerics.precision
    masses = ("lumped",)  # the 5-point differences are the structured mesh's lumped-mass scheme

    def __init__(self, stepper: StepperProtocol) -> None:
        super().__init__(stepper)
        domain = stepper.domain
        if not isinstance(domain, GridDomain):
            raise SceneError("numerics.scheme", self.name, f'{fem_schemes()} on this domain: the finite-difference '
                             'reference needs the structured channel ([domain] kind = "grid")')
        self.domain = domain
        self._advection_order = {"upwind3": 3, "upwind1": 1}[stepper.numerics.fd_advection]
        u, v = self._nodal_flow(0.0)
        # a flow that changes in time: its fastest moment, where known (each step is checked too)
        speed = max(_speed(u, v), stepper.flow.speed_bound or 0.0)
        self.dt_max = explicit_stability_limit(stepper.params, domain.grid.h, speed, stepper.smallest_radius,
                                               stepper.energy)
        if stepper.dt > self.dt_max * (1 + 1e-12):
            raise SceneError(
                "phases.dt", stepper.dt,
                f"a time step ≤ {rounded_down(self.dt_max)} for the explicit finite-difference scheme at "
                f"h = {domain.grid.h:g} (diffusion+reaction: dt·J0·(8·D/h² + L) ≤ {DIFFUSION_NUMBER:g}; "
                f"advection: dt·(max|u| + max|v|)/h ≤ {COURANT_NUMBER:g} with max|u| + max|v| = "
                f"{speed:.4g}{' at its fastest' if stepper.flow.speed_bound else ''}); "
                + (f"set dt ≤ {rounded_down(self.dt_max)} here (the paper's dt = 0.1 h² is above it)" if self.dt_max < 0.1 * domain.grid.h**2
                   else "use the paper's dt = 0.1 at h = 1, or dt ≈ 0.1 h² on finer grids"),
            )
        self._steady = None if not stepper.flow.steady else (u, v)
        #: a changing flow's nodal velocity at the last two times asked (a step's two stages)
        self._recent: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._layout: Layout | None = None

    def _nodal_flow(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) at every node in grid order; zeros for a still flow."""
        flow = self.stepper.flow
        if flow.is_still:
            return np.zeros(self.domain.n_dofs), np.zeros(self.domain.n_dofs)
        x, y = self.domain.coordinates
        u, v = flow.velocity(x, y, time)
        return (np.broadcast_to(u, x.shape).astype(float), np.broadcast_to(v, x.shape).astype(float))

    def _index(self, layout: Layout) -> list[np.ndarray]:
        if self._layout is not layout:
            self._layout, self._padded = layout, padded_index(layout, self.domain.lattice)
        return self._padded

    def _flow_at(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) at every node at ``time``: a steady flow's, or a changing one's, evaluated
        once per time (a step's second stage is the next step's first)."""
        if self._steady is not None:
            return self._steady
        if time not in self._recent:
            self._recent = {t: flow for t, flow in self._recent.items() if t > time - 2 * self.stepper.dt}
            self._recent[time] = self._nodal_flow(time)
        return self._recent[time]

    def _check_courant(self, state: State) -> None:
        """For a flow that changes in time, which the check at construction saw at t = 0 and at
        its :attr:`~femphase.flows.Flow.speed_bound`, if it has one: stop before a step whose advective Courant number exceeds :data:`COURANT_NUMBER`,
        where the explicit step is unstable or nearly (:class:`~femphase.errors.UnstableStepError`,
        the state before the step kept)."""
        dt, h = self.stepper.dt, self.domain.grid.h
        for time in (state.time, state.time + dt):
            speed = _speed(*self._flow_at(time))
            if dt * speed / h > COURANT_NUMBER * (1 + 1e-12):
                raise UnstableStepError(state.step + 1, state.time, (
                    f"the flow's max|u| + max|v| = {speed:.4g} at t = {time:g} makes the explicit scheme's advective "
                    f"Courant number dt·speed/h = {dt * speed / h:.6g} exceed {COURANT_NUMBER:g}, past which it goes "
                    f"unstable; set the phase's dt ≤ {rounded_down(COURANT_NUMBER * h / speed)}"))

    def advance(self, phi: np.ndarray, layout: Layout, state: State) -> tuple[np.ndarray, Layout]:
        dt, time, radii = self.stepper.dt, state.time, state.radii
        if self._steady is None:
            self._check_courant(state)
        k1 = self.rate(phi, layout, radii, time)
        k2 = self.rate(phi + dt * k1, layout, radii, time + dt)
        return phi + 0.5 * dt * (k1 + k2), layout

    def rate(self, phi: np.ndarray, layout: Layout, radii: np.ndarray, time: float) -> np.ndarray:
        """f(φ, t) = −v·∇_h φ − J0 g(φ) + J0 D Δ_h φ + s for the flat window vector φ."""
        stepper, h = self.stepper, self.domain.grid.h
        j0 = stepper.mobility
        rate = stepper.energy.explicit_derivative(WindowedFields(phi, layout, radii))
        rate *= -j0
        u, v = self._flow_at(time)
        velocities = [(axis, c[layout.node_index]) for axis, c in ((2, u), (1, v)) if np.any(c)]
        extended = np.append(phi, 0.0)
        for (_, _, start, stop, _), index in zip(layout.groups, self._index(layout)):
            padded = extended[index]
            block = rate[start:stop].reshape(padded.shape[0], padded.shape[1] - 4, padded.shape[2] - 4)
            block += j0 * stepper.energy.diffusivity * five_point_laplacian(padded, h)
            for axis, velocity in velocities:
                block -= upwind_advection(padded, velocity[start:stop].reshape(block.shape), axis, h,
                                          self._advection_order)
        source = stepper.source_term(layout, time)
        if source is not None:
            rate += source
        return rate


def fem_schemes() -> str:
    """What a domain the finite-difference reference cannot run on takes instead, for
    messages: 'a FEM scheme ("euler", "sav2", "adaptive")', from the registry."""
    names = ", ".join(f'"{name}"' for name in SCHEMES.names() if name != FiniteDifferenceHeun.name)
    return f"a FEM scheme ({names})"
