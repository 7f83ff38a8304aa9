"""The flat interface: the discrete equilibrium against (1 + tanh(d/λ))/2, vs h.

    python -m verification.flat_interface [--quick]

Setup: one field, no flow, μ = 0 (no area term), the paper's λ, γ, J0. The interface runs
along x at y = Ly/2 and the field depends on y only. That is exactly one-dimensional on this
mesh: the P1 stiffness of the right-isosceles triangulation is the 5-point Laplacian and the
lumped mass is uniform (halved on the walls, with the wall rows of K halved too: a mirror), so
a y-only field obeys exactly the 3-point scheme in y and stays y-only (the x-variation is
recorded to show it). The walls are Neumann mirrors, so the field is one interface of a
periodic array of period 2Ly: with Ly = 64 = 32λ the interaction is ~e^{−Ly/λ}, negligible.
The symmetry φ(Ly − y) = 1 − φ(y) (W'(1 − φ) = −W'(φ); Ly/h even puts a node at Ly/2) is
kept by every step and pins the interface, otherwise free to slide, at y = Ly/2.

The start is the profile of twice the width; it relaxes with dt = 5 (automatic
stabilisation) until no node changes by more than 1e-14 in a step. The fixed point of the
step does not depend on dt or S: it solves 2γλ K φ + M_L g(φ) = 0.

Measured against φ_e(y) = (1 + tanh((y − y_c)/λ))/2, with y_c the φ = 1/2 crossing of the
nodal values (linear interpolation between the nodes that bracket it):

* max nodal error and the L2 error per unit interface length (trapezoid rule in y);
* the interface energy per unit length F_h/Lx against σ = (γ/λ)∫[W + λ²φ_e'²] = 2γ/3.

Expected: order 2 for all three (a second-order 3-point scheme with nodal quadrature).
"""

from __future__ import annotations

import os

# one BLAS thread: the machine's two cores are shared with other long runs
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import time  # noqa: E402
from dataclasses import asdict, replace  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from femphase.domains.grid.domain import GridDomain  # noqa: E402
from femphase.model.energy import FreeEnergy, WindowedFields  # noqa: E402
from femphase.domains.grid.lattice import channel_grid  # noqa: E402
from femphase.model.parameters import ModelParameters, interface_profile  # noqa: E402
from femphase.state import State  # noqa: E402
from femphase.config import Numerics  # noqa: E402
from femphase.timestepping.stepper import Stepper
from verification.mms import command_line, log_axes, observed_orders, save_figure, save_results  # noqa: E402

PARAMS = replace(ModelParameters(), area_stiffness=0.0)
LX, LY = 4.0, 64.0
DT = 5.0
TOLERANCE = 1e-14  # largest nodal change in the last step
MAX_STEPS = 20_000
SPACINGS = (2.0, 1.0, 0.5, 0.25, 0.125)
QUICK_SPACINGS = (1.0, 0.5, 0.25)
EXPECTED = {"order": 2.0, "order_max": 2.0, "order_energy": 2.0}


def tension() -> float:
    """σ = 2γ/3: the energy per unit length of the exact flat interface."""
    return 2.0 * PARAMS.tension / 3.0


def equilibrium(h: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """Relax the flat interface on spacing h: (y of the rows, the profile φ(y), diagnostics)."""
    grid = channel_grid(LX, LY, h)
    domain = GridDomain(grid)
    _, y = grid.coordinates()
    start = interface_profile(y - 0.5 * LY, 2.0 * PARAMS.interface_width)
    # one flat field in grid order (dof = iy * nx + ix)
    state = State(domain, [domain.full_window()], [np.repeat(start, grid.nx)], np.array([PARAMS.radius]))
    stepper = Stepper(domain, PARAMS, Numerics(scheme="euler", windows=False), DT, None, state.radii)
    change = np.inf
    while change > TOLERANCE:
        if state.step == MAX_STEPS:
            raise RuntimeError(f"h = {h}: no equilibrium after {MAX_STEPS} steps (change {change:.2e})")
        previous = state.fields[0].copy()
        stepper.step(state)
        change = float(np.abs(state.fields[0] - previous).max())
    field = state.fields[0].reshape(grid.ny, grid.nx)
    layout, phi = state.flat()
    energy = FreeEnergy.paper(PARAMS).parts(WindowedFields(phi, layout, state.radii, domain.stiffness_apply(layout)))
    diagnostics = {
        "steps": state.step,
        "energy_per_length": energy.total / LX,
        "x_variation": float(np.ptp(field, axis=1).max()),
    }
    return y, field[:, 0].copy(), diagnostics


def half_crossing(y: np.ndarray, phi: np.ndarray) -> float:
    """y where the increasing nodal profile crosses 1/2 (linear interpolation)."""
    j = int(np.flatnonzero(phi >= 0.5)[0])
    return float(y[j - 1] + (0.5 - phi[j - 1]) / (phi[j] - phi[j - 1]) * (y[j] - y[j - 1]))


def profile_errors(y: np.ndarray, phi: np.ndarray) -> dict:
    """Errors of the nodal profile against the exact one centred at its φ = 1/2 crossing."""
    centre = half_crossing(y, phi)
    error = phi - interface_profile(y - centre, PARAMS.interface_width)
    weights = np.full(y.size, y[1] - y[0])
    weights[[0, -1]] *= 0.5
    return {
        "centre_shift": centre - 0.5 * LY,
        "max_error": float(np.abs(error).max()),
        "L2_error": float(np.sqrt(weights @ error**2)),
    }


def study(spacings: tuple[float, ...]) -> dict:
    """Errors of the discrete equilibrium against h."""
    table = {key: [] for key in ("h", "max_error", "L2_error", "energy_error", "centre_shift",
                                 "steps", "x_variation")}
    profiles = {}
    for h in spacings:
        y, phi, diagnostics = equilibrium(h)
        errors = profile_errors(y, phi)
        table["h"].append(h)
        for key in ("max_error", "L2_error", "centre_shift"):
            table[key].append(errors[key])
        table["energy_error"].append(diagnostics["energy_per_length"] - tension())
        table["steps"].append(diagnostics["steps"])
        table["x_variation"].append(diagnostics["x_variation"])
        profiles[h] = (y, phi)
    table["orders_L2"] = observed_orders(table["h"], table["L2_error"])
    table["orders_max"] = observed_orders(table["h"], table["max_error"])
    table["orders_energy"] = observed_orders(table["h"], np.abs(table["energy_error"]))
    table["profiles"] = {
        str(h): {"y": y.tolist(), "phi": phi.tolist()} for h, (y, phi) in profiles.items()
    }
    return table


def plot(results: dict, path: Path) -> None:
    table = results["table"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    for h, profile in table["profiles"].items():
        h = float(h)
        d = np.array(profile["y"]) - 0.5 * LY
        error = np.array(profile["phi"]) - interface_profile(d, PARAMS.interface_width)
        near = np.abs(d) <= 5 * PARAMS.interface_width
        left.plot(d[near], error[near] / h**2, ".-", ms=4, lw=0.8, label=f"h = {h:g}")
    left.set(xlabel="d = y − Ly/2", ylabel="(φ_h − φ_e) / h²",
             title="Flat interface: nodal error / h² (collapses at order 2)")
    left.legend(fontsize=8)
    h = np.array(table["h"])
    right.loglog(h, table["L2_error"], "o-", label="L2 per unit length")
    right.loglog(h, table["max_error"], "s-", label="max nodal")
    right.loglog(h, np.abs(table["energy_error"]), "^-", label="|F_h/Lx − 2γ/3|")
    right.loglog(h, table["L2_error"][-1] * (h / h[-1]) ** 2, "k:", lw=0.8, label="slope 2")
    log_axes(right, h)
    right.set(xlabel="h", ylabel="error", title="Flat interface: error vs h")
    right.legend(fontsize=8)
    save_figure(fig, path)


def run(quick: bool = False, output: Path | None = None) -> dict:
    """The h study; writes results/flat_interface.json and .png (or into
    ``output``)."""
    start = time.perf_counter()
    table = study(QUICK_SPACINGS if quick else SPACINGS)
    results = {
        "check": "flat_interface",
        "quick": quick,
        "order": table["orders_L2"][-1],
        "order_max": table["orders_max"][-1],
        "order_energy": table["orders_energy"][-1],
        "expected": EXPECTED,
        "orders_from": "the two finest spacings",
        "setup": {
            "geometry": f"channel {LX:g} x {LY:g}, interface along x at y = Ly/2, field of y only",
            "model": asdict(PARAMS),
            "relaxation": f"dt = {DT:g}, stabilisation auto, until max nodal change < {TOLERANCE:g}",
            "start": "(1 + tanh((y - Ly/2)/(2 lambda)))/2",
            "exact": "(1 + tanh((y - y_c)/lambda))/2, y_c the phi = 1/2 crossing",
            "tension": tension(),
        },
        "table": table,
    }
    return save_results("flat_interface", results, plot, start, output)


if __name__ == "__main__":
    command_line("flat_interface", run, ("order", "order_max", "order_energy"))
