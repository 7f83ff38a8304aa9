"""Manufactured solution for one field in a shear flow: observed orders in h and dt.

    python -m verification.mms [--quick]

The exact solution (lattice units, model time units)

    φ_e(x, y, t) = 1/2 + A cos(kx − ωt) cos(qy) e^{−t/τ},    k = 2π/Lx,  q = π/Ly,

is periodic in x, has ∂yφ_e = 0 on the walls y = 0 and y = Ly, and stays in
[1/2 − A, 1/2 + A] = [0.05, 0.95], where the double well W'(φ) = 8φ(1 − φ)(1 − 2φ) is far
from linear. It travels in x (ω), decays (τ) and is sheared by u = γ̇ y/Ly
(:func:`femphase.flows.linear_shear`). The stepper's ``source`` hook adds

    s = ∂tφ_e + u ∂xφ_e + J0 [(γ/λ) W'(φ_e) − 2γλ Δφ_e − (4μ/πR²)(1 − a_e) φ_e],

with the paper's parameters, the area term included: a_e = ∫φ_e²/(πR²) =
LxLy(1 + A²e^{−2t/τ})/(4πR²) exactly, and the stepper's nodal quadrature integrates φ_e²
exactly too (a trigonometric polynomial summed over whole periods), so the nonlocal term is
consistent. One field on the whole mesh (numerics.windows = false), so no repulsion.

Errors at the final time T, measured on the P1 field with a degree-6 rule per triangle
(so the measurement is far more accurate than the errors it measures):

* L2:  ‖φ_h − φ_e‖, φ_h the P1 interpolant of the nodal values;
* H1:  ‖∇φ_h − ∇φ_e‖, ∇φ_h the constant gradient of each element (operators.gradient).

Expected: P1 gives order 2 in L2 (mass lumping keeps it: on this mesh M_L⁻¹K is the
5-point Laplacian) and 1 in H1; the Lie-split, linearly implicit Euler step is first order in
dt. The spatial study takes dt = h²/8 and h²/16 and measures the time-extrapolated field
2φ_{h²/16} − φ_{h²/8}, whose O(dt) error is removed, so that the table shows the spatial
error alone (raw errors at dt = h²/16 are listed too: dt ∝ h² keeps them O(h²) as well).
The temporal study fixes h = 0.125, whose spatial L2 error is < 1% of the smallest temporal
one, and takes dt ≤ 0.5 < 2/(J0 L) where the automatic stabilisation is zero. A second
temporal study (``order_dt_2``) does the same for the second-order scheme ``sav2`` at
h = 0.0625 and dt = 1, 0.5, 0.25.

This module also holds the helpers the other convergence checks share (observed orders,
writing results, the command line).
"""

from __future__ import annotations

import os

# one BLAS thread: the machine's two cores are shared with other long runs
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import FixedFormatter, FixedLocator, NullFormatter  # noqa: E402
import numpy as np  # noqa: E402
from skfem.quadrature import get_quadrature  # noqa: E402
from skfem.refdom import RefTri  # noqa: E402

from femphase.domains.grid.domain import GridDomain  # noqa: E402
from femphase.flows import linear_shear  # noqa: E402
from femphase.io.files import write_json  # noqa: E402
from femphase.domains.grid.lattice import channel_grid  # noqa: E402
from femphase.model.parameters import ModelParameters, double_well_derivative  # noqa: E402
from femphase.state import State  # noqa: E402
from femphase.config import Numerics  # noqa: E402
from femphase.timestepping.stepper import Stepper

RESULTS = Path(__file__).resolve().parent / "results"

PARAMS = ModelParameters()  # the paper's λ, γ, κ, μ, J0 and R = 8
LX, LY = 16.0, 8.0
AMPLITUDE = 0.45
FREQUENCY = 0.2  # ω (1/time)
DECAY_TIME = 20.0  # τ
SHEAR_RATE = 1.0  # γ̇: the top wall's velocity
FINAL_TIME = 10.0
WAVENUMBER_X, WAVENUMBER_Y = 2 * np.pi / LX, np.pi / LY

SPACINGS = (2.0, 1.0, 0.5, 0.25, 0.125)
QUICK_SPACINGS = (2.0, 1.0, 0.5)
TEMPORAL = (0.125, (0.5, 0.25, 0.125, 0.0625, 0.03125))
QUICK_TEMPORAL = (0.5, (0.25, 0.125, 0.0625))
#: The second-order scheme sav2: its errors fall 4× per halving, so h must be finer to keep
#: the spatial error (extrapolated: ~1e-4 at h = 0.0625, a quarter of h = 0.125's) below its
#: temporal errors (5e-3 at dt = 0.25).
TEMPORAL_2 = (0.0625, (1.0, 0.5, 0.25))
QUICK_TEMPORAL_2 = (0.25, (2.0, 1.0))
EXPECTED = {"order_h_L2": 2.0, "order_h_H1": 1.0, "order_dt": 1.0, "order_dt_2": 2.0}


# -- the manufactured solution -------------------------------------------------------------
def _factors(x, y, t):
    phase = WAVENUMBER_X * np.asarray(x) - FREQUENCY * t
    return phase, np.cos(WAVENUMBER_Y * np.asarray(y)), AMPLITUDE * np.exp(-t / DECAY_TIME)


def exact(x: np.ndarray, y: np.ndarray, t: float) -> np.ndarray:
    """φ_e at points (x, y) and time t."""
    phase, wall_mode, amplitude = _factors(x, y, t)
    return 0.5 + amplitude * np.cos(phase) * wall_mode


def exact_gradient(x: np.ndarray, y: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(∂xφ_e, ∂yφ_e) at points (x, y) and time t."""
    phase, wall_mode, amplitude = _factors(x, y, t)
    return (
        -WAVENUMBER_X * amplitude * np.sin(phase) * wall_mode,
        -WAVENUMBER_Y * amplitude * np.cos(phase) * np.sin(WAVENUMBER_Y * np.asarray(y)),
    )


def exact_area_ratio(t: float) -> float:
    """a_e = ∫φ_e² / (πR²) over the channel, in closed form."""
    amplitude = AMPLITUDE * np.exp(-t / DECAY_TIME)
    return LX * LY * (1.0 + amplitude**2) / (4.0 * np.pi * PARAMS.radius**2)


def source(x: np.ndarray, y: np.ndarray, t: float) -> np.ndarray:
    """s = ∂tφ_e + u ∂xφ_e + J0 δF/δφ[φ_e] (the stepper's ``source`` hook)."""
    phase, wall_mode, amplitude = _factors(x, y, t)
    phi = 0.5 + amplitude * np.cos(phase) * wall_mode
    dphi_dt = amplitude * wall_mode * (FREQUENCY * np.sin(phase) - np.cos(phase) / DECAY_TIME)
    dphi_dx = -WAVENUMBER_X * amplitude * np.sin(phase) * wall_mode
    laplacian = -(WAVENUMBER_X**2 + WAVENUMBER_Y**2) * (phi - 0.5)
    p = PARAMS
    area_force = 4.0 * p.area_stiffness / (np.pi * p.radius**2) * (1.0 - exact_area_ratio(t))
    variation = (
        p.tension / p.interface_width * double_well_derivative(phi)
        - 2.0 * p.tension * p.interface_width * laplacian
        - area_force * phi
    )
    velocity = SHEAR_RATE * np.asarray(y) / LY
    return dphi_dt + velocity * dphi_dx + p.mobility * variation


# -- solving and measuring -------------------------------------------------------------------
def simulate(h: float, dt: float, scheme: str = "euler") -> tuple[GridDomain, np.ndarray, float]:
    """The discrete solution at FINAL_TIME on spacing h with step dt: (domain, nodal values
    in grid order, the stabilisation S the stepper's Euler scheme chose; 0 for sav2)."""
    domain = GridDomain(channel_grid(LX, LY, h))
    x, y = domain.coordinates  # of every dof, grid order
    state = State(domain, [domain.full_window()], [exact(x, y, 0.0)], np.array([PARAMS.radius]))
    # double precision: the finest errors measured here (~6e-4 in L2 at h = 0.125) must not
    # carry the ~1e-6 rounding of numerics.precision = "mixed"
    stepper = Stepper(domain, PARAMS, Numerics(windows=False, scheme=scheme, precision="double"), dt,
                      linear_shear(SHEAR_RATE, LY), state.radii, source)
    for _ in range(round(FINAL_TIME / dt)):
        stepper.step(state)
    return domain, state.global_field(0), getattr(stepper.scheme, "stabilisation", 0.0)


_POINTS, _WEIGHTS = get_quadrature(RefTri, 6)
_WEIGHTS = _WEIGHTS / _WEIGHTS.sum()  # fractions of the element's area
#: barycentric coordinates of the quadrature points, (3 vertices, n_points)
_BARYCENTRIC = np.stack([1.0 - _POINTS[0] - _POINTS[1], _POINTS[0], _POINTS[1]])


def error_norms(domain: GridDomain, phi: np.ndarray, t: float) -> tuple[float, float]:
    """(‖φ_h − φ_e‖_L2, ‖∇φ_h − ∇φ_e‖_L2) of the P1 field with nodal values phi (per dof) at
    time t."""
    mesh, ops = domain.mesh, domain.operators
    corners = mesh.p[:, mesh.t]  # (2, 3, n_elements), the non-periodic coordinates
    x, y = np.einsum("dve,vq->deq", corners, _BARYCENTRIC)
    values = np.einsum("ve,vq->eq", phi[domain.dof_map[mesh.t]], _BARYCENTRIC)
    weights = ops.element_area[:, None] * _WEIGHTS[None, :]
    l2 = np.sum(weights * (values - exact(x, y, t)) ** 2)
    gx, gy = exact_gradient(x, y, t)
    h1 = np.sum(weights * ((ops.gradient[0] @ phi)[:, None] - gx) ** 2
                + weights * ((ops.gradient[1] @ phi)[:, None] - gy) ** 2)
    return float(np.sqrt(l2)), float(np.sqrt(h1))


def spatial_study(spacings: tuple[float, ...]) -> dict:
    """Errors against h of the time-extrapolated field 2φ(dt = h²/16) − φ(dt = h²/8), and the
    raw errors at dt = h²/16."""
    table = {"h": [], "dt": [], "L2": [], "H1": [], "L2_raw": [], "H1_raw": []}
    for h in spacings:
        domain, coarse, _ = simulate(h, h * h / 8)
        _, fine, _ = simulate(h, h * h / 16)
        extrapolated = error_norms(domain, 2.0 * fine - coarse, FINAL_TIME)
        raw = error_norms(domain, fine, FINAL_TIME)
        for key, value in zip(("h", "dt", "L2", "H1", "L2_raw", "H1_raw"),
                              (h, h * h / 16, *extrapolated, *raw)):
            table[key].append(value)
    for key in ("L2", "H1", "L2_raw"):
        table[f"orders_{key}"] = observed_orders(table["h"], table[key])
    return table


def temporal_study(h: float, steps: tuple[float, ...], scheme: str = "euler") -> dict:
    """Errors against dt at fixed h with the time scheme ``scheme``."""
    table = {"h": h, "scheme": scheme, "dt": list(steps), "L2": [], "H1": [], "stabilisation": []}
    for dt in steps:
        domain, phi, stabilisation = simulate(h, dt, scheme)
        l2, h1 = error_norms(domain, phi, FINAL_TIME)
        table["L2"].append(l2)
        table["H1"].append(h1)
        table["stabilisation"].append(stabilisation)
    table["orders_L2"] = observed_orders(table["dt"], table["L2"])
    table["orders_H1"] = observed_orders(table["dt"], table["H1"])
    return table


def plot(results: dict, path: Path) -> None:
    space, time_ = results["spatial"], results["temporal"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    h = np.array(space["h"])
    left.loglog(h, space["L2"], "o-", label="L2 (time-extrapolated)")
    left.loglog(h, space["L2_raw"], "o--", mfc="none", label="L2 raw, dt = h²/16")
    left.loglog(h, space["H1"], "s-", label="H1 seminorm (time-extrapolated)")
    left.loglog(h, space["L2"][-1] * (h / h[-1]) ** 2, "k:", lw=0.8, label="slope 2")
    left.loglog(h, space["H1"][-1] * (h / h[-1]), "k-.", lw=0.8, label="slope 1")
    log_axes(left, h)
    left.set(xlabel="h", ylabel="error at t = T", title="MMS: error vs h")
    left.legend(fontsize=8)
    dt = np.array(time_["dt"])
    right.loglog(dt, time_["L2"], "o-", label=f"L2, euler (h = {time_['h']:g})")
    right.loglog(dt, time_["H1"], "s-", label="H1 seminorm, euler")
    right.loglog(dt, time_["L2"][-1] * dt / dt[-1], "k:", lw=0.8, label="slope 1")
    second = results["temporal_2"]
    dt2 = np.array(second["dt"])
    right.loglog(dt2, second["L2"], "^-", label=f"L2, sav2 (h = {second['h']:g})")
    right.loglog(dt2, second["L2"][-1] * (dt2 / dt2[-1]) ** 2, "k--", lw=0.8, label="slope 2")
    log_axes(right, np.union1d(dt, dt2))
    right.set(xlabel="dt", ylabel="error at t = T", title="MMS: error vs dt")
    right.legend(fontsize=8)
    save_figure(fig, path)


def run(quick: bool = False, output: Path | None = None) -> dict:
    """Both studies; writes results/mms.json and results/mms.png (or into ``output``)."""
    start = time.perf_counter()
    spatial = spatial_study(QUICK_SPACINGS if quick else SPACINGS)
    h, steps = QUICK_TEMPORAL if quick else TEMPORAL
    temporal = temporal_study(h, steps)
    h2, steps2 = QUICK_TEMPORAL_2 if quick else TEMPORAL_2
    temporal_2 = temporal_study(h2, steps2, "sav2")
    results = {
        "check": "mms",
        "quick": quick,
        "order_h_L2": spatial["orders_L2"][-1],
        "order_h_H1": spatial["orders_H1"][-1],
        "order_dt": temporal["orders_L2"][-1],
        "order_dt_2": temporal_2["orders_L2"][-1],
        "expected": EXPECTED,
        "orders_from": "the two finest levels of each table",
        "setup": {
            "solution": "1/2 + A cos(kx - w t) cos(q y) exp(-t/tau), k = 2 pi/Lx, q = pi/Ly",
            "A": AMPLITUDE, "w": FREQUENCY, "tau": DECAY_TIME, "T": FINAL_TIME,
            "Lx": LX, "Ly": LY, "flow": f"linear shear u = {SHEAR_RATE:g} y/Ly",
            "model": asdict(PARAMS),
            "area_term": "included (mu = 20, R = 8), a_e exact",
            "numerics": "lumped mass, stabilisation auto, one field on the whole mesh",
            "spatial_errors": "of 2 phi(dt = h^2/16) - phi(dt = h^2/8) (O(dt) removed); raw at dt = h^2/16",
            "norms": "L2 of phi_h - phi_e and of grad phi_h - grad phi_e, degree-6 quadrature per triangle",
        },
        "spatial": spatial,
        "temporal": temporal,
        "temporal_2": temporal_2,
    }
    return save_results("mms", results, plot, start, output)


# -- shared by the other convergence checks -----------------------------------------------
def observed_orders(sizes, errors) -> list[float]:
    """log(e_i / e_{i+1}) / log(s_i / s_{i+1}) for consecutive levels."""
    sizes, errors = np.asarray(sizes, dtype=float), np.asarray(errors, dtype=float)
    return (np.log(errors[:-1] / errors[1:]) / np.log(sizes[:-1] / sizes[1:])).tolist()


def save_figure(fig, path: Path) -> None:
    """Lay out ``fig``, write it to ``path`` (120 dpi) and close it."""
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def save_results(name: str, results: dict, plot_function: Callable[[dict, Path], None], start: float,
                 output: Path | None = None) -> dict:
    """Add the run time and command, write <name>.json and <name>.png into ``output``
    (default: results/); return results."""
    directory = RESULTS if output is None else Path(output)
    results["run_time_s"] = round(time.perf_counter() - start, 1)
    results["command"] = f"python -m verification.{name}" + (" --quick" if results["quick"] else "")
    directory.mkdir(parents=True, exist_ok=True)
    write_json(directory / f"{name}.json", results)
    plot_function(results, directory / f"{name}.png")
    return results


def log_axes(ax, sizes) -> None:
    """Log–log axes whose x ticks are the sampled sizes (h or dt), plainly labelled."""
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(FixedLocator(sizes))
    ax.xaxis.set_major_formatter(FixedFormatter([f"{s:g}" for s in sizes]))
    ax.xaxis.set_minor_formatter(NullFormatter())


def output_directory(quick: bool, output: Path | None) -> Path:
    """Where a verification run writes: ``output`` if given, else a new temporary directory
    for coarse levels (``quick``: they must not replace the stored full-level results that
    verification/README.md shows), else results/."""
    if output is not None:
        return Path(output)
    return Path(tempfile.mkdtemp(prefix="verification-quick-")) if quick else RESULTS


def command_line(name: str, run_function: Callable[[bool, Path | None], dict], headline: tuple[str, ...]) -> None:
    """``python -m verification.<name> [--quick] [--output DIR]``: run and print the headline
    numbers (:func:`output_directory` says where the results go)."""
    parser = argparse.ArgumentParser(prog=f"python -m verification.{name}")
    parser.add_argument("--quick", action="store_true",
                        help="coarse levels only (seconds), into a new temporary directory unless --output names one")
    parser.add_argument("--output", type=Path, default=None,
                        help=f"directory for {name}.json/.png (default {RESULTS}: the stored results)")
    args = parser.parse_args()
    directory = output_directory(args.quick, args.output)
    results = run_function(args.quick, directory)
    expected = results.get("expected", {})
    for key in headline:
        note = f"  (expected {expected[key]:g})" if key in expected else ""
        print(f"{key} = {json.dumps(results[key])}{note}")
    print(f"wrote {directory / name}.json and .png in {results['run_time_s']} s")


if __name__ == "__main__":
    command_line("mms", run, ("order_h_L2", "order_h_H1", "order_dt", "order_dt_2"))
