"""How often the period measurement finds a period in a record that has none, and how its
uncertainty separates those from real oscillations.

    python -m verification.period_false_alarms [--quick]

:func:`femphase.analysis.periods.oscillation_period` reports a period when the record's
autocorrelation has a clear peak (≥ 0.4, prominence 0.2) and at least three primary peaks
agree with it. A record of red noise (slow, correlated wandering, as r̄(t) shows where the
suspension does not oscillate) can pass on a short record. This check measures how often,
on records as femphase's runs write them (200–1000 frames), and what the passing ones
report, against records that do oscillate:

* **red noise**: AR(1) records x_k = ρ x_{k−1} + ε_k, ρ = 0.8 … 0.99 (correlation times of
  5 to 100 frames), n = 200, 400 and 1000 samples, 40 records each;
* **smoothed noise**: white noise smoothed by a Gaussian of s.d. 2, 5 and 10 samples (a
  wandering without the AR(1)'s small-scale roughness, whose autocorrelation falls as a
  Gaussian), the same lengths, 40 records each;
* **oscillations**: the paper's asymmetric cycle, sin ωt + ½ sin(2ωt + 1), of period 10, 20
  and 40 samples, under AR(1) noise (ρ = 0.5) of standard deviation 0.1, 0.3, 0.6 and 1 ×
  the cycle's amplitude, the same lengths, 10 records each.

Reported: the fraction of records given a period; for those, the relative uncertainty
u/T and the cycles measured; for the oscillations, the fraction within 10 % of the true
period. The first quarter of each record is discarded, as for runs.
"""

from __future__ import annotations

import os

# one BLAS thread: the machine's two cores are shared with other long runs
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import time  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from femphase.analysis.periods import oscillation_period  # noqa: E402
from verification.mms import command_line, save_figure, save_results  # noqa: E402

CORRELATIONS = (0.8, 0.9, 0.95, 0.98, 0.99)
SMOOTHING = (2.0, 5.0, 10.0)
LENGTHS = (200, 400, 1000)
PERIODS = (10.0, 20.0, 40.0)
NOISE_LEVELS = (0.1, 0.3, 0.6, 1.0)
SEED = 1


def ar1(rng: np.random.Generator, n: int, rho: float) -> np.ndarray:
    """An AR(1) record of unit innovations, started at 0."""
    noise = rng.normal(size=n)
    out = np.empty(n)
    out[0] = noise[0]
    for k in range(1, n):
        out[k] = rho * out[k - 1] + noise[k]
    return out


def smoothed(rng: np.random.Generator, n: int, width: float) -> np.ndarray:
    """White noise smoothed by a Gaussian of s.d. ``width`` samples."""
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(rng.normal(size=n), width)


def measured(record: np.ndarray) -> tuple[float, float, int] | None:
    """(period, u/T, cycles) of a record sampled at unit spacing, None when none is found."""
    try:
        estimate = oscillation_period(np.arange(record.size, dtype=float), record)
    except ValueError:
        return None
    return estimate.period, estimate.uncertainty / estimate.period, estimate.n_cycles


def noise_rows(rng: np.random.Generator, make, name: str, parameters: tuple, records: int) -> list[dict]:
    """Per noise parameter (``name``) and length: ``records`` records of ``make(rng, n,
    parameter)`` and the periods found in them."""
    rows = []
    for parameter in parameters:
        for n in LENGTHS:
            found = [measured(make(rng, n, parameter)) for _ in range(records)]
            rows.append({name: parameter, "n": n, "records": records, "found": [list(f) for f in found if f is not None]})
    return rows


def run(quick: bool = False, output: Path | None = None) -> dict:
    start = time.perf_counter()
    rng = np.random.default_rng(SEED)
    red_records, periodic_records = (8, 2) if quick else (40, 10)
    red = noise_rows(rng, ar1, "rho", CORRELATIONS, red_records)
    smooth = noise_rows(rng, smoothed, "width", SMOOTHING, red_records)
    periodic = []
    for period in PERIODS:
        for level in NOISE_LEVELS:
            for n in LENGTHS:
                t = np.arange(n, dtype=float)
                cycle = np.sin(2 * np.pi * t / period) + 0.5 * np.sin(4 * np.pi * t / period + 1.0)
                scale = level * np.ptp(cycle) / 2 * np.sqrt(1 - 0.5**2)  # the AR(1)'s s.d. is 1/√(1 − ρ²)
                found = [measured(cycle + scale * ar1(rng, n, 0.5)) for _ in range(periodic_records)]
                periodic.append({"period": period, "noise": level, "n": n, "records": periodic_records,
                                 "found": [list(f) for f in found if f is not None]})
    red_found = [f for row in red for f in row["found"]]
    smooth_found = [f for row in smooth for f in row["found"]]
    periodic_found = [(row["period"], f) for row in periodic for f in row["found"]]
    close = [f for period, f in periodic_found if abs(f[0] - period) <= 0.1 * period]
    results = {
        "quick": quick,
        "red": red,
        "periodic": periodic,
        "red_records": sum(row["records"] for row in red),
        "red_found": len(red_found),
        "red_relative_uncertainty": [min(f[1] for f in red_found), max(f[1] for f in red_found)] if red_found else [],
        "red_cycles": [min(f[2] for f in red_found), max(f[2] for f in red_found)] if red_found else [],
        "smooth": smooth,
        "smooth_records": sum(row["records"] for row in smooth),
        "smooth_found": len(smooth_found),
        "smooth_relative_uncertainty": ([min(f[1] for f in smooth_found), max(f[1] for f in smooth_found)]
                                        if smooth_found else []),
        "smooth_cycles": [min(f[2] for f in smooth_found), max(f[2] for f in smooth_found)] if smooth_found else [],
        "periodic_records": sum(row["records"] for row in periodic),
        "periodic_found": len(periodic_found),
        "periodic_within_10_percent": len(close),
        "periodic_relative_uncertainty_quantiles": [float(q) for q in np.quantile([f[1] for f in close],
                                                                                   [0.1, 0.5, 0.9])],
    }
    return save_results("period_false_alarms", results, plot, start, output)


def plot(results: dict, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(5.5, 4))
    red = [(f[2], f[1]) for row in results["red"] for f in row["found"]]
    smooth = [(f[2], f[1]) for row in results["smooth"] for f in row["found"]]
    periodic = [(f[2], f[1]) for row in results["periodic"] for f in row["found"]
                if abs(f[0] - row["period"]) <= 0.1 * row["period"]]
    for points, label, marker in ((periodic, "oscillations (period within 10 %)", "."), (red, "red noise", "x"),
                                  (smooth, "smoothed noise", "+")):
        if points:
            cycles, relative = np.array(points).T
            ax.scatter(cycles, 100 * relative, marker=marker, label=label, s=18)
    ax.set_xscale("log")
    ax.set_xlabel("cycles measured")
    ax.set_ylabel("relative uncertainty u/T (%)")
    ax.legend(fontsize=8)
    save_figure(fig, path)


if __name__ == "__main__":
    command_line("period_false_alarms", run, ("red_found", "red_records", "red_relative_uncertainty", "red_cycles",
                                              "smooth_found", "smooth_records", "smooth_relative_uncertainty",
                                              "smooth_cycles",
                                              "periodic_found", "periodic_records", "periodic_within_10_percent",
                                              "periodic_relative_uncertainty_quantiles"))
