"""Verify the periodic Stokes solver against plane Poiseuille flow.

On the channel [0, Lx] × [0, Ly], periodic in x with no-slip walls, a
pressure drop Δp over one period gives u = G/(2η) y (Ly − y), v = 0 with
G = Δp/Lx, and a periodic pressure part that is constant (zero here, by the
zero-mean convention).  A prescribed flux Q gives the same profile with
G = 12 η Q / Ly³.  P2 velocities contain this quadratic exactly, so every
error below should be round-off, on every mesh: structured, and irregular
(nodes randomly moved, x sides kept matching).

Writes verification/results/stokes.json (``max_rel_error``: the largest
nodal error of (u, v) relative to the centreline velocity, over all cases)
and verification/results/stokes.png.

Run from the repository root: ``python verification/stokes.py [--output DIR]``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import NullFormatter  # noqa: E402
import numpy as np  # noqa: E402

# the script lives outside the package; make `femphase` importable from a checkout
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from femphase.domains.mesh.stokes import StokesFlow, channel_mesh, poiseuille_profile, solve_stokes

LX, LY = 70.0, 240.0
VISCOSITY = 1.0
PRESSURE_DROP = 1.0
FLUX = 1.0
ROWS = (8, 16, 32, 64)
MESHES = {"structured": 0.0, "unstructured": 0.2}
RESULTS = Path(__file__).resolve().parent / "results"


def centreline_velocity(flow: StokesFlow) -> float:
    """U of the exact Poiseuille flow with the solution's driving."""
    gradient = flow.pressure_drop / LX
    return gradient * LY**2 / (8 * flow.viscosity)


def nodal_errors(flow: StokesFlow) -> dict[str, float]:
    """Errors against Poiseuille, relative to the centreline velocity U
    (velocity) and to the pressure drop (periodic pressure part)."""
    U = centreline_velocity(flow)
    u, v = flow.velocity_at_nodes()
    exact = poiseuille_profile(flow.mesh.p[1], LY, U)
    return {
        "max_rel_error": float(max(np.abs(u - exact).max(), np.abs(v).max()) / U),
        "max_rel_error_u": float(np.abs(u - exact).max() / U),
        "max_rel_v": float(np.abs(v).max() / U),
        "max_rel_pressure": float(np.abs(flow.pressure).max() / flow.pressure_drop),
    }


def run_case(ny: int, jitter: float, driving: str) -> tuple[dict, StokesFlow]:
    nx = max(2, round(ny * LX / LY))
    mesh = channel_mesh(LX, LY, nx, ny, jitter=jitter, seed=ny)
    drive = {"pressure_drop": PRESSURE_DROP} if driving == "pressure_drop" else {"flux": FLUX}
    flow = solve_stokes(mesh, LX, viscosity=VISCOSITY, **drive)
    U = centreline_velocity(flow)
    case = {
        "nx": nx,
        "ny": ny,
        "h": float(mesh.param()),
        "n_velocity_dofs": int(flow.velocity_basis.N),
        "pressure_drop": float(flow.pressure_drop),
        "flux": float(flow.flux),
        # Poiseuille: Q = 2 U Ly / 3
        "rel_flux_error": float(abs(flow.flux - 2 * U * LY / 3) / (2 * U * LY / 3)),
        **nodal_errors(flow),
    }
    return case, flow


def plot(cases: dict[str, dict], profile_flow: StokesFlow, path: Path) -> None:
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))

    y = np.linspace(0, LY, 200)
    U = centreline_velocity(profile_flow)
    left.plot(poiseuille_profile(y, LY, U), y, "k-", label="analytic")
    u, _ = profile_flow.velocity_at_nodes()
    left.plot(u, profile_flow.mesh.p[1], ".", ms=3, label="P2 at nodes (unstructured)")
    left.set(xlabel="u", ylabel="y", title="Poiseuille profile, Δp-driven")
    left.legend(loc="center left")

    for mesh_name in MESHES:
        # flux-driven runs are scaled Δp-driven ones: open markers keep both visible
        for driving, marker, face in (("pressure_drop", "o-", None), ("flux", "s--", "none")):
            series = [c for c in cases.values()
                      if c["mesh"] == mesh_name and c["driving"] == driving]
            # exact zeros would vanish from a log axis
            errors = [max(c["max_rel_error"], 1e-17) for c in series]
            right.loglog([c["h"] for c in series], errors, marker, mfc=face, ms=8,
                         label=f"{mesh_name}, {driving}")
    right.axhline(np.finfo(float).eps, color="grey", lw=0.8, label="machine ε")
    right.set(xlabel="h (longest edge)", ylabel="max rel. nodal error",
              title="Error vs mesh size", ylim=(1e-17, 1e-8))
    right.xaxis.set_minor_formatter(NullFormatter())
    right.legend(fontsize=8)

    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(output: Path | None = None) -> dict:
    """Every case; writes stokes.json and stokes.png into ``output`` (default: results/)."""
    cases = {}
    for mesh_name, jitter in MESHES.items():
        for driving in ("pressure_drop", "flux"):
            for ny in ROWS:
                case, flow = run_case(ny, jitter, driving)
                name = f"{mesh_name}/{driving}/ny={ny}"
                cases[name] = {"mesh": mesh_name, "driving": driving, **case}
                print(f"{name:34s} h={case['h']:8.3f}  "
                      f"max_rel_error={case['max_rel_error']:.2e}")
                if (mesh_name, driving, ny) == ("unstructured", "pressure_drop", ROWS[1]):
                    profile_flow = flow

    summary = {
        "max_rel_error": max(c["max_rel_error"] for c in cases.values()),
        "max_rel_flux_error": max(c["rel_flux_error"] for c in cases.values()),
        "max_rel_pressure": max(c["max_rel_pressure"] for c in cases.values()),
        "setup": {
            "Lx": LX, "Ly": LY, "viscosity": VISCOSITY,
            "pressure_drop": PRESSURE_DROP, "flux": FLUX,
            "elements": "Taylor-Hood P2/P1",
            "unstructured": f"structured mesh, nodes moved by up to "
                            f"{MESHES['unstructured']} x spacing",
            "error": "max over vertices of |(u, v) - (u_exact, 0)|_inf / U_centreline",
        },
        "cases": cases,
    }
    directory = RESULTS if output is None else Path(output)
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "stokes.json").write_text(json.dumps(summary, indent=2) + "\n")
    plot(cases, profile_flow, directory / "stokes.png")
    print(f"max_rel_error = {summary['max_rel_error']:.3e}")
    return summary


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output", type=Path, default=None,
                        help=f"directory for stokes.json/.png (default {RESULTS})")
    main(parser.parse_args().output)
