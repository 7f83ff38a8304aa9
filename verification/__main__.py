"""Run every verification check and regenerate the tables of verification/README.md.

    python -m verification [--quick] [--only NAME ...] [--output DIR] [--readme-only]

Checks, in order: ``mms``, ``flat_interface``, ``equilibrium`` (each ``run(quick)``),
``fem_vs_fd`` (``run(quick)``, skipped when it cannot be imported) and ``stokes`` (its script's
``main()``; it has no quick mode and takes seconds). Each writes ``<name>.json`` and
``<name>.png`` into ``verification/results/``, the stored results, and then every table of
the README is rewritten from those JSON files: the text between
``<!-- BEGIN generated: NAME -->`` and ``<!-- END generated: NAME -->`` (a check without
markers gets a new section at the end); everything else in the README is left alone.
``--readme-only`` rewrites the tables from the stored JSON files without running anything.

With ``--output DIR``, and with ``--quick`` (into a new temporary directory unless
``--output`` names one), the results go there and the README is left alone: its tables
show the stored full-level results, which coarse levels must not replace.

Exit status 1 when a check raised (the others still run, and the README is still rewritten
when the results are the stored ones).
"""

from __future__ import annotations

import os

# one BLAS thread: the machine's two cores are shared with other long runs
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

from verification.mms import output_directory  # noqa: E402
from verification.readme import with_block  # noqa: E402

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
README = HERE / "README.md"
CHECKS = ("mms", "flat_interface", "equilibrium", "fem_vs_fd", "stokes")
#: an observed order counts as agreeing with the expected one within this
ORDER_TOLERANCE = 0.2


# -- running ------------------------------------------------------------------------------
def run_check(name: str, quick: bool, output: Path = RESULTS) -> str:
    """Run one check, its results into ``output``; returns a status line."""
    start = time.perf_counter()
    try:
        module = importlib.import_module(f"verification.{name}")
    except ImportError as exc:
        return f"skipped ({exc})"
    if name == "stokes":
        module.main(output)  # a script: no run(), no quick mode
    elif name == "fem_vs_fd":  # its run() returns the results; save() writes them as its command line does
        module.save(module.run(quick), output)
    else:
        module.run(quick, output=output)
    return f"done in {time.perf_counter() - start:.0f} s"


# -- markdown -----------------------------------------------------------------------------
def table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def number(value, digits: int = 4) -> str:
    if value is None:
        return "–"
    if isinstance(value, str):
        return value
    return f"{value:.{digits}g}"


def orders(values: list[float]) -> list[str]:
    """Orders between consecutive levels, aligned with the levels (first row blank)."""
    return ["–"] + [f"{v:.2f}" for v in values]


def verdict(observed: float, expected: float) -> str:
    return "agrees" if abs(observed - expected) <= ORDER_TOLERANCE else "**differs**"


def summary(results: dict, keys: list[str]) -> str:
    expected = results["expected"]
    rows = [[f"`{key}`", f"{results[key]:.3f}", f"{expected[key]:g}", verdict(results[key], expected[key])]
            for key in keys]
    return table(["quantity", "observed", "expected", "within ±0.2"], rows)


def provenance(results: dict) -> str:
    mode = " (quick mode: coarse levels only)" if results.get("quick") else ""
    seconds = f"; {results['run_time_s']} s wall time" if "run_time_s" in results else ""
    return f"_Produced by `{results['command']}`{mode}, also run by `python -m verification`{seconds}._"


def mms_section(r: dict) -> str:
    s, t = r["spatial"], r["temporal"]
    spatial = table(
        ["h", "dt (finer run)", "L2 error", "order", "H1 error", "order", "L2 raw", "order"],
        [[number(h), number(dt), number(l2), o1, number(h1), o2, number(raw), o3]
         for h, dt, l2, o1, h1, o2, raw, o3 in zip(
             s["h"], s["dt"], s["L2"], orders(s["orders_L2"]), s["H1"], orders(s["orders_H1"]),
             s["L2_raw"], orders(s["orders_L2_raw"]))],
    )
    temporal = table(
        ["dt", "L2 error", "order", "H1 error", "order", "stabilisation S"],
        [[number(dt), number(l2), o1, number(h1), o2, number(stab)]
         for dt, l2, o1, h1, o2, stab in zip(
             t["dt"], t["L2"], orders(t["orders_L2"]), t["H1"], orders(t["orders_H1"]), t["stabilisation"])],
    )
    second = r["temporal_2"]
    temporal_2 = table(
        ["dt", "L2 error", "order", "H1 error", "order"],
        [[number(dt), number(l2), o1, number(h1), o2]
         for dt, l2, o1, h1, o2 in zip(second["dt"], second["L2"], orders(second["orders_L2"]), second["H1"],
                                      orders(second["orders_H1"]))],
    )
    return "\n\n".join([
        provenance(r),
        summary(r, ["order_h_L2", "order_h_H1", "order_dt", "order_dt_2"]),
        "Errors against h (time-extrapolated field 2φ(h²/16) − φ(h²/8); raw: φ(h²/16)):",
        spatial,
        f"Errors against dt at h = {t['h']:g} (the default scheme, euler):",
        temporal,
        f"Errors against dt at h = {second['h']:g} (the second-order scheme, {second['scheme']}):",
        temporal_2,
    ])


def flat_interface_section(r: dict) -> str:
    t = r["table"]
    rows = [[number(h), number(l2), o1, number(mx), o2, number(en), o3, number(shift, 2), steps]
            for h, l2, o1, mx, o2, en, o3, shift, steps in zip(
                t["h"], t["L2_error"], orders(t["orders_L2"]), t["max_error"], orders(t["orders_max"]),
                t["energy_error"], orders(t["orders_energy"]), t["centre_shift"], t["steps"])]
    return "\n\n".join([
        provenance(r),
        summary(r, ["order", "order_max", "order_energy"]),
        table(["h", "L2 error", "order", "max error", "order", "F_h/Lx − 2γ/3", "order",
               "y_c − Ly/2", "steps"], rows),
        f"Largest variation of φ along x: {max(t['x_variation']):.1e} (the field stays one-dimensional).",
    ])


def equilibrium_section(r: dict) -> str:
    data, names = r["study"], ("area", "mass", "radius", "radius_from_mass", "interior")
    quantities = data["quantities"]
    column = data["extrapolation_dt"]
    by_h = {run["h"]: run for run in data["runs"] if run["dt"] == column}
    per_h = table(
        ["h", "∫φ²", "∫φ", "r_½ (contour)", "r from ∫φ", "φ(centre)", "bulk 1 + δ", "steps", "drift"],
        [[number(h), *(number(by_h[h][n], 10) for n in names), number(by_h[h]["interior_bulk"], 6),
          by_h[h]["steps"], number(by_h[h]["drift"], 2)] for h in data["h"] if h in by_h],
    )
    limits = table(
        ["quantity", "Richardson limit", "observed order", "expected", "", "spread over dt"],
        [[n, number(quantities[n]["limit"], 10), f"{quantities[n]['order']:.2f}", f"{r['expected'][n + '_order']:g}",
          verdict(quantities[n]["order"], r["expected"][n + "_order"]), number(quantities[n]["dt_spread"], 2)]
         for n in names],
    )
    window = r["window_truncation"]
    truncation = table(
        ["h", *names, "drift on the full mesh"],
        [[number(h), *(number(window[n][i], 2) for n in names), number(window["full_mesh_drift"][i], 2)]
         for i, h in enumerate(window["h"])],
    )
    area = table(
        ["h \\ dt", *(f"{dt:g}" for dt in data["dt"])],
        [[number(h), *(number(v, 12) for v in row)] for h, row in zip(data["h"], quantities["area"]["table"])],
    )
    return "\n\n".join([
        provenance(r),
        f"Values at dt = {column:g} (πR² = {r['target_area']:.6g}):",
        per_h,
        f"Extrapolated from h = {', '.join(f'{h:g}' for h in data['extrapolation_h'][-3:])} at dt = {column:g}; "
        "spread over dt = largest difference between the runs of one h with different dt:",
        limits,
        "Window truncation, windowed − full-mesh values at dt = 1:",
        truncation,
        "∫φ² for every (h, dt):",
        area,
    ])


def fem_vs_fd_section(r: dict) -> str:
    """Per scene: the FEM–FD field differences against h and their order. Expected 2 unless the
    results say otherwise: both schemes are second order in h, and dt ∝ h² makes their first
    order in dt O(h²) as well."""
    expected = r.get("expected_order", 2.0)
    rows = [[name, ", ".join(f"{h:g}" for h in scene["h"]),
             ", ".join(number(v, 3) for v in scene["fem_vs_fd"]["field"]),
             f"{scene['order']:.2f}", number(scene.get("order_fit"), 3), f"{expected:g}",
             verdict(scene["order"], expected)]
            for name, scene in r["scenes"].items()]
    lines = [provenance(r) if "command" in r else
             "_Produced by `python verification/fem_vs_fd.py`, also run by `python -m verification`._"]
    return "\n\n".join(lines + [table(["scene", "h", "field difference FEM − FD", "observed order (two finest h)",
                                       "least-squares order (all h)", "expected", ""], rows)])


def stokes_section(r: dict) -> str:
    rows = [[name, number(case["h"], 3), number(case["max_rel_error"], 2), number(case["rel_flux_error"], 2)]
            for name, case in r["cases"].items()]
    return "\n\n".join([
        "_Produced by `python verification/stokes.py`, also run by `python -m verification`._",
        f"Largest relative nodal velocity error over all cases: {r['max_rel_error']:.2e} "
        "(expected: round-off, P2 velocities contain the quadratic profile exactly).",
        table(["case", "h", "max rel. error", "rel. flux error"], rows),
    ])


def generic_section(r: dict) -> str:
    """Any other check: its top-level numbers and strings, with expected values if given."""
    expected = r.get("expected", {}) if isinstance(r.get("expected"), dict) else {}
    rows = []
    for key, value in r.items():
        if isinstance(value, (int, float, str)) and not isinstance(value, bool) and key != "command":
            rows.append([f"`{key}`", number(value), number(expected.get(key, "–"))])
    lines = [provenance(r)] if "command" in r else []
    return "\n\n".join(lines + [table(["quantity", "value", "expected"], rows)])


SECTIONS = {
    "mms": mms_section,
    "flat_interface": flat_interface_section,
    "equilibrium": equilibrium_section,
    "fem_vs_fd": fem_vs_fd_section,
    "stokes": stokes_section,
}


def section(name: str) -> str:
    path = RESULTS / f"{name}.json"
    if not path.is_file():
        return f"_Not run yet: `{path.relative_to(HERE.parent)}` does not exist._"
    results = json.loads(path.read_text())
    try:
        body = SECTIONS.get(name, generic_section)(results)
    except (KeyError, TypeError, ValueError) as exc:  # results in a layout this file does not know
        body = f"_Detailed tables unavailable ({exc!r}); the top-level results:_\n\n" + generic_section(results)
    figure = RESULTS / f"{name}.png"
    return body + (f"\n\n![{name}](results/{name}.png)" if figure.is_file() else "")


def update_readme(names: tuple[str, ...] = CHECKS) -> None:
    """Rewrite every generated block of the README from the JSON results."""
    text = README.read_text() if README.is_file() else "# Verification\n"
    for name in names:
        text = with_block(text, name, section(name), name)
    README.write_text(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m verification", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="coarse levels only, into a new temporary directory unless --output names one")
    parser.add_argument("--only", nargs="+", choices=CHECKS, help="run these checks only")
    parser.add_argument("--output", type=Path, default=None,
                        help=f"directory for the results, leaving {RESULTS} and the README alone")
    parser.add_argument("--readme-only", action="store_true", help="rewrite the README tables, run nothing")
    args = parser.parse_args(argv)
    if args.readme_only:
        update_readme()
        print(f"wrote {README}")
        return 0
    output = output_directory(args.quick, args.output)
    output.mkdir(parents=True, exist_ok=True)
    failed = False
    for name in args.only or CHECKS:
        print(f"== {name}", flush=True)
        try:
            print(f"== {name}: {run_check(name, args.quick, output)}", flush=True)
        except Exception:  # report and go on: one failing check must not hide the others
            traceback.print_exc()
            print(f"== {name}: FAILED", flush=True)
            failed = True
    if output.resolve() == RESULTS.resolve():
        update_readme()
        print(f"wrote {README}")
    else:
        print(f"results in {output}; {README} left alone (its tables are those of {RESULTS})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
