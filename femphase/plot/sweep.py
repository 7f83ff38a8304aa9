"""Figures of a sweep directory: ``femphase plot DIR`` on a sweep (it has sweep.json).

It aggregates first when summary.csv is missing or older than any run's outputs
(:mod:`femphase.aggregate`), then draws, against the swept key (the first axis that is not a
sample axis), the mean over the sample axes of the runs that are done, with ±1 sample
standard deviation (ddof = 1, the paper's Fig. 1a band) shaded: ``sweep_order`` (Ψ6, Ψ2^L),
``sweep_dynamics`` (mean elongation, T1 rate) and ``sweep_period`` (only when some run has a
detectable period). Other non-sample axes give one curve per combination of their values.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from femphase.aggregate import SAMPLE_SUFFIX, SUMMARY, is_current, read_summary, read_sweep, write_aggregate
from femphase.errors import InputError
from femphase.plot.figures import pyplot, save

__all__ = ["FIGURE_PANELS", "Curve", "plot_summary", "plot_sweep", "sample_curves"]

#: figure → panels, each (y label, [(summary column, legend label)]).
FIGURE_PANELS = {
    "sweep_order": [("order parameter (last fifth of the last phase)", [("Psi6_mean", "Ψ6"), ("Psi2_mean", "Ψ2^L")])],
    "sweep_dynamics": [("mean elongation r (bulk)", [("elongation_mean", "r")]),
                       ("T1 rate (1/(particle · time unit))", [("t1_rate", "T1 rate")])],
    "sweep_period": [("period of the bulk-mean r(t) (time units)", [("period", "period")])],
}


@dataclass
class Curve:
    """Sample statistics of one summary column along the swept key, for one combination of the
    other swept keys: at each x the mean, the sample standard deviation (ddof = 1; NaN for
    one sample) and the number of samples."""

    x: list
    mean: np.ndarray
    sd: np.ndarray
    n: np.ndarray


def sample_curves(rows: list[dict], column: str, x_key: str, curve_keys: list[str]) -> dict[tuple, Curve]:
    """The rows' finite values of ``column`` grouped by the other swept keys' values (the
    curves) and by ``x_key`` (the points), averaged over what remains: the sample axes."""
    groups: dict[tuple, dict] = {}
    for row in rows:
        value = row[column]
        if isinstance(value, float) and np.isfinite(value):
            groups.setdefault(tuple(row[k] for k in curve_keys), {}).setdefault(row[x_key], []).append(value)
    curves = {}
    for label, by_x in groups.items():
        xs = sorted(by_x, key=lambda v: (isinstance(v, str), v if not isinstance(v, str) else 0, str(v)))
        samples = [np.asarray(by_x[x]) for x in xs]
        curves[label] = Curve(xs, np.array([s.mean() for s in samples]),
                              np.array([s.std(ddof=1) if s.size > 1 else np.nan for s in samples]),
                              np.array([s.size for s in samples]))
    return curves


def plot_summary(rows: list[dict], keys: list[str], output: str | Path, fmt: str = "png") -> dict[str, Path]:
    """Draw :data:`FIGURE_PANELS` from summary rows (module docstring) into ``output``; the
    period figure only when some run that is done has a period. Returns {figure: path}."""
    samples = [k for k in keys if k.endswith(SAMPLE_SUFFIX)]
    swept = [k for k in keys if k not in samples]
    x_key = swept[0] if swept else keys[0]
    curve_keys = swept[1:]
    averaged = [k for k in samples if k != x_key]
    done = [row for row in rows if row["status"] == "done"]
    if not done:
        statuses = sorted({row["status"] for row in rows})
        raise InputError(f"no run of the sweep is done (statuses: {', '.join(statuses) or 'no runs'}); "
                         "nothing to plot yet")
    x_all = sorted({row[x_key] for row in done}, key=str)
    numeric = all(isinstance(x, float) for x in x_all)
    plt = pyplot()
    paths = {}
    for figure, panels in FIGURE_PANELS.items():
        columns = [column for _, entries in panels for column, _ in entries]
        if not any(isinstance(row[c], float) and np.isfinite(row[c]) for row in done for c in columns):
            continue  # e.g. no run has a detectable period: no figure rather than an empty one
        fig, axes = plt.subplots(1, len(panels), figsize=(max(4.8 * len(panels), 6.4), 3.8), squeeze=False)
        for ax, (ylabel, entries) in zip(axes[0], panels):
            for column, name in entries:
                for label, curve in sample_curves(done, column, x_key, curve_keys).items():
                    x = curve.x if numeric else [x_all.index(v) for v in curve.x]
                    text = name + "".join(f", {k} = {v:g}" if isinstance(v, float) else f", {k} = {v}"
                                          for k, v in zip(curve_keys, label))
                    n = f"{curve.n.min()}–{curve.n.max()}" if curve.n.min() != curve.n.max() else f"{curve.n[0]}"
                    # error bars too: a band needs two neighbouring points with a spread to show
                    bars = ax.errorbar(x, curve.mean, yerr=curve.sd, marker="o", capsize=3, label=f"{text} (n = {n})")
                    ax.fill_between(x, curve.mean - curve.sd, curve.mean + curve.sd, color=bars.lines[0].get_color(),
                                    alpha=0.2, lw=0)
            if not numeric:
                ax.set_xticks(range(len(x_all)), [str(v) for v in x_all])
            elif min(x_all) > 0 and max(x_all) > 100 * min(x_all):  # rates over decades, as the paper plots them
                ax.set_xscale("log")
            ax.set_xlabel(x_key)
            ax.set_ylabel(ylabel)
            if ax.get_legend_handles_labels()[0]:  # a panel of runs without the column has no curve
                ax.legend(fontsize=7)
        over = (f"mean over {', '.join(averaged)} ± 1 s.d. (ddof = 1; bars and band)" if averaged
                else "one run per point")
        fig.suptitle(f"{len(done)} of {len(rows)} runs done; {over}", fontsize=8)
        paths[figure] = save(fig, Path(output) / f"{figure}.{fmt}")
    return paths


def plot_sweep(directory: str | Path, output: str | Path | None = None, fmt: str = "png") -> dict[str, Path]:
    """Figures of a sweep directory (module docstring), aggregating first unless sweep.nc and
    summary.csv are newer than every input. ``output`` defaults to DIR/figures."""
    directory = Path(directory)
    sweep = read_sweep(directory)
    if not is_current(sweep):
        write_aggregate(directory)
    return plot_summary(read_summary(directory / SUMMARY), list(sweep.axes),
                        directory / "figures" if output is None else output, fmt)
