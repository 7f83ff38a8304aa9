"""Semi-Lagrangian advection on meshes against the explicit Galerkin step: cost and accuracy.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 \\
        python benchmarks/mesh_semi_lagrangian.py        # ~11 min, mostly building matrices

The semi-Lagrangian step tried here (not part of femphase; docs/decisions/0042): every dof's
departure point x over the step (classical RK4 on the flow, steps of at most a fifth of the
median edge), and the field's value there from the P1 interpolant plus a curvature
correction on the triangle (corners a, b, c; barycentric λ) that holds x,

    φ(x) ≈ Σ_a λ_a φ_a − ½ Σ_{a<b} λ_a λ_b e_abᵀ H(z_ab) e_ab,
    e_ab = x_a − x_b,  z_ab = (x + x_a + x_b)/3,

which is exact for every polynomial of degree p when H is a polynomial's Hessian of degree
p − 2. H comes from a least-squares fit over a patch of the triangle: p = 2, a quadratic
over the first ring of its corners (H constant, about 12 entries per row); p = 3, a cubic
over the second ring (H linear, about 27 entries per row); "weighted", with Gaussian
weights on the patch's distance from the triangle. p = 1 is P1 interpolation alone. The
correction vanishes at the nodes, so a fluid at rest moves nothing. A steady flow's step
is one sparse matrix per dt, applied to all windows at once as one block-diagonal product
(:class:`~femphase.fem.blocks.BlockPattern`, as the Galerkin step's matrices).

Measured:

* **accuracy**: the translating disc of verification/mesh_advection.py (R = 8 on a 40 × 30
  Delaunay channel at h = 1, carried 32 units by u = 1 under the default adaptive scheme at
  phase dt 0.25, 1, 2, 4): displacement error, elongation change, and the Courant numbers
  u dt_a/h of the advections dt_a the scheme built (h the median edge; a built one may go
  unused);
* **whole runs**: examples/random.toml in Poiseuille flow against examples/straight_mesh.toml
  in its Stokes flow (``benchmarks/mesh_parity.py``'s kinds, centre-line velocity 0.1,
  400 time units of relaxation and 800 of flow at dt = 10), the mesh with its default
  advection and with the quadratic semi-Lagrangian step, each run its own process, the
  three alternated ``--repeats`` times: CPU per time unit under flow against the grid's,
  the semi-Lagrangian matrices' construction taken out (it is uncompiled here, and done
  once per flow and dt);
* **cost of one advection** on a relaxed state of examples/straight_mesh.toml (400 time
  units at dt = 10, 100 772 window positions) in Poiseuille flow of centre-line velocity
  0.1, over the default substep dt/3 = 3.33: the Galerkin steps (Taylor–Galerkin, the
  default, and Runge–Kutta) against each semi-Lagrangian matrix, best of 5 × 20 advections,
  with each one's first (layout) call.

Writes benchmarks/results/mesh_semi_lagrangian.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import common  # pins BLAS threads
import mesh_parity
import numpy as np
import scipy.sparse as sp

from femphase.domains.mesh.advection import GalerkinAdvection, GalerkinRungeKutta, TaylorGalerkin
from femphase.domains.mesh.domain import MeshDomain
from femphase.domains.mesh.location import locate
from femphase.fem.blocks import BlockPattern
from femphase.flows import python_flow

ROOT = Path(__file__).resolve().parents[1]
RESULT = Path(__file__).parent / "results" / "mesh_semi_lagrangian.json"
#: name → (degree p, weighted patch)
VARIANTS = {"P1 interpolation": (1, False), "quadratic (p = 2)": (2, False), "cubic (p = 3)": (3, False),
            "cubic, weighted": (3, True)}
#: Largest RK4 step of the departure points, in median edges.
DEPARTURE_STEP = 0.2


def velocity_at(flow, x: np.ndarray, y: np.ndarray, time: float) -> tuple[np.ndarray, np.ndarray]:
    if flow.stokes is not None:
        # in parts: skfem's point location takes memory in points × elements
        parts = [flow.stokes(x[i:i + 1000], y[i:i + 1000]) for i in range(0, x.size, 1000)]
        return np.concatenate([u for u, _ in parts]), np.concatenate([v for _, v in parts])
    u, v = flow.velocity(x, y, time)
    return np.broadcast_to(u, x.shape).astype(float), np.broadcast_to(v, x.shape).astype(float)


def departure_points(domain: MeshDomain, flow, dt: float, time: float = 0.0) -> np.ndarray:
    """(2, n_dofs): where each dof's fluid was dt earlier, x wrapped into the period."""
    x, y = (c.copy() for c in domain.coordinates)
    speed = float(np.max(np.hypot(*velocity_at(flow, x, y, time))))
    steps = max(1, int(np.ceil(speed * dt / (DEPARTURE_STEP * domain.median_edge))))
    h = -dt / steps
    low, high = domain.y_range

    def rate(dx, dy, k):
        return velocity_at(flow, x + k * dx, np.clip(y + k * dy, low, high), time)

    for _ in range(steps):
        k1 = rate(0, 0, 0.0)
        k2 = rate(*k1, 0.5 * h)
        k3 = rate(*k2, 0.5 * h)
        k4 = rate(*k3, h)
        x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        y = np.clip(y + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]), low, high)
    return np.stack([domain.x0 + np.mod(x - domain.x0, domain.period), y])


def _containing(domain: MeshDomain, points: np.ndarray) -> np.ndarray:
    elements = locate(domain.mesh, points)
    lost = elements < 0  # on the seam: try the periodic image
    if lost.any():
        image = points[:, lost].copy()
        image[0] += np.where(image[0] < domain.x0 + domain.period / 2, domain.period, -domain.period)
        elements[lost] = locate(domain.mesh, image)
    if np.any(elements < 0):
        raise RuntimeError(f"{int(np.sum(elements < 0))} departure points outside the mesh")
    return elements


def interpolation_matrix(domain: MeshDomain, points: np.ndarray, degree: int, weighted: bool) -> sp.csr_matrix:
    """(n_points, n_dofs): the interpolant of degree ``degree`` (module docstring) at ``points``."""
    mesh, period, edge = domain.mesh, domain.period, domain.median_edge
    elements = _containing(domain, points)
    corners = mesh.p[:, mesh.t[:, elements]]  # (2, 3, n)
    centre = corners.mean(axis=1)
    p = points.copy()
    p[0] = centre[0] + np.mod(p[0] - centre[0] + period / 2, period) - period / 2
    e1, e2, d = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], p - corners[:, 0]
    det = e1[0] * e2[1] - e1[1] * e2[0]
    s, t = (d[0] * e2[1] - d[1] * e2[0]) / det, (e1[0] * d[1] - e1[1] * d[0]) / det
    lam = np.stack([1 - s - t, s, t])
    n = points.shape[1]
    rows, cols, vals = [np.repeat(np.arange(n), 3)], [domain.dof_map[mesh.t[:, elements]].T.ravel()], [lam.T.ravel()]
    if degree >= 2:
        pattern = domain.operators.mass.tocsr()
        xd, yd = domain.coordinates

        def ring(dofs):
            return np.unique(np.concatenate([pattern.indices[pattern.indptr[v]:pattern.indptr[v + 1]] for v in dofs]))

        fits = {}
        for k in np.unique(elements):
            patch = ring(domain.dof_map[mesh.t[:, k]])
            if degree == 3:
                patch = ring(patch)
            cx, cy = mesh.p[:, mesh.t[:, k]].mean(axis=1)
            dx = (np.mod(xd[patch] - cx + period / 2, period) - period / 2) / edge
            dy = (yd[patch] - cy) / edge
            powers = [np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy]
            if degree == 3:
                powers += [dx**3, dx * dx * dy, dx * dy * dy, dy**3]
            basis = np.stack(powers, axis=1)
            weight = np.exp(-(dx * dx + dy * dy) / degree) if weighted else np.ones_like(dx)
            # rows of the fit's coefficients of x², xy, y² (and the cubic ones), per patch value
            fits[k] = patch, (np.linalg.pinv(basis * weight[:, None]) * weight)[3:], (cx, cy)
        for j, k in enumerate(elements):
            patch, c, (cx, cy) = fits[k]
            corner = mesh.p[:, mesh.t[:, k]]
            correction = np.zeros(patch.size)
            for a, b in ((0, 1), (0, 2), (1, 2)):
                if lam[a, j] * lam[b, j] == 0.0:
                    continue
                ex, ey = (corner[:, a] - corner[:, b]) / edge
                hxx, hxy, hyy = 2 * c[0], c[1], 2 * c[2]
                if degree == 3:
                    zx = ((p[0, j] + corner[0, a] + corner[0, b]) / 3 - cx) / edge
                    zy = ((p[1, j] + corner[1, a] + corner[1, b]) / 3 - cy) / edge
                    hxx = hxx + 6 * c[3] * zx + 2 * c[4] * zy
                    hxy = hxy + 2 * c[4] * zx + 2 * c[5] * zy
                    hyy = hyy + 2 * c[5] * zx + 6 * c[6] * zy
                correction += lam[a, j] * lam[b, j] * (ex * ex * hxx + 2 * ex * ey * hxy + ey * ey * hyy)
            rows.append(np.full(patch.size, j))
            cols.append(patch)
            vals.append(-0.5 * correction)
    matrix = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                           shape=(n, domain.n_dofs))
    matrix.sum_duplicates()
    matrix.eliminate_zeros()
    return matrix


class SemiLagrangian(GalerkinAdvection):
    """The semi-Lagrangian step over dt (module docstring), one matrix per flow and dt in the
    domain's budget, applied to the windows as one block-diagonal product per layout."""

    degree, weighted = 2, False
    #: CPU seconds spent building matrices, and how many were built (whole runs report the
    #: flow's CPU without them: a compiled build would cost a fraction, and they are per dt)
    build_cpu, built = 0.0, 0

    @property
    def matrix(self) -> sp.csr_matrix:
        return self._per_flow(f"semi-Lagrangian {self.dt!r} {self.degree} {self.weighted}", self._build)

    def _build(self) -> sp.csr_matrix:
        clock = time.process_time()
        # steady flows only, as the design measured here (record 0042): C's time does not enter
        points = departure_points(self.domain, self.flow, self.dt)
        matrix = interpolation_matrix(self.domain, points, self.degree, self.weighted)
        SemiLagrangian.build_cpu += time.process_time() - clock
        SemiLagrangian.built += 1
        return matrix

    def advect(self, phi, layout, time):
        self._step_from(time)
        matrix = self.matrix
        dtype = np.dtype(phi.dtype).type
        block = self.domain.per_layout(layout, ("semi-Lagrangian", self.dt, dtype), lambda: BlockPattern(
            matrix, layout.node_index, layout.offsets).block(matrix.data.astype(dtype)), tag=matrix)
        return block @ phi, layout


_default_advection = MeshDomain.advection
#: the dt of every advection made since :func:`use`, for the Courant numbers
made: list[float] = []


def use(variant: str | None) -> None:
    """Make meshes advect by ``variant`` (a key of VARIANTS), or by their default if None."""
    if variant is not None:
        SemiLagrangian.degree, SemiLagrangian.weighted = VARIANTS[variant]

    def advection(self, flow, dt, numerics):
        made.append(dt)
        if variant is None:
            return _default_advection(self, flow, dt, numerics)
        return SemiLagrangian(self, flow, dt)

    MeshDomain.advection = advection


#: The meshes' default Galerkin step below the semi-Lagrangian threshold, as the results name it
#: (results/mesh_semi_lagrangian.json, measured when it was the three-stage Runge–Kutta step,
#: names it "Galerkin, 3 stages, K = 2 (default)")
DEFAULT_GALERKIN = "Galerkin, Taylor–Galerkin, K = 2 (default)"


def disc_accuracy() -> dict:
    """The translating disc (module docstring) for the default Galerkin step and every variant."""
    sys.path.insert(0, str(ROOT))
    from verification import mesh_advection as disc
    from femphase.config import Numerics
    from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing

    domain = MeshDomain.from_mesh(*delaunay_channel(disc.LENGTH, edge_for_spacing(1.0), lambda x: 0 * x,
                                                    lambda x: 0 * x + disc.HEIGHT, seed=1))
    results = {}
    for variant in [None, *VARIANTS]:
        use(variant)
        rows = []
        for dt in disc.STEPS:
            made.clear()
            row = disc.carried(domain, None, Numerics(), dt)
            courant = sorted({round(a / domain.median_edge, 4) for a in made})
            rows.append({**row, "courant": courant})
        results[variant or DEFAULT_GALERKIN] = rows
        print(variant, json.dumps(rows), flush=True)
    MeshDomain.advection = _default_advection
    return results


def advection_cost() -> dict:
    """CPU of one advection over dt/3 on a relaxed straight-mesh state (module docstring)."""
    from femphase.run.simulation import Simulation
    from femphase.scene import load_scene

    scene = load_scene(common.STRAIGHT_MESH_SCENE, ["phases.0.dt=10.0", "phases.0.duration=400",
                                                    "output.fields=false"])
    state = scene.initial_state()
    stepper = Simulation(scene).stepper(scene.phases[0], state.radii)
    stepper.scheme.start_phase(state)
    stepper.step(state, scene.phases[0].n_steps)
    domain, (layout, phi) = stepper.domain, state.flat()
    low, high = domain.y_range
    width = high - low
    flow = python_flow(lambda x, y: (0.4 * (y - low) * (high - y) / width**2 + 0 * x, 0 * y))
    dt = 10.0 / 3
    advections = {DEFAULT_GALERKIN: TaylorGalerkin(domain, flow, dt, scene.numerics),
                  "Galerkin, Runge–Kutta, 3 stages, K = 2": GalerkinRungeKutta(domain, flow, dt, scene.numerics)}
    entries = {}
    for variant in VARIANTS:
        if variant == "P1 interpolation":
            continue
        advection = SemiLagrangian(domain, flow, dt)
        advection.degree, advection.weighted = VARIANTS[variant]
        clock = time.process_time()
        entries[variant] = {"entries_per_row": advection.matrix.nnz / advection.matrix.shape[0],
                            "matrix_build_cpu_s": time.process_time() - clock}
        advections[variant] = advection
    out = {}
    for name, advection in advections.items():
        clock = time.process_time()
        advection.advect(phi, layout, 0.0)
        first = time.process_time() - clock
        best = []
        for _ in range(5):
            clock = time.process_time()
            for _ in range(20):
                advection.advect(phi, layout, 0.0)
            best.append((time.process_time() - clock) / 20)
        out[name] = {"ms_per_advection": 1e3 * min(best), "first_call_ms": 1e3 * first, **entries.get(name, {})}
        print(name, json.dumps(out[name]), flush=True)
    return {"positions": int(layout.node_index.size), "dofs": domain.n_dofs, "substep": dt, "advections": out}


#: whole-run kind → (mesh_parity kind, advection variant or None for the default)
RUN_KINDS = {"grid": ("grid", None), "mesh": ("mesh", None),
             "mesh, quadratic semi-Lagrangian": ("mesh", "quadratic (p = 2)")}


def whole_runs(repeats: int) -> dict:
    """Flow-phase CPU per time unit of RUN_KINDS, each in its own process (module docstring)."""
    runs = []
    for repeat in range(repeats):
        for kind in RUN_KINDS:
            out = subprocess.run([sys.executable, __file__, "--child", kind], capture_output=True, text=True,
                                 env={**os.environ, **mesh_parity.THREADS})
            if out.returncode != 0:
                raise SystemExit(f"{kind} failed:\n{out.stderr[-3000:]}")
            runs.append({**json.loads(out.stdout.strip().splitlines()[-1]), "kind": kind, "repeat": repeat})
            print(json.dumps(runs[-1]), flush=True)
    ratios = {kind: [m["flow_ms_per_time_unit"] / g["flow_ms_per_time_unit"] for g in runs if g["kind"] == "grid"
                     for m in runs if m["kind"] == kind and m["repeat"] == g["repeat"]] for kind in list(RUN_KINDS)[1:]}
    return {"relax": 400.0, "flow": 800.0, "velocity": 0.1, "runs": runs, "flow_cpu_ratio_to_grid": ratios}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=2, help="alternations of the whole runs (default 2)")
    parser.add_argument("--child", choices=sorted(RUN_KINDS), help=argparse.SUPPRESS)
    parser.add_argument("--output", type=Path, default=RESULT)
    args = parser.parse_args()
    if args.child:
        kind, variant = RUN_KINDS[args.child]
        if variant is not None:
            use(variant)
        record = mesh_parity.child(kind, 400.0, 800.0, 0.1)
        record.update(matrices_built=SemiLagrangian.built, matrix_build_cpu_s=SemiLagrangian.build_cpu,
                      flow_ms_per_time_unit=1e3 * (record["flow_cpu_s"] - SemiLagrangian.build_cpu) / 800.0)
        print(json.dumps(record))
        return
    # the whole runs first: a child's peak resident memory counts its parent's at its start
    runs = whole_runs(args.repeats)
    result = {"disc": disc_accuracy(), "cost": advection_cost(), "whole_runs": runs}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
