"""An isolated particle at rest: its equilibrium converged in h and dt.

    python -m verification.equilibrium [--quick]

The paper's parameters (R = 8) and protocol: a disc of radius R/2 at the centre of a
48 × 48 channel, per-particle window on (margin 4), no flow, relaxed until neither ∫φ² nor
∫φ changes by more than 1e-10 over a time unit (one step for dt = 10), t ≈ 800: the
remaining error is ~1e-10/κ ≈ 3e-9, κ ≈ 0.04 the slowest relaxation rate. Every (h, dt) of
h ∈ {2, 1, 0.5, 0.25}, dt ∈ {10, 1, 0.1} is run, and h = 0.125 at dt = 1: the three coarser
spacings are not yet asymptotic for the contour radius (observed order 1.6 from h = 1, 0.5,
0.25). Measured at equilibrium:

* ``area``      ∫φ², the quantity the soft constraint holds near πR² = 201.06;
* ``mass``      ∫φ (nodal quadrature, as ∫φ²);
* ``radius``    r_½ = sqrt(A_½/π), A_½ the area of {φ_h ≥ 1/2} of the P1 field, computed
                exactly triangle by triangle (the region of a linear function above a level
                is a triangle or a quadrilateral);
* ``radius_from_mass``  sqrt(∫φ/π − π²λ²/12), the radius a disc with the flat profile
                (1 + tanh((r − d)/λ))/2 and φ = 1 inside would have (∫φ = πr² + π³λ²/12 for
                that profile). It is biased high: the pressure of the area constraint lifts
                the interior above 1 (``interior``, below);
* ``interior``  φ at the centre, against the bulk balance (γ/λ) W'(1 + δ) = f (1 + δ),
                f = 4μ(1 − a)/(πR²), i.e. 16(γ/λ)δ² + 8(γ/λ)δ = f (``interior_bulk``).

Expected: order 2 in h for every quantity (second-order equilibria; A_½ from the P1 field is
second order as well); independent of dt, since the fixed point of the no-flow step solves
2γλ K φ + M_L g(φ) = 0 whatever dt and the stabilisation S are, up to where each run stops.
(With the automatic S, dt = 10 advances as dt* = 2/(J0 L) ≈ 3.0 would, L the explicit terms'
curvature bound for one particle: 1/(J0 dt) + S = L/2 for every dt ≥ dt*; dt = 1 and 0.1 are
below dt*, with S = 0.) Richardson extrapolation uses the three finest h (at the dt the finest
was run with): observed order p = log2((Q_1 − Q_½)/(Q_½ − Q_¼)), limit Q_¼ + (Q_¼ − Q_½)/(2^p − 1).
The window's truncation (the field is zero beyond its window) is measured against full-mesh
runs at h = 1, 0.5, 0.25 (dt = 1).
"""

from __future__ import annotations

import os

# one BLAS thread: the machine's two cores are shared with other long runs
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import time  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import NullFormatter  # noqa: E402
import numpy as np  # noqa: E402

from femphase.analysis.shape import shape_observables  # noqa: E402
from femphase.domains.grid.domain import GridDomain  # noqa: E402
from femphase.domains.grid.lattice import channel_grid  # noqa: E402
from femphase.model.parameters import ModelParameters  # noqa: E402
from femphase.state import State, discs_state  # noqa: E402
from femphase.config import Numerics  # noqa: E402
from femphase.timestepping.stepper import Stepper
from verification.mms import command_line, log_axes, observed_orders, save_figure, save_results  # noqa: E402

PARAMS = ModelParameters()
SIZE = 48.0  # Lx = Ly
TOLERANCE = 1e-10  # largest change of ∫φ² or ∫φ over the last time unit
MAX_STEPS = 50_000
SPACINGS = (2.0, 1.0, 0.5, 0.25)
STEPS = (10.0, 1.0, 0.1)
#: every (h, dt), and h = 0.125 at dt = 1 so that the extrapolation is asymptotic (the
#: fixed point does not depend on dt; dt = 0.1 there would cost 8 minutes)
PLAN = [(h, dt) for h in SPACINGS for dt in STEPS] + [(0.125, 1.0)]
#: quick: the h study at dt = 1, the dt study at h = 2
QUICK_PLAN = [(h, 1.0) for h in (1.0, 0.5, 0.25)] + [(2.0, dt) for dt in STEPS]
#: spacings (at dt = 1) where the windowed equilibrium is compared with the full-mesh one
WINDOW_CHECK = (1.0, 0.5, 0.25)
QUICK_WINDOW_CHECK = (0.5,)
QUANTITIES = ("area", "mass", "radius", "radius_from_mass", "interior")
EXPECTED_ORDER = 2.0


def superlevel_area(domain: GridDomain, phi: np.ndarray, level: float = 0.5) -> float:
    """Area of {φ_h ≥ level} of the P1 field with nodal values phi (per dof, grid order),
    exactly."""
    low, middle, high = np.sort(phi[domain.dof_map[domain.mesh.t]], axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        # only the highest corner above: a similar triangle at that corner
        one_above = (high - level) ** 2 / ((high - low) * (high - middle))
        # only the lowest corner below: the triangle minus one at the lowest corner
        two_above = 1.0 - (level - low) ** 2 / ((high - low) * (middle - low))
    fraction = np.select([low >= level, middle >= level, high > level], [1.0, two_above, one_above], 0.0)
    return float(domain.operators.element_area @ fraction)


def interior_bulk(area: float) -> float:
    """1 + δ, the bulk value balancing the double well against the area pressure."""
    lam, gamma = PARAMS.interface_width, PARAMS.tension
    force = 4 * PARAMS.area_stiffness * (1 - area / (np.pi * PARAMS.radius**2)) / (np.pi * PARAMS.radius**2)
    a, b = 16 * gamma / lam, 8 * gamma / lam
    return 1.0 + (-b + np.sqrt(b * b + 4 * a * force)) / (2 * a)


CENTRE = (0.5 * SIZE, 0.5 * SIZE)


def relaxed_state(h: float, dt: float, windows: bool = True) -> tuple[GridDomain, State]:
    """The particle relaxed from a disc of radius R/2 on spacing h with step dt."""
    domain = GridDomain(channel_grid(SIZE, SIZE, h))
    # the linearly implicit Euler step's fixed point is the discrete equilibrium, whatever dt
    numerics = Numerics(scheme="euler", windows=windows)
    state = discs_state(domain, np.array([CENTRE]), np.array([PARAMS.radius]), np.array([0.5 * PARAMS.radius]),
                        PARAMS.interface_width, domain.window_policy(numerics))
    stepper = Stepper(domain, PARAMS, numerics, dt, None, state.radii)
    # compare ∫φ² and ∫φ every time unit (or step): they do not see the particle's slow
    # drift (a neutral mode) that keeps nodal values changing
    interval = max(1, round(1.0 / dt))
    integrals = np.zeros(2)
    change = np.inf
    while change > TOLERANCE:
        if state.step > MAX_STEPS:
            raise RuntimeError(f"h = {h}, dt = {dt}: no equilibrium in {MAX_STEPS} steps (change {change:.2e})")
        for _ in range(interval):
            stepper.step(state)
        previous, integrals = integrals, np.array(integrals_of(domain, state))
        change = float(np.abs(integrals - previous).max())
    return domain, state


def integrals_of(domain: GridDomain, state: State) -> tuple[float, float]:
    """(∫φ², ∫φ) of the state's one field, nodal quadrature."""
    phi = state.global_field(0)
    return float(phi**2 @ domain.operators.lumped_mass), float(phi @ domain.operators.lumped_mass)


def measure(domain: GridDomain, state: State) -> dict:
    """The equilibrium quantities of the module docstring, and run diagnostics."""
    grid, phi = domain.grid, state.global_field(0)
    shape = shape_observables(state)
    area, mass = integrals_of(domain, state)
    centre_node = (grid.ny // 2) * grid.nx + grid.nx // 2  # the node at (Lx/2, Ly/2)
    return {
        "area": area,
        "mass": mass,
        "radius": float(np.sqrt(superlevel_area(domain, phi) / np.pi)),
        "radius_from_mass": float(np.sqrt(mass / np.pi - (np.pi * PARAMS.interface_width) ** 2 / 12)),
        "interior": float(phi[centre_node]),
        "interior_bulk": float(interior_bulk(area)),
        "drift": float(np.hypot(shape.x[0] - CENTRE[0], shape.y[0] - CENTRE[1])),
        "time": state.time,
        "steps": state.step,
        "window": list(asdict(state.windows[0]).values()),
    }


def relax(h: float, dt: float, windows: bool = True) -> dict:
    """The measured equilibrium on spacing h with step dt."""
    return measure(*relaxed_state(h, dt, windows))


def richardson(sizes: list[float], values: list[float]) -> dict:
    """Observed order and extrapolated limit from the last three levels (sizes halving)."""
    coarse, middle, fine = values[-3:]
    ratio = sizes[-3] / sizes[-2]
    order = float(np.log(abs((coarse - middle) / (middle - fine))) / np.log(ratio))
    return {"order": order, "limit": float(fine + (fine - middle) / (ratio**order - 1))}


def study(plan: list[tuple[float, float]]) -> dict:
    """Every run of the plan, then per quantity the h × dt table, the extrapolation and the
    spread over dt."""
    runs = {}
    for h, dt in plan:
        runs[(h, dt)] = relax(h, dt)
        print(f"h = {h:5g} dt = {dt:5g}: area {runs[(h, dt)]['area']:.10g} "
              f"(t = {runs[(h, dt)]['time']:.0f}, {runs[(h, dt)]['steps']} steps)", flush=True)
    spacings = sorted({h for h, _ in plan}, reverse=True)
    steps = sorted({dt for _, dt in plan}, reverse=True)
    # extrapolate at the (smallest) dt the finest h was run with
    column = min(dt for dt in steps if (spacings[-1], dt) in runs)
    column_h = [h for h in spacings if (h, column) in runs]
    quantities = {}
    for name in QUANTITIES:
        table = [[runs[(h, dt)][name] if (h, dt) in runs else None for dt in steps] for h in spacings]
        values = [runs[(h, column)][name] for h in column_h]
        spread = [max(row_values) - min(row_values) for row_values in
                  ([v for v in row if v is not None] for row in table) if len(row_values) > 1]
        quantities[name] = {
            "table": table,
            **richardson(column_h, values),
            # orders from consecutive differences, coarse to fine
            "orders_h": observed_orders(column_h[:-1], np.abs(np.diff(values))),
            "dt_spread": max(spread) if spread else None,
        }
    return {
        "h": spacings,
        "dt": steps,
        "extrapolation_dt": column,
        "extrapolation_h": column_h,
        "quantities": quantities,
        "runs": [{"h": h, "dt": dt, **values} for (h, dt), values in runs.items()],
    }


def window_truncation(data: dict, spacings: tuple[float, ...]) -> dict:
    """Windowed minus full-mesh equilibrium at dt = 1 (the windowed runs taken from ``data``),
    and the drift on the full mesh (none is expected there: the setup is symmetric)."""
    windowed = {run["h"]: run for run in data["runs"] if run["dt"] == 1.0}
    table = {"h": list(spacings), **{name: [] for name in QUANTITIES}, "full_mesh_drift": []}
    for h in spacings:
        full_mesh = relax(h, 1.0, windows=False)
        for name in QUANTITIES:
            table[name].append(windowed[h][name] - full_mesh[name])
        table["full_mesh_drift"].append(full_mesh["drift"])
    return table


def plot(results: dict, path: Path) -> None:
    data = results["study"]
    names = ("area", "mass", "radius", "radius_from_mass")
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(17, 3.8))
    for ax, name in zip(axes, names):
        quantity = data["quantities"][name]
        for j, dt in enumerate(data["dt"]):
            points = [(h, row[j]) for h, row in zip(data["h"], quantity["table"]) if row[j] is not None]
            if points:
                h, values = zip(*points)
                ax.plot(h, values, "os^"[j] + "-", mfc="none", ms=6 + 2 * j, label=f"dt = {dt:g}")
        ax.axhline(quantity["limit"], color="k", ls=":", lw=0.8, label="Richardson limit")
        ax.set_xscale("log")
        ax.set_xticks(data["h"], [f"{h:g}" for h in data["h"]])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set(xlabel="h", title=f"{name} (order {quantity['order']:.2f})")
        ax.legend(fontsize=7)
    # convergence: distance of each h (at the extrapolation dt) from the limit
    ax = axes[-1]
    h = np.array(data["extrapolation_h"])
    for name in names:
        quantity = data["quantities"][name]
        column = data["dt"].index(data["extrapolation_dt"])
        values = np.array([row[column] for row, hh in zip(quantity["table"], data["h"]) if hh in h])
        ax.plot(h, np.abs(values - quantity["limit"]) / abs(quantity["limit"]), "o-", ms=4, label=name)
    log_axes(ax, h)
    ax.plot(h, 1e-4 * (h / h[-1]) ** 2, "k:", lw=0.8, label="slope 2")
    ax.set(xlabel="h", title=f"|Q − limit| / limit, dt = {data['extrapolation_dt']:g}")
    ax.legend(fontsize=7)
    fig.suptitle(f"Isolated particle at rest, R = {PARAMS.radius:g}: equilibrium vs h and dt")
    save_figure(fig, path)


def run(quick: bool = False, output: Path | None = None) -> dict:
    """The (h, dt) study and the window check; writes results/equilibrium.json and .png (or into
    ``output``)."""
    start = time.perf_counter()
    data = study(QUICK_PLAN if quick else PLAN)
    truncation = window_truncation(data, QUICK_WINDOW_CHECK if quick else WINDOW_CHECK)
    quantities = data["quantities"]
    results = {
        "check": "equilibrium",
        "quick": quick,
        **{f"{name}_limit": quantities[name]["limit"] for name in QUANTITIES},
        **{f"{name}_order": quantities[name]["order"] for name in QUANTITIES},
        "expected": {**{f"{name}_order": EXPECTED_ORDER for name in QUANTITIES}, "dt_spread": 0.0},
        "target_area": float(np.pi * PARAMS.radius**2),
        "window_truncation": truncation,
        "setup": {
            "model": asdict(PARAMS),
            "domain": f"{SIZE:g} x {SIZE:g}, particle at the centre, windows on",
            "start": "disc of radius R/2 (the paper's protocol)",
            "relaxation": f"until int phi^2 and int phi change by < {TOLERANCE:g} per time unit (per step if dt > 1)",
            "radius": "sqrt(area of {phi_h >= 1/2} of the P1 field / pi), exact per triangle",
            "radius_from_mass": "sqrt(int phi / pi - pi^2 lambda^2 / 12) (flat profile, phi = 1 inside)",
            "window_truncation": "windowed minus full-mesh values at dt = 1; drift on the full mesh",
        },
        "study": data,
    }
    return save_results("equilibrium", results, plot, start, output)


if __name__ == "__main__":
    command_line("equilibrium", run, ("area_limit", "area_order", "radius_limit", "radius_order"))
