"""Milliseconds per step and per simulated time unit, measured in one run.

    python benchmarks/step_time.py [--steps N] [--full-steps M] [--shear-time T] [--random-rates R ...]

The paper's N = 100 hexagonal lattice under shear (γ̇ = 0.1487) at h = 1, first relaxed for
100 time units so the windows have their working size. In the same process:

* windows against the full mesh, both with the first-order scheme at dt = 1 (wall ms per step);
* the default scheme (numerics defaults; outer step ``FRAME`` = the lattice benchmarks'
  frame interval; calls of ``EXAMPLE_CALL`` steps, as the examples' runs take them) over
  ``--shear-time`` time units, and the first-order scheme at dt = 1
  over as long and at the paper's dt = 0.1 over a tenth of that: CPU ms per simulated
  time unit.

The paper's Fig. 1a protocol starts from random initial conditions instead: with
``--random-rates``, ``examples/random.toml`` (seed 1) is relaxed by the default scheme for
its 2000 time units (CPU timed), then sheared from that state at each rate for
``--shear-time``: CPU ms per time unit there, and the protocol's CPU minutes (relaxation +
10⁵ time units) at each rate: an extrapolation from the first ``--shear-time`` of shear,
where the windows still grow as the particles first elongate; ``protocol.py`` runs the
whole protocol end to end instead (frames, T1 looks and output included).

Their ratio is the speed-up of the default over first order at dt = 0.1. It is "at equal
period error" only if the default's period error is no larger: the errors come from
``results/work_precision_schemes.json`` (``work_precision.py --schemes``, errors in time on
the lattice over one period). If the default's is larger, the comparison is with the
first-order dt that has the default's period error (interpolated in log-log between the
measured first-order points, cost ∝ 1/dt from the dt = 0.1 measurement). The absolute
milliseconds depend on the shared machine's load; the ratios, measured in one run, less so.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import common  # pins BLAS threads before numpy loads
import numpy as np

from femphase.run.simulation import Simulation
from femphase.config import Numerics
from femphase.timestepping.stepper import Stepper
from work_precision import FRAME, is_default_scheme

RESULTS = Path(__file__).parent / "results"


def relaxed_lattice(windows: bool = True):
    """(simulation, scene, state) of the lattice relaxed by the first-order scheme."""
    scene = common.lattice_scene(windows=windows)
    simulation = Simulation(scene)
    state = scene.initial_state()
    relax = Stepper(simulation.domain, scene.model, replace(scene.numerics, scheme="euler"), 1.0, None, state.radii)
    for _ in range(20 if not windows else 100):
        relax.step(state)
    return simulation, scene, state


def shear_stepper(simulation, scene, state, dt: float, **numerics) -> Stepper:
    phase = replace(scene.phases[0], dt=dt)
    stepper = Stepper(simulation.domain, scene.model, replace(scene.numerics, **numerics), dt, scene.flow(phase),
                      state.radii)
    stepper.step(state)  # builds the factorisations: set-up cost, not per-step cost
    return stepper


def step_ms(stepper: Stepper, state, calls: int, clock=None, steps_per_call: int = 1) -> np.ndarray:
    """Each call's ms by ``clock`` (default wall ``time.perf_counter``, which
    redesign_step_time.py hooks; CPU time: ``time.process_time``), each call
    ``stepper.step(state, steps_per_call)``."""
    clock = clock or time.perf_counter
    samples = []
    for _ in range(calls):
        start = clock()
        stepper.step(state, steps_per_call)
        samples.append(clock() - start)
    return np.array(samples) * 1e3


def time_steps(windows: bool, steps: int) -> dict:
    simulation, scene, state = relaxed_lattice(windows)
    samples = step_ms(shear_stepper(simulation, scene, state, 1.0, scheme="euler"), state, steps)
    return {"mode": "windows" if windows else "full mesh", "steps": steps,
            "median_ms": float(np.median(samples)), "mean_ms": float(samples.mean()),
            "dofs_per_particle": float(np.mean([f.size for f in state.fields]))}


EXAMPLE_CALL = common.EXAMPLE_CALL


def per_time_unit(dt: float, shear_time: float, steps_per_call: int = 1, **numerics) -> float:
    """CPU ms per simulated time unit over ``shear_time`` of shear after the relaxation, in
    calls of ``steps_per_call`` steps."""
    simulation, scene, state = relaxed_lattice()
    stepper = shear_stepper(simulation, scene, state, dt, **numerics)
    calls = round(shear_time / (dt * steps_per_call))
    return float(step_ms(stepper, state, calls, time.process_time, steps_per_call).sum() / shear_time)


def random_packing(rates: list[float], shear_time: float) -> dict:
    """The default scheme on examples/random.toml: CPU seconds of its relaxation, and CPU ms
    per time unit of shear at each rate from the relaxed state."""
    import copy

    scene, simulation, relaxed, seconds = common.relaxed_random_packing()
    out = {"relax_seconds": seconds, "relax_time": scene.phases[0].duration, "ms_per_time_unit": {}}
    for rate in rates:
        state = copy.deepcopy(relaxed)
        stepper, phase = common.random_shear_stepper(scene, simulation, state, rate)
        stepper.step(state)  # set-up
        samples = step_ms(stepper, state, round(shear_time / (phase.dt * EXAMPLE_CALL)), time.process_time,
                          EXAMPLE_CALL)
        out["ms_per_time_unit"][str(rate)] = float(samples.sum() / shear_time)
    return out


def period_errors() -> tuple[dict, float] | None:
    """({first-order dt: period error}, the default's period error) from the schemes benchmark."""
    path = RESULTS / "work_precision_schemes.json"
    if not path.exists():
        return None
    euler, default = {}, None
    for row in json.loads(path.read_text())["rows"]:
        if "time_errors" not in row:
            continue
        if row["options"].get("scheme") == "euler":
            euler[row["dt"]] = row["time_errors"]["period"]
        if is_default_scheme(row):
            default = row["time_errors"]["period"]
    return (euler, default) if default is not None and 0.1 in euler else None


def equal_error_speedup(euler_ms: float, default_ms: float) -> tuple[float, str]:
    """(speed-up of the default over first order at equal period error, how it was found)."""
    errors = period_errors()
    if errors is None:
        return euler_ms / default_ms, "no period errors yet (run work_precision.py --schemes): plain ratio"
    euler, default = errors
    if default <= euler[0.1]:
        return euler_ms / default_ms, (f"the default's period error {default:.2e} is no larger than first order's "
                                       f"at dt = 0.1 ({euler[0.1]:.2e}): plain ratio")
    dts = np.array(sorted(euler))
    slope, offset = np.polyfit(np.log(dts), np.log([euler[d] for d in dts]), 1)
    dt_equal = float(np.exp((np.log(default) - offset) / slope))
    return (euler_ms * 0.1 / dt_equal / default_ms,
            f"the default's period error {default:.2e} exceeds first order's at dt = 0.1 ({euler[0.1]:.2e}); first "
            f"order reaches it at dt ≈ {dt_equal:.2g} (fit error ∝ dt^{slope:.2f}), cost scaled by 0.1/dt")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--full-steps", type=int, default=10)
    parser.add_argument("--shear-time", type=float, default=500.0)
    parser.add_argument("--random-rates", type=float, nargs="*", default=[0.0161, 0.1083, 1.0],
                        help="shear rates of the random-packing measurement (none: skip it)")
    args = parser.parse_args()
    load_start = common.load_average()
    windows = time_steps(True, args.steps)
    full = time_steps(False, args.full_steps)
    speedup = full["median_ms"] / windows["median_ms"]
    default = Numerics()
    default_ms = per_time_unit(FRAME, args.shear_time, EXAMPLE_CALL)
    euler_ms = per_time_unit(0.1, args.shear_time / 10, scheme="euler")
    euler_dt1_ms = per_time_unit(1.0, args.shear_time, scheme="euler")
    equal, how = equal_error_speedup(euler_ms, default_ms)
    protocol_minutes = default_ms * 1.02e5 / 1e3 / 60
    random = random_packing(args.random_rates, args.shear_time) if args.random_rates else None
    print(f"{'mode':<10} {'steps':>6} {'median ms/step':>15} {'mean ms/step':>13} {'dofs/particle':>14}")
    for row in (windows, full):
        print(f"{row['mode']:<10} {row['steps']:>6} {row['median_ms']:>15.2f} {row['mean_ms']:>13.2f} {row['dofs_per_particle']:>14.0f}")
    print(f"windows speedup over full mesh (first order, dt = 1): {speedup:.1f}")
    print(f"first order: {euler_dt1_ms:.2f} ms per time unit at dt = 1, {euler_ms:.2f} at dt = 0.1")
    print(f"paper protocol (1.02e5 time units) at the default scheme: {protocol_minutes:.1f} CPU-min")
    print(f"speedup of the default over first order at dt = 1 (the former default): {euler_dt1_ms / default_ms:.2f}")
    print(f"ms per time unit at the default scheme: {default_ms:.2f}  "
          f"({default.scheme}, tolerance_t {default.tolerance_t:g}, outer dt {FRAME:g})")
    print(f"speedup of the default over first-order dt = 0.1 at equal period error: {equal:.1f}  ({how})")
    if random:
        random["protocol_minutes"] = {rate: (random["relax_seconds"] + ms * 1e2) / 60
                                      for rate, ms in random["ms_per_time_unit"].items()}
        print(f"random packing (examples/random.toml, seed 1): relaxation {random['relax_seconds']:.1f} CPU s; "
              + "; ".join(f"γ̇ = {rate}: {ms:.2f} ms per time unit, protocol {random['protocol_minutes'][rate]:.1f} CPU-min"
                          for rate, ms in random["ms_per_time_unit"].items()))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "step_time.json").write_text(json.dumps({
        "windows": windows, "full_mesh": full, "speedup": speedup,
        "default_scheme": {"scheme": default.scheme, "tolerance_t": default.tolerance_t, "outer_dt": FRAME},
        "default_ms_per_time_unit": default_ms, "euler_dt_0.1_ms_per_time_unit": euler_ms,
        "euler_dt_1_ms_per_time_unit": euler_dt1_ms, "speedup_over_euler_dt_1": euler_dt1_ms / default_ms,
        "speedup_over_euler_dt_0.1_at_equal_period_error": equal, "equal_error_basis": how,
        "protocol_minutes": protocol_minutes, "random_packing": random,
        "load_average": {"start": load_start, "end": common.load_average()},
        "command": "python benchmarks/step_time.py"}, indent=2) + "\n")


if __name__ == "__main__":
    main()
