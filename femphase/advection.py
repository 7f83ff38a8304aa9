"""Advection v·∇φ over one time step, split from the relaxation (Lie splitting).

Each domain picks its advection (:meth:`femphase.domain.Domain.advection`); all three take
the flow at the step's midpoint t + dt/2 when it depends on time (second order in dt for the
displacement; exact for steady flows).

**Row shift** (structured channel, flows (u(y, t), 0)): exact in time. Over dt every row of
nodes moves by s = u(y, t + dt/2) dt / h nodes. The integer part of a window's mean shift
moves the window itself (no data are touched); the remaining fractional shift of each row
is a phase shift of the row's discrete Fourier series (trigonometric interpolation). Rows
of a window are zero near both ends (the window's margin), so treating them as periodic is
exact up to the field's value at the margin; rows of a full-width window are periodic. The
interface profile tanh(x/λ) has Fourier coefficients ~ exp(−π²λ/(2h)) at the Nyquist
frequency, so the interpolation error is ~1e-4 at h = λ/2 and falls exponentially with h.
No CFL limit: any dt is one exact shift.

**Semi-Lagrangian** (structured channel, other flows): each node's departure point
x − dt v(x − dt v(x)/2) (second order in dt) is found and the field is interpolated there
with cubic splines.

**Galerkin–Padé** (meshes): Galerkin in space (consistent mass M, skew-symmetric advection
matrix C, :func:`advection_matrix`), and in time the (2,2) Padé approximant of the exact
propagator exp(−dt M⁻¹C),

    φ* = R(dt M⁻¹C) φ⁰,   R(z) = (1 − z/2 + z²/12) / (1 + z/2 + z²/12)
                              = 1 + 2 Re[−2i√3 / (1 − z/r)],   r = −3 + i√3,

i.e. one complex solve per window, φ* = φ⁰ + 4√3 Im w with (M − (dt/r) C) w = M φ⁰.
Why Galerkin and not semi-Lagrangian on meshes: semi-Lagrangian with P1 interpolation adds a
numerical diffusion ~ h² C(1 − C)/(2 dt) (C the Courant number) as large as the model's own
diffusivity at the paper's u ~ 1, h = 1; Galerkin has none, and the resolved interface held
to its tanh profile by the double well does not oscillate at cell Péclet numbers above 2.
Why Padé (2,2) and not Crank–Nicolson: both are A-stable and conserve ∫φ² for the skew C at
any dt, but CN's phase error (ω dt)²/12 made a disc translating at u = 1 with dt = 1 lag by
1.2 % and stretch (elongation +0.024); Padé costs one complex solve instead of a real one and
cuts both to 0.1 % and +0.002 (verification/README.md, meshed geometries).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
from scipy import fft
from scipy.ndimage import map_coordinates
from skfem import Basis, BilinearForm, ElementTriP1
from skfem.helpers import dot, grad

from .discretisation import fold_matrix
from .domain import window_block
from .flows import Flow
from .solvers import make_solver
from .windows import Layout, Window, pad_window

if TYPE_CHECKING:
    from .channel import ChannelDomain
    from .domain import Domain
    from .meshed import MeshDomain
    from .stepping import Numerics
    from .windows import GridLayout


def row_phases(shifts: np.ndarray, nx: int, single: bool = False) -> np.ndarray:
    """The Fourier phase factors (..., ny, nx//2 + 1) that shift rows of nx nodes by
    ``shifts`` (..., ny) nodes in +x (see :func:`shift_rows`); ``single``: rounded to single
    precision (complex64) after they are built in double."""
    # the phase factor of mode m is z**m with z = exp(−2πi s/nx): one exp per row, then
    # a cumulative product, is several times cheaper than an exp per mode
    phases = np.empty(np.shape(shifts) + (nx // 2 + 1,), dtype=complex)
    phases[..., 0] = 1.0
    phases[..., 1:] = np.exp(-2j * np.pi * np.asarray(shifts) / nx)[..., None]
    np.cumprod(phases, axis=-1, out=phases)
    return phases.astype(np.complex64) if single else phases


def shift_rows(fields: np.ndarray, shifts: np.ndarray, phases: np.ndarray | None = None) -> np.ndarray:
    """Shift every row of fields (..., ny, nx) by shifts (..., ny) nodes in +x, periodically
    (trigonometric interpolation); ``phases``: :func:`row_phases` of the shifts, if known, in
    the fields' precision. Float32 fields are shifted in single precision (complex64
    spectra: 3× faster on 100 windows of 34 × 34 nodes, a relative error ~1e-7)."""
    nx = fields.shape[-1]
    if phases is None:
        phases = row_phases(shifts, nx, fields.dtype == np.float32)
    spectrum = fft.rfft(fields, axis=-1)
    spectrum *= phases
    return fft.irfft(spectrum, n=nx, axis=-1)


def regather(phi: np.ndarray, old: Layout, new: Layout) -> np.ndarray:
    """φ in ``old``'s order rearranged into ``new``'s (windows regrouped by a move)."""
    if np.array_equal(old.order, new.order):
        return phi
    return new.gather(old.scatter(phi))


class StepAdvection:
    """Advection over steps of fixed dt in ``flow`` on ``domain`` (the base of the three)."""

    def __init__(self, domain: "Domain", flow: Flow, dt: float) -> None:
        self.domain, self.flow, self.dt = domain, flow, dt

    def velocity(self, time: float) -> np.ndarray:
        """(2, n_dofs) nodal velocity at the step starting at ``time`` (its midpoint)."""
        return nodal_velocity(self.domain, self.flow, time + 0.5 * self.dt)


class RowShift(StepAdvection):
    """Exact advection of the structured channel's windows in a row flow (u(y, t), 0), in
    the fields' precision (:func:`shift_rows`; numerics.precision = "mixed" passes float32)."""

    #: Runs whose phase factors are kept (10 kB a window of 36 × 36 nodes; an adaptive
    #: stepper keeps up to 8 advections): a new layout regroups a few windows and leaves the
    #: other groups as they were
    STACK_CACHE = 32

    def __init__(self, domain: "ChannelDomain", flow: Flow, dt: float) -> None:
        super().__init__(domain, flow, dt)
        _, self._y = domain.grid.coordinates()
        self._steady_shift = self._row_shift(0.0) if flow.steady else None
        #: per run of windows (:func:`row_runs`; its width, particles, heights and
        #: precision): their first rows (k,), whole-node moves (k,) and stacked phase
        #: factors (rows, nx//2 + 1)
        self._stacks: dict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        #: (groups, :func:`row_runs`) of the last layout advected: moved layouts keep both
        self._runs: tuple[list, list] | None = None

    def _row_shift(self, time: float) -> np.ndarray:
        return np.asarray(self.flow.row_velocity(self._y, time + 0.5 * self.dt), dtype=float) * self.dt / self.domain.grid.h

    def _window_shifts(self, row_shift: np.ndarray, first_rows: np.ndarray, heights: np.ndarray,
                       full_width: bool) -> tuple[np.ndarray, np.ndarray]:
        """For windows of one width, first rows ``first_rows`` and ``heights`` rows each: the
        whole nodes each moves (k,), the mean of its rows' shifts rounded (none for
        full-width windows), and the fractional shifts left for their rows, all rows one
        after the other (Σ heights,)."""
        starts = np.concatenate([[0], np.cumsum(heights)])
        shifts = row_shift[np.arange(starts[-1]) + np.repeat(first_rows - starts[:-1], heights)]
        if full_width:
            return np.zeros(heights.size, dtype=np.int64), shifts
        whole = np.rint(np.add.reduceat(shifts, starts[:-1]) / heights)
        return whole.astype(np.int64), shifts - np.repeat(whole, heights)

    def _run_phases(self, first_rows: np.ndarray, heights: np.ndarray, members: np.ndarray, nx: int,
                    single: bool) -> tuple[np.ndarray, np.ndarray]:
        """The whole-node moves (k,) and phase factors (Σ heights, nx//2 + 1; complex64 if
        ``single``) of the windows of particles ``members``, all ``nx`` wide, in a steady
        flow. A row flow never changes them while the windows keep their rows, so they are
        kept per run of windows and renewed window by window when a refit moves windows
        across rows (building them every substep was 6 % of the lattice's step, stacking
        them window by window 4 %; under strong shear refits move a window or two across
        rows every substep, and building a group's factors afresh then cost 5 % of the
        random packing's time at γ̇ = 1)."""
        key = (nx, single, members.tobytes(), heights.tobytes())
        kept = self._stacks.get(key)
        if kept is None:
            if len(self._stacks) >= self.STACK_CACHE:
                self._stacks.clear()
            changed = np.ones(members.size, dtype=bool)
            kept = self._stacks[key] = (first_rows.copy(), np.empty(members.size, dtype=np.int64),
                                        np.empty((int(heights.sum()), nx // 2 + 1),
                                                 dtype=np.complex64 if single else complex))
        else:
            changed = kept[0] != first_rows
        if changed.any():
            kept_rows, kept_wholes, kept_phases = kept
            wholes, shifts = self._window_shifts(self._steady_shift, first_rows, heights,
                                                 nx == self.domain.grid.nx)
            rows = np.repeat(changed, heights)
            kept_wholes[changed], kept_phases[rows] = wholes[changed], row_phases(shifts[rows], nx, single)
            kept_rows[changed] = first_rows[changed]
        return kept[1], kept[2]

    def advect(self, phi: np.ndarray, layout: "GridLayout", time: float) -> tuple[np.ndarray, Layout]:
        grid = self.domain.grid
        row_shift = None if self._steady_shift is not None else self._row_shift(time)
        if self._runs is None or self._runs[0] is not layout.groups:  # kept while the groups are
            self._runs = (layout.groups, row_runs(layout))
        corners = layout.corners
        first_columns = corners[:, 2].copy()
        for start, stop, slots, members, heights, nx in self._runs[1]:
            block = phi[start:stop].reshape(-1, nx)
            first_rows = corners[slots, 0]
            if row_shift is None:
                wholes, phases = self._run_phases(first_rows, heights, members, nx, block.dtype == np.float32)
                block[...] = shift_rows(block, None, phases)
            else:
                wholes, shifts = self._window_shifts(row_shift, first_rows, heights, nx == grid.nx)
                block[...] = shift_rows(block, shifts)
            first_columns[slots] += wholes
        np.remainder(first_columns, grid.nx, out=first_columns)
        moved = self.domain.moved_along_rows(layout, first_columns)
        return regather(phi, layout, moved), moved


def row_runs(layout: Layout) -> list[tuple[int, int, slice, np.ndarray, np.ndarray, int]]:
    """The layout's windows in runs of consecutive groups of one width (the channel's window
    keys start with nx): (first position, end position, the run's slots (layout order),
    their particles (k,), their windows' heights (k,), nx). A row shift transforms a run's
    rows in one call: on the random packing 4 runs instead of 14 groups
    (benchmarks/README.md, "Session 15")."""
    runs = []  # [first position, end position, first slot, members, heights, nx]
    slot = 0
    for (_, members, start, stop, _), (ny, nx) in zip(layout.groups, layout.shapes):
        if not runs or runs[-1][5] != nx:
            runs.append([start, stop, slot, [], [], nx])
        runs[-1][1] = stop
        runs[-1][3].append(members)
        runs[-1][4].append(np.full(members.size, ny, dtype=np.int64))
        slot += members.size
    return [(start, stop, slice(first, first + sum(m.size for m in members)), np.concatenate(members),
             np.concatenate(heights), nx) for start, stop, first, members, heights, nx in runs]


class SemiLagrangian(StepAdvection):
    """Advection of the structured channel's windows in any flow, by cubic interpolation at
    departure points."""

    PAD = 4

    def advect(self, phi: np.ndarray, layout: Layout, time: float) -> tuple[np.ndarray, Layout]:
        grid, dt, pad = self.domain.grid, self.dt, self.PAD
        lattice = self.domain.lattice
        t_mid = time + 0.5 * dt
        fields, windows = layout.scatter(phi), list(layout.windows)
        for i, (values, w) in enumerate(zip(fields, layout.windows)):
            ux, uy = self._velocity(*self._node_coordinates(w), t_mid)
            # move the window with the mean displacement so the departure points stay inside it
            kx = int(np.rint(np.mean(ux) * dt / grid.h)) if w.nx < grid.nx else 0
            ky = int(np.rint(np.mean(uy) * dt / grid.h))
            iy0 = min(max(w.iy0 + ky, 0), grid.ny - w.ny)
            new = Window(iy0, w.ny, (w.ix0 + kx) % grid.nx, w.nx)
            xn, yn = self._node_coordinates(new)
            u0, v0 = self._velocity(xn, yn, t_mid)
            um, vm = self._velocity(xn - 0.5 * dt * u0, yn - 0.5 * dt * v0, t_mid)
            xd = xn - dt * um
            yd = np.clip(yn - dt * vm, 0.0, grid.width)
            fields[i] = map_coordinates(
                pad_window(values.reshape(w.shape), w, lattice, pad),
                [yd / grid.h - w.iy0 + pad, self._local_columns(xd, w) + pad], order=3, mode="nearest",
            ).ravel()
            windows[i] = new
        moved = self.domain.layout(windows)
        return moved.gather(fields), moved

    def _local_columns(self, x: np.ndarray, w: Window) -> np.ndarray:
        """x (lattice units) as a column coordinate of window w, unwrapped near the window."""
        grid = self.domain.grid
        col = (x / grid.h - w.ix0) % grid.nx
        if w.nx == grid.nx:
            return col
        # points just left of the window come out near nx; bring them back below zero
        return np.where(col > 0.5 * (w.nx + grid.nx), col - grid.nx, col)

    def _node_coordinates(self, w: Window) -> tuple[np.ndarray, np.ndarray]:
        grid = self.domain.grid
        x = np.broadcast_to(w.columns(grid.nx)[None, :] * grid.h, w.shape)
        y = np.broadcast_to(w.rows()[:, None] * grid.h, w.shape)
        return x, y

    def _velocity(self, x: np.ndarray, y: np.ndarray, time: float):
        """(u, v) at points, x wrapped into [0, Lx) and y clipped to the channel."""
        grid = self.domain.grid
        x = np.mod(x, grid.length)
        y = np.clip(y, 0.0, grid.width)
        u, v = self.flow.velocity(x, y, time)
        return np.broadcast_to(u, x.shape), np.broadcast_to(v, x.shape)


@BilinearForm
def skew_advection(u, v, w):
    return 0.5 * (dot(w.velocity, grad(u)) * v - dot(w.velocity, grad(v)) * u)


def nodal_velocity(domain: "Domain", flow: Flow, time: float = 0.0) -> np.ndarray:
    """(2, n_dofs): the flow's velocity at every dof."""
    if flow.stokes is not None:
        out = np.empty((2, domain.n_dofs))
        out[:, domain.dof_map] = flow.stokes.velocity_at_nodes()  # periodic partners carry equal values
        return out
    x, y = domain.coordinates
    u, v = flow.velocity(x, y, time)
    return np.stack([np.broadcast_to(u, x.shape), np.broadcast_to(v, x.shape)]).astype(float)


def advection_matrix(domain: "MeshDomain", flow: Flow, time: float = 0.0) -> sp.csr_matrix:
    """The skew-symmetric advection matrix C_ij = c(φ_j, φ_i) on the periodic dofs,

        c(φ, ψ) = ½ ∫ (v·∇φ) ψ − ½ ∫ (v·∇ψ) φ,

    equal to the advective form for a divergence-free v with v·n = 0 on the walls and
    periodic sides, and exactly antisymmetric for the only weakly divergence-free P2 Stokes
    velocity, so the step conserves ∫φ² (mass-matrix norm) at any dt. The velocity enters at
    the quadrature points (the P2 Stokes field exactly, analytic flows by evaluation)."""
    if flow.stokes is not None:
        basis = flow.stokes.pressure_basis  # P1 on the velocity basis' quadrature points
        velocity = np.asarray(flow.stokes.velocity_basis.interpolate(flow.stokes.velocity))
    else:
        basis = Basis(domain.mesh, ElementTriP1(), intorder=4)
        x, y = basis.mapping.F(basis.X)
        u, v = flow.velocity(x, y, time)
        velocity = np.stack([np.broadcast_to(u, x.shape), np.broadcast_to(v, x.shape)])
    fold = fold_matrix(domain.dof_map, domain.n_dofs)
    matrix = skew_advection.assemble(basis, velocity=velocity)
    return (fold.T @ matrix @ fold).tocsr()


#: The pole r of the (2,2) Padé approximant R(z) = 1 + 2 Re[−2i√3/(1 − z/r)] of exp(−z).
PADE_POLE = -3.0 + 1j * np.sqrt(3.0)


class GalerkinPade(StepAdvection):
    """Galerkin advection with the (2,2) Padé step on a meshed domain; one factorised
    complex system per window, kept while the window's dofs do not change. A time-dependent
    flow is assembled at every step's midpoint (its factorisations are then rebuilt)."""

    def __init__(self, domain: "MeshDomain", flow: Flow, dt: float, numerics: "Numerics") -> None:
        super().__init__(domain, flow, dt)
        self.numerics = numerics
        self._assembled_at: float | None = None
        self._solvers: dict = {}
        if flow.steady:
            self._assemble(0.0)

    def _assemble(self, time: float) -> None:
        ops = self.domain.operators
        self._system = (ops.mass - (self.dt / PADE_POLE) * advection_matrix(self.domain, self.flow, time)).tocsr()
        self._mass = ops.mass.tocsr()
        self._solvers = {}
        self._assembled_at = time

    def advect(self, phi: np.ndarray, layout: Layout, time: float) -> tuple[np.ndarray, Layout]:
        if not self.flow.steady and self._assembled_at != time + 0.5 * self.dt:
            self._assemble(time + 0.5 * self.dt)
        current = {key for key, *_ in layout.groups}
        self._solvers = {k: v for k, v in self._solvers.items() if k in current}
        out = np.empty_like(phi)
        for group, (key, members, start, stop, size) in enumerate(layout.groups):
            if key not in self._solvers:
                dofs = self.domain.window_dofs(layout.representative(group))
                self._solvers[key] = (
                    make_solver(window_block(self._system, dofs), self.numerics.solver, self.numerics.tolerance),
                    window_block(self._mass, dofs),
                )
            solver, mass = self._solvers[key]
            current_phi = phi[start:stop].reshape(members.size, size).T
            w = solver.solve((mass @ current_phi).astype(complex))
            out[start:stop].reshape(members.size, size).T[...] = current_phi + 4.0 * np.sqrt(3.0) * w.imag
        return out, layout
