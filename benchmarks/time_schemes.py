"""The time schemes on the paper's lattice over one oscillation period (issue 12).

    python benchmarks/time_schemes.py

The lattice problem of ``work_precision.py`` (N = 100, 70 × 240, h = 1, relaxed 300 and
sheared at γ̇ = 0.1487 for 3600 time units: one full period between the first two T1 peaks),
run with the default first-order scheme ``euler`` at dt = 1 and 0.25, the second-order
``sav2`` at dt = 1 and 2.5, and ``adaptive`` (outer step 10 = the frame interval) at three
tolerances. Errors, as there: ``elongation`` max_t |r̄(t) − r̄_ref(t)| / max r̄_ref, ``period``
|T − T_ref|/T_ref, against two references: ``converged`` is the one stored in
``results/work_precision.json`` (FEM h = 0.5, dt = 0.2: space and time error together), and
``time`` is sav2 at h = 1, dt = 0.25, computed in this run (the same spatial
discretisation, so only the time error remains; sav2 is second order, so its own error is
~1/16 of sav2 at dt = 1). CPU seconds of the run, and the speed-up over ``euler`` at
dt = 0.25 measured in the same run.

Writes ``results/time_schemes.json``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
from work_precision import RESULTS, Point, lattice_errors, run

POINTS = [
    ("euler", 1.0, {}), ("euler", 0.25, {}),
    ("sav2", 2.5, {"scheme": "sav2"}), ("sav2", 1.0, {"scheme": "sav2"}),
    ("adaptive 1e-2", 10.0, {"scheme": "adaptive", "tolerance_t": 1e-2}),
    ("adaptive 3e-3", 10.0, {"scheme": "adaptive", "tolerance_t": 3e-3}),
    ("adaptive 1e-3", 10.0, {"scheme": "adaptive", "tolerance_t": 1e-3}),
]


def main() -> None:
    started = time.process_time()
    converged = json.loads((RESULTS / "work_precision.json").read_text())["lattice"]["reference"]
    in_time = run(Point("lattice", "fem", 1.0, 0.25, {"scheme": "sav2"})).result
    rows = []
    for name, dt, options in POINTS:
        point = run(Point("lattice", "fem", 1.0, dt, options))
        if point.failure:
            rows.append({"scheme": name, "dt": dt, "failure": point.failure})
            continue
        rows.append({"scheme": name, "dt": dt, "options": options, "seconds": point.seconds,
                     "errors": lattice_errors(point, converged), "time_errors": lattice_errors(point, in_time),
                     "command": point.command()})
        print(rows[-1]["scheme"], dt, f"{point.seconds:.1f} s", rows[-1]["errors"], rows[-1]["time_errors"], flush=True)
    baseline = next(r for r in rows if r["scheme"] == "euler" and r["dt"] == 0.25)
    for row in rows:
        if "seconds" in row:
            row["speedup_over_euler_dt_0.25"] = baseline["seconds"] / row["seconds"]
    out = Path(RESULTS) / "time_schemes.json"
    out.write_text(json.dumps({"rows": rows, "reference": "errors: work_precision.json lattice reference (h = 0.5, dt = 0.2); "
                               "time_errors: sav2 at h = 1, dt = 0.25 (this run)",
                               "cpu_seconds": time.process_time() - started,
                               "command": "python benchmarks/time_schemes.py"}, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
