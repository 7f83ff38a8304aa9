"""Advection on the structured channel, over one step of fixed dt.

**Row shift** (structured channel, flows (u(y, t), 0)): exact in time. Over dt every row of
nodes moves by s = u(y, t + dt/2) dt / h nodes. The integer part of a window's mean shift
moves the window itself (no data are touched); the remaining fractional shift of each row
is a phase shift of the row's discrete Fourier series (trigonometric interpolation). Rows
of a window are zero near both ends (the window's margin), so treating them as periodic is
exact up to the field's value at the margin; rows of a full-width window are periodic. The
interface profile tanh(x/λ) has Fourier coefficients ~ exp(−π²λ/(2h)) at the Nyquist
frequency, so the interpolation error is ~1e-4 at h = λ/2 and falls exponentially with h.
No CFL limit: any dt is one exact shift.

**The Nyquist mode** (rows of even length) stays where it is on the grid: the shift is the
exact flow of the spectral derivative, whose Nyquist coefficient is zero (the usual
convention for even lengths), so shifts compose exactly, S(a) S(b) = S(a + b), and the
result does not depend on how a displacement is split into steps. The real part of the
trigonometric interpolant's phase factor would instead scale that mode by cos(πs) at every
shift, a damping that depends on the step: over a displacement S in steps of s it is
~π²Ss/2, a first-order error in time. Measured on the sheared N = 100 lattice in double
precision: sav2's r̄(t) then converged at order 1.4 between dt = 0.25, 0.125 and 0.0625, and
the adaptive scheme's error fell as tolerance_t^0.68 (docs/decisions/0018-nyquist-mode.md).

**Semi-Lagrangian** (structured channel, other flows): each node's departure point
x − dt v(x − dt v(x)/2) (second order in dt) is found and the field is interpolated there
with cubic splines.
"""

from __future__ import annotations

import numpy as np
from scipy import fft
from scipy.ndimage import map_coordinates

from femphase.domains.advection import StepAdvection, regather
from femphase.domains.base import Domain
from femphase.domains.grid.windows import GridLayout, Window, pad_window
from femphase.domains.layout import Layout
from femphase.flows import Flow, time_mean, velocity_at

__all__ = ["RowShift", "SemiLagrangian", "row_phases", "row_runs", "shift_rows"]


def row_phases(shifts: np.ndarray, nx: int, single: bool = False, moves: np.ndarray | None = None) -> np.ndarray:
    """The Fourier phase factors (..., ny, nx//2 + 1) that shift rows of nx nodes by
    ``shifts`` (..., ny) nodes in +x (see :func:`shift_rows`); ``single``: rounded to single
    precision (complex64) after they are built in double. For even nx the Nyquist mode's
    factor is (−1)^moves, ``moves`` (..., ny) the whole nodes each row's window moves with
    the same shift (default none): the mode then stays in place on the grid (module
    docstring)."""
    # the phase factor of mode m is z**m with z = exp(−2πi s/nx): one exp per row, then
    # a cumulative product, is several times cheaper than an exp per mode
    phases = np.empty(np.shape(shifts) + (nx // 2 + 1,), dtype=complex)
    phases[..., 0] = 1.0
    phases[..., 1:] = np.exp(-2j * np.pi * np.asarray(shifts) / nx)[..., None]
    np.cumprod(phases, axis=-1, out=phases)
    if nx % 2 == 0:
        phases[..., -1] = 1.0 if moves is None else 1.0 - 2.0 * (np.asarray(moves) % 2)
    return phases.astype(np.complex64) if single else phases


def shift_rows(fields: np.ndarray, shifts: np.ndarray, phases: np.ndarray | None = None,
               moves: np.ndarray | None = None) -> np.ndarray:
    """Shift every row of fields (..., ny, nx) by shifts (..., ny) nodes in +x, periodically
    (trigonometric interpolation; for even nx the Nyquist mode stays in place, or changes
    sign with odd ``moves``, :func:`row_phases`); ``phases``: :func:`row_phases` of the
    shifts, if known, in the fields' precision. Float32 fields are shifted in single
    precision (complex64 spectra: 3× faster on 100 windows of 34 × 34 nodes, a relative
    error ~1e-7)."""
    nx = fields.shape[-1]
    if phases is None:
        phases = row_phases(shifts, nx, fields.dtype == np.float32, moves)
    spectrum = fft.rfft(fields, axis=-1)
    spectrum *= phases
    return fft.irfft(spectrum, n=nx, axis=-1)


class RowShift(StepAdvection):
    """Exact advection of the structured channel's windows in a row flow (u(y, t), 0), in
    the fields' precision (:func:`shift_rows`; numerics.precision = "mixed" passes float32)."""

    moves_windows = True

    def __init__(self, domain: Domain, flow: Flow, dt: float) -> None:
        super().__init__(domain, flow, dt)
        _, self._y = domain.grid.coordinates()
        self._steady_shift = self._row_shift(0.0) if flow.steady else None
        #: per run of windows (:func:`row_runs`; its width, particles, heights and
        #: precision): their first rows (k,), whole-node moves (k,) and stacked phase
        #: factors (rows, nx//2 + 1), 10 kB a window of 36 × 36 nodes, in the domain's
        #: budget (a new layout regroups a few windows and leaves the other groups as they were)
        self._stacks = domain.caches.cache("row-shift phases")
        #: (groups, :func:`row_runs`) of the last layout advected: moved layouts keep both
        self._runs: tuple[list, list] | None = None

    def _row_shift(self, time: float) -> np.ndarray:
        """Nodes each row moves over the step from ``time``: ∫u(y, t) dt over the step, exact
        for a steady flow and by :func:`~femphase.flows.time_mean` for one that changes."""
        row, y = self.flow.row_velocity, self._y
        mean = row(y, time) if self.flow.steady else time_mean(lambda t: row(y, t), time, self.dt)
        return np.asarray(mean, dtype=float) * self.dt / self.domain.grid.h

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
            changed = np.ones(members.size, dtype=bool)
            kept = self._stacks.put(key, (first_rows.copy(), np.empty(members.size, dtype=np.int64),
                                          np.empty((int(heights.sum()), nx // 2 + 1),
                                                   dtype=np.complex64 if single else complex)))
        else:
            changed = kept[0] != first_rows
        if changed.any():
            kept_rows, kept_wholes, kept_phases = kept
            wholes, shifts = self._window_shifts(self._steady_shift, first_rows, heights,
                                                 nx == self.domain.grid.nx)
            rows = np.repeat(changed, heights)
            kept_wholes[changed] = wholes[changed]
            kept_phases[rows] = row_phases(shifts[rows], nx, single, np.repeat(wholes, heights)[rows])
            kept_rows[changed] = first_rows[changed]
        return kept[1], kept[2]

    def advect(self, phi: np.ndarray, layout: GridLayout, time: float) -> tuple[np.ndarray, Layout]:
        grid = self.domain.grid
        row_shift = None if self._steady_shift is not None else self._row_shift(time)
        if self._runs is None or self._runs[0] is not layout.groups:  # kept while the groups are
            self._runs = (layout.groups, row_runs(layout))
            # phase factors are kept for the runs of these groups only: a run regrouped is
            # rarely met again (kept until the budget was full, they reached 85 MiB in 3000
            # time units at γ̇ = 1 on examples/random.toml)
            self._stacks.retain({(nx, single, members.tobytes(), heights.tobytes())
                                 for *_, members, heights, nx in self._runs[1] for single in (False, True)})
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
                block[...] = shift_rows(block, shifts, moves=np.repeat(wholes, heights))
            first_columns[slots] += wholes
        np.remainder(first_columns, grid.nx, out=first_columns)
        moved = self.domain.moved_along_rows(layout, first_columns)
        return regather(phi, layout, moved), moved


def row_runs(layout: Layout) -> list[tuple[int, int, slice, np.ndarray, np.ndarray, int]]:
    """The layout's windows in runs of consecutive groups of one width (the channel's window
    keys start with nx): (first position, end position, the run's slots (layout order),
    their particles (k,), their windows' heights (k,), nx). A row shift transforms a run's
    rows in one call: on the random packing 4 runs instead of 14 groups."""
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

    moves_windows = True

    PAD = 4

    def advect(self, phi: np.ndarray, layout: Layout, time: float) -> tuple[np.ndarray, Layout]:
        grid, dt, pad = self.domain.grid, self.dt, self.PAD
        lattice = self.domain.lattice
        fields, windows = layout.scatter(phi), list(layout.windows)
        for i, (values, w) in enumerate(zip(fields, layout.windows)):
            ux, uy = self._velocity(*self._node_coordinates(w), time)
            # move the window with the mean displacement so the departure points stay inside it
            kx = int(np.rint(np.mean(ux) * dt / grid.h)) if w.nx < grid.nx else 0
            ky = int(np.rint(np.mean(uy) * dt / grid.h))
            iy0 = min(max(w.iy0 + ky, 0), grid.ny - w.ny)
            new = Window(iy0, w.ny, (w.ix0 + kx) % grid.nx, w.nx)
            xn, yn = self._node_coordinates(new)
            u0, v0 = self._velocity(xn, yn, time)
            um, vm = self._velocity(xn - 0.5 * dt * u0, yn - 0.5 * dt * v0, time)
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

    def _velocity(self, x: np.ndarray, y: np.ndarray, time: float) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) at points, x wrapped into [0, Lx) and y clipped to the channel, over the step
        from ``time``: the flow's, or for a flow that changes its mean over the step
        (:func:`~femphase.flows.time_mean`; departure points traced in it are exact in time
        for v = f(t) w(x), as the row shift is)."""
        grid = self.domain.grid
        x = np.mod(x, grid.length)
        y = np.clip(y, 0.0, grid.width)
        if self.flow.steady:
            return tuple(velocity_at(self.flow, x, y, time))
        return tuple(time_mean(lambda t: velocity_at(self.flow, x, y, t), time, self.dt))
