"""Advection v·∇φ over one time step, split from the relaxation (Lie splitting).

Row flows (u(y), 0) are advected exactly in time: over dt every row of nodes moves by
s = u(y) dt / h nodes. The integer part of a window's mean shift moves the window itself
(no data are touched); the remaining fractional shift of each row is applied as a phase
shift of the row's discrete Fourier series (trigonometric interpolation). Rows of a
window are zero near both ends (the window's margin), so treating them as periodic is
exact up to the field's value at the margin; rows of a full-width window are periodic.
The interface profile tanh(x/λ) has Fourier coefficients ~ exp(−π²λ/(2h)) at the Nyquist
frequency, so the interpolation error is ~1e-4 at h = λ/2 and falls exponentially with h.
No CFL limit: any dt is one exact shift.

Other flows are advected semi-Lagrangian: each node's departure point x − dt v(x − dt v(x)/2)
(second order in dt) is found and the field is interpolated there with cubic splines.
"""

from __future__ import annotations

import numpy as np
from scipy import fft
from scipy.ndimage import map_coordinates

from .flows import Flow
from .mesh import ChannelGrid
from .windows import Layout, Window, pad_window


def shift_rows(fields: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """Shift every row of fields (..., ny, nx) by shifts (..., ny) nodes in +x, periodically."""
    nx = fields.shape[-1]
    spectrum = fft.rfft(fields, axis=-1)
    # the phase factor of mode m is z**m with z = exp(−2πi s/nx): one exp per row, then
    # a cumulative product, is several times cheaper than an exp per mode
    phases = np.empty(spectrum.shape, dtype=complex)
    phases[..., 0] = 1.0
    phases[..., 1:] = np.exp(-2j * np.pi * shifts / nx)[..., None]
    np.cumprod(phases, axis=-1, out=phases)
    spectrum *= phases
    return fft.irfft(spectrum, n=nx, axis=-1)


def advect_row_flow(
    phi: np.ndarray, layout: Layout, grid: ChannelGrid, flow: Flow, dt: float
) -> list[Window]:
    """Advect the gathered fields ``phi`` (layout order) in place over dt in a row flow.

    Returns the windows after the step: a window not spanning the whole width moves by the
    whole-node part of its mean shift; each group of equal windows is shifted by one batched
    FFT on its block of ``phi``.
    """
    _, y = grid.coordinates()
    row_shift = flow.row_velocity(y) * dt / grid.h
    windows = list(layout.windows)
    for group, (_key, members, *_) in enumerate(layout.groups):
        block = layout.group_block(phi, group)
        w0 = windows[members[0]]
        iy0 = np.array([windows[i].iy0 for i in members])
        shifts = row_shift[iy0[:, None] + np.arange(w0.ny)[None, :]]
        if w0.nx < grid.nx:
            whole = np.rint(shifts.mean(axis=1))
            shifts -= whole[:, None]
            for i, k in zip(members, whole.astype(int)):
                w = windows[i]
                windows[i] = Window(w.iy0, w.ny, (w.ix0 + k) % grid.nx, w.nx)
        block[...] = shift_rows(block, shifts)
    return windows


def advect_semi_lagrangian(
    fields: list[np.ndarray], windows: list[Window], grid: ChannelGrid, flow: Flow, dt: float
) -> tuple[list[np.ndarray], list[Window]]:
    """Advect all fields over dt in any flow, by cubic interpolation at departure points."""
    out_fields, out_windows = [], []
    for phi, w in zip(fields, windows):
        ux, uy = _velocity(flow, *_node_coordinates(w, grid), grid)
        # move the window with the mean displacement so the departure points stay inside it
        kx = int(np.rint(np.mean(ux) * dt / grid.h)) if w.nx < grid.nx else 0
        ky = int(np.rint(np.mean(uy) * dt / grid.h))
        iy0 = min(max(w.iy0 + ky, 0), grid.ny - w.ny)
        new = Window(iy0, w.ny, (w.ix0 + kx) % grid.nx, w.nx)
        xn, yn = _node_coordinates(new, grid)
        u0, v0 = _velocity(flow, xn, yn, grid)
        um, vm = _velocity(flow, xn - 0.5 * dt * u0, yn - 0.5 * dt * v0, grid)
        xd = xn - dt * um
        yd = np.clip(yn - dt * vm, 0.0, grid.width)
        values = map_coordinates(
            pad_window(phi, w, grid, _PAD), [yd / grid.h - w.iy0 + _PAD, _local_columns(xd, w, grid) + _PAD],
            order=3, mode="nearest",
        )
        out_fields.append(values)
        out_windows.append(new)
    return out_fields, out_windows


_PAD = 4


def _local_columns(x: np.ndarray, w: Window, grid: ChannelGrid) -> np.ndarray:
    """x (lattice units) as a column coordinate of window w, unwrapped near the window."""
    col = (x / grid.h - w.ix0) % grid.nx
    if w.nx == grid.nx:
        return col
    # points just left of the window come out near nx; bring them back below zero
    return np.where(col > 0.5 * (w.nx + grid.nx), col - grid.nx, col)


def _node_coordinates(w: Window, grid: ChannelGrid) -> tuple[np.ndarray, np.ndarray]:
    x = np.broadcast_to(w.columns(grid)[None, :] * grid.h, (w.ny, w.nx))
    y = np.broadcast_to(w.rows()[:, None] * grid.h, (w.ny, w.nx))
    return x, y


def _velocity(flow: Flow, x: np.ndarray, y: np.ndarray, grid: ChannelGrid):
    """(u, v) at points, x wrapped into [0, Lx) and y clipped to the channel."""
    x = np.mod(x, grid.length)
    y = np.clip(y, 0.0, grid.width)
    u, v = flow.velocity(x, y)
    return np.broadcast_to(u, x.shape), np.broadcast_to(v, x.shape)
