"""Convergence studies as one command: a scene at several resolutions, its observables'
observed order, Richardson-extrapolated limit with an error bar, and each run's error.

    femphase converge SCENE.toml --h 1,0.5,0.25 -o DIR [--observable period,area]
    femphase converge SCENE.toml --tolerance-t 0.1,0.01,0.001 -o DIR
    femphase converge SCENE.toml --dt 10,5,2.5 -o DIR
    femphase converge MESH_SCENE.toml --mesh coarse.vtu,medium.vtu,fine.vtu -o DIR

**The refinement.** One parameter s takes two or more values: the spacing ``domain.h`` of
the structured channel or the mesh files ``domain.mesh`` of a meshed one (spatial; s is
then each mesh's effective spacing √(area / dofs)), the adaptive scheme's
``numerics.tolerance_t`` or every phase's ``dt`` (temporal). The study is an ordinary sweep (:mod:`femphase.sweep`) over that key, run on
Dask and resumable: DIR holds ``sweep.toml`` (the study as a sweep file), ``sweep.json`` and
``runs/<id>/``; rerunning the command continues it, and added values add runs.

**The analysis** (:func:`richardson`), per observable f, with levels ordered coarse to fine
and r = s₂/s₃ the finest pair's ratio:

* observed order p from the three finest levels (f₁ the coarsest of them):
  (f₁ − f₂)/(f₂ − f₃) = (s₁^p − s₂^p)/(s₂^p − s₃^p), i.e. ``p = log(|f₁ − f₂| / |f₂ − f₃|) / log r``
  at a constant ratio, solved over all real p at any other (:func:`_observed_order`); with
  two levels, p is the ``expected_order``;
* limit f∞ = f₃ + (f₃ − f₂)/(r^q − 1) (Richardson), q = min(p, formal order): an observed
  order above the formal one (2 in h; in dt the scheme's, 2, or 1 for ``euler``; 1 in the
  tolerance; ``--order``: :func:`formal_order`) comes from levels outside the asymptotic
  range and would shrink the error bar;
* error bar: Roache's grid convergence index, ``F·|f₃ − f₂|/(r^q − 1)``, with the safety
  factor F = 1.25 when p is observed and 3 when it is assumed, in quadrature with twice the
  limit's measurement uncertainty (a period's own, from its cycles: :func:`_with_noise`);
* each run's error f_k − f∞;
* for a tolerance study, the neighbouring levels whose last phase took the same substeps
  (:func:`same_substeps`), named in every observable's note; where a level of such a pair
  is among the finest three, no order and no limit (the tolerance does not control its
  step, so its difference to the others is not the error the tolerance controls).

The limit is not reported (NaN, with the reason) when the differences change sign
(oscillatory convergence) or p ≤ 0 (divergence): the levels are not in the asymptotic
range and a finer one is needed. Where the finest two values are equal (and took different
substeps, in a tolerance study), the limit is that value at any order, with an error bar
of 0.

**Observables** (:data:`OBSERVABLES`), all from the run directories:

* ``period``: period of the bulk-mean elongation r̄(t) under flow, its first quarter
  discarded as transient (:func:`femphase.oscillations.measured_period`), time units;
* ``mean_elongation``: r averaged over particles and over the last phase's averaging
  window (the last fifth of its frames), dimensionless;
* ``area``: mean particle area ∫φ² at the last frame, lattice units²;
* ``separation``: centroid distance of a two-particle scene at the last frame (minimum
  image in x), lattice units.

**Outputs** in DIR: ``convergence.csv`` (one row per observable and level: s, value, its
measurement uncertainty, error against the limit, CPU seconds; and per observable the order, limit and error bar),
``convergence.nc`` (the same as an xarray Dataset over ``observable`` × ``level``; both
with each level's substeps in the last phase, :func:`last_phase_substeps`) and
``convergence.png`` (the absolute error against s and against CPU seconds: the work–precision plot).
"""

from __future__ import annotations

import ast
import csv
import io
import json
import math
import re
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from femphase.errors import FemphaseError, SceneError
from femphase.io.files import atomic_write, output_directory
from femphase.io.reader import RunData, mean_present, open_run
from femphase.tomlio import toml_value

if TYPE_CHECKING:  # dask.distributed loads only where a study runs
    from distributed import Client

__all__ = ["FORMAL_ORDER", "OBSERVABLES", "PARAMETERS", "ConvergenceError", "Estimate", "StudyIncomplete", "analyse",
           "formal_order", "last_phase_substeps", "option_of", "plateau_among_finest", "richardson", "run_convergence",
           "same_substeps",
           "study_sweep"]

#: Refinement parameters: command-line name → (scene key, its unit). For "mesh" the values are
#: mesh files and s is each run's effective spacing √(area / dofs).
PARAMETERS = {"h": ("domain.h", "lattice units"), "mesh": ("domain.mesh", "lattice units"),
              "tolerance_t": ("numerics.tolerance_t", "dimensionless"), "dt": ("phases.*.dt", "time units")}


#: Formal order of each refinement: P1 in h (and a mesh's spacing), a second-order scheme in
#: dt (:func:`formal_order`: the scheme's own, 1 for ``euler``), and an error per substep
#: proportional to the tolerance.
FORMAL_ORDER = {"h": 2.0, "mesh": 2.0, "dt": 2.0, "tolerance_t": 1.0}


def formal_order(parameter: str, settings: dict, method: str = "fem") -> float:
    """The formal order of refining ``parameter`` in a run of the resolved scene
    ``settings``: in dt that of its time scheme (``TimeScheme.order``; the FD reference's
    Heun step is 2), else :data:`FORMAL_ORDER`."""
    if parameter != "dt" or method == "fd":
        return FORMAL_ORDER[parameter]
    from femphase.timestepping.base import scheme_class

    return float(scheme_class(settings["numerics"]["scheme"]).order)


class ConvergenceError(SceneError):
    """A convergence study that cannot be run or analysed as asked (names the option)."""


class StudyIncomplete(FemphaseError):
    """Some runs of a study did not finish (failed, interrupted or pending): nothing to
    analyse yet. The message names each with its status and error."""


@dataclass(frozen=True)
class Estimate:
    """What a study says about one observable (see the module docstring)."""

    order: float
    order_observed: bool
    order_used: float
    limit: float
    error_bar: float
    errors: tuple[float, ...]
    note: str = ""


#: The observed orders :func:`_observed_order` resolves: beyond them it returns ±inf.
ORDER_RANGE = 50.0


def _observed_order(s: np.ndarray, f: np.ndarray) -> float:
    """p with (f₁ − f₂)/(f₂ − f₃) = (s₁^p − s₂^p)/(s₂^p − s₃^p) for the three finest levels,
    the left side positive. With x = ln(s₁/s₂) and y = ln(s₂/s₃) the right side is
    expm1(p x)/(−expm1(−p y)), which rises from 0 to ∞ over all real p, through x/y at p = 0
    (r^p at a constant ratio r): a ratio of differences below x/y has a negative p, however
    the levels are spaced. Solved by bisection on [−50, 50] (:data:`ORDER_RANGE`), narrowed
    where the levels lie so far apart that s^p would leave the doubles (|p|·max(x, y) up to
    700); ±inf beyond."""
    s1, s2, s3 = s[-3:]
    target = (f[-3] - f[-2]) / (f[-2] - f[-1])
    x, y = math.log(s1 / s2), math.log(s2 / s3)

    def ratio(p: float) -> float:
        return x / y if p == 0 else math.expm1(p * x) / -math.expm1(-p * y)

    high = min(ORDER_RANGE, 700.0 / max(x, y))
    low = -high
    if target <= ratio(low):
        return -math.inf
    if target >= ratio(high):
        return math.inf
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if ratio(middle) < target else (low, middle)
    return 0.5 * (low + high)


def richardson(spacings: list[float], values: list[float], expected_order: float = 2.0,
               uncertainties: list[float] | None = None) -> Estimate:
    """Observed order, Richardson limit, error bar and errors of ``values`` measured at
    ``spacings`` (any order, all different); ``expected_order`` is the formal order, used
    with two levels and whenever the observed order exceeds it. ``uncertainties``: each
    value's own standard uncertainty as measured (a period's, from its cycles), which the
    error bar takes in (:func:`_with_noise`)."""
    order_of = np.argsort(spacings)[::-1]  # coarse to fine
    s = np.asarray(spacings, dtype=float)[order_of]
    f = np.asarray(values, dtype=float)[order_of]
    if s.size < 2:
        raise ConvergenceError("levels", list(spacings), "at least two values of the refined parameter")
    if np.any(s[:-1] <= s[1:] * (1 + 1e-9)) or s[-1] <= 0:
        raise ConvergenceError("levels", list(spacings), "different values > 0 of the refined parameter")
    u = np.zeros(s.size) if uncertainties is None else np.asarray(uncertainties, dtype=float)[order_of]
    estimate = _richardson(s, f, order_of, float(expected_order))
    differences = f[:-1] - f[1:]
    reversed_pairs = np.flatnonzero(differences[:-2] * differences[-1] <= 0) if s.size > 3 else []
    if np.all(np.isfinite(f)) and len(reversed_pairs):
        named = ", ".join(f"{s[k]:g} to {s[k + 1]:g}" for k in reversed_pairs)
        estimate = replace(estimate, note=((estimate.note + "; ") if estimate.note else "") + (
            f"levels coarser than the finest three, which set the order, do not converge with them (from {named} "
            "the difference has the other sign): they are outside the asymptotic range"))
    return _with_noise(estimate, f, u, float(s[-2] / s[-1]))


def _with_noise(estimate: Estimate, f: np.ndarray, u: np.ndarray, r: float) -> Estimate:
    """``estimate`` with the values' measurement uncertainties ``u`` (levels coarse to fine):
    the limit's, √((u₃ r^q)² + u₂²)/(r^q − 1), enters the error bar as twice itself in
    quadrature with the grid convergence index; and where a difference of neighbouring
    levels among the finest three is within twice its own uncertainty, the note says that
    the order (or the sign change) may be the measurement's noise. The levels' errors are
    taken as independent, which is conservative where they are correlated: a period read
    from the same few cycles at every h carries the same cycle-to-cycle jitter at each, and
    their differences are better known than u says."""
    if not np.any(u > 0):
        return estimate
    noisy = [k for k in range(max(0, f.size - 3), f.size - 1) if abs(f[k] - f[k + 1]) <= 2 * math.hypot(u[k], u[k + 1])]
    note = estimate.note
    if noisy:
        pairs = ", ".join(f"{f[k]:.6g} ± {u[k]:.2g} and {f[k + 1]:.6g} ± {u[k + 1]:.2g}" for k in noisy)
        note = ((note + "; ") if note else "") + (f"levels differ by less than twice their measurement uncertainty "
                                                  f"({pairs}): unless their errors are one (the same cycles measured "
                                                  f"at every level), the order is not resolved; measure longer or "
                                                  f"refine further")
    error_bar = estimate.error_bar
    if math.isfinite(error_bar):
        scale = r**estimate.order_used - 1.0
        error_bar = math.hypot(error_bar, 2 * math.hypot(u[-1] * (scale + 1.0), u[-2]) / scale)
    return replace(estimate, error_bar=error_bar, note=note)


def _richardson(s: np.ndarray, f: np.ndarray, order_of: np.ndarray, expected_order: float) -> Estimate:
    """:func:`richardson` on the levels ordered coarse to fine (``order_of``: their places in the input)."""
    r = float(s[-2] / s[-1])  # the finest pair's ratio
    nan = (math.nan,) * s.size
    observed = s.size >= 3
    missing = int(np.count_nonzero(~np.isfinite(f)))
    if missing:
        return Estimate(math.nan, observed, math.nan, math.nan, math.nan, nan,
                        f"not measured in {missing} of the {s.size} runs")
    if f[-1] == f[-2]:  # the extrapolation is f₃ at any order
        errors = np.empty(s.size)
        errors[order_of] = f - f[-1]
        return Estimate(math.inf if observed else float(expected_order), observed, float(expected_order),
                        float(f[-1]), 0.0, tuple(float(e) for e in errors),
                        "identical at the finest two levels: the limit is their value")
    if observed:
        coarse, fine = f[-3] - f[-2], f[-2] - f[-1]
        if coarse == 0:
            return Estimate(-math.inf, True, math.nan, math.nan, math.nan, nan,
                            "identical at the coarser two of the finest three levels and not at the finer two: "
                            "not in the asymptotic range (refine further)")
        if coarse * fine < 0:
            return Estimate(math.nan, True, math.nan, math.nan, math.nan, nan,
                            "the differences change sign: not in the asymptotic range (refine further)")
        order = _observed_order(s, f)
        if not order > 0:
            return Estimate(order, True, math.nan, math.nan, math.nan, nan,
                            "the differences grow as s falls: divergent")
    else:
        order = float(expected_order)
    # an order observed above the formal one comes from levels outside the asymptotic range
    # and would shrink the bar: extrapolate with the smaller (Roache's conservative choice)
    used = min(order, float(expected_order))
    scale = r**used - 1.0
    limit = float(f[-1] + (f[-1] - f[-2]) / scale)
    error_bar = (1.25 if observed else 3.0) * abs(f[-1] - f[-2]) / scale
    errors = np.empty(s.size)
    errors[order_of] = f - limit
    note = f"observed order above the formal {expected_order:g}: extrapolated with {expected_order:g}" if used < order else ""
    return Estimate(float(order), observed, used, limit, float(error_bar), tuple(float(e) for e in errors), note)


def _period(run: RunData) -> tuple[float, float]:
    from femphase.oscillations import period_estimate

    estimate = period_estimate(run)  # the first quarter of the last phase is discarded as transient
    return (math.nan, math.nan) if estimate is None else (float(estimate.period), float(estimate.uncertainty))


def _mean_elongation(run: RunData) -> tuple[float, float]:
    from femphase.aggregate import averaging_window

    window = averaging_window(run.time, run.info["settings"]["phases"])
    # over the particles present: a vanished one's r is NaN
    return mean_present(run.elongation[window]), 0.0  # NaN for an empty window too


def _area(run: RunData) -> tuple[float, float]:
    return float(np.mean(run.particles["area"][-1])), 0.0


def _require_pair(n_particles: int) -> None:
    """ConvergenceError unless the scene has the two particles ``separation`` measures."""
    if n_particles != 2:
        raise ConvergenceError("--observable", "separation", f"a two-particle scene (this one has {n_particles})")


def _separation(run: RunData) -> tuple[float, float]:
    _require_pair(run.n_particles)
    period = float(run.scene["domain"].get("Lx", 0.0)) or run.domain.period
    dx = (run.x[-1, 1] - run.x[-1, 0] + period / 2) % period - period / 2
    return float(np.hypot(dx, run.y[-1, 1] - run.y[-1, 0])), 0.0


#: Observables a study can measure: name → (function of a run giving its value and the
#: value's own standard uncertainty as measured, 0 where it is exact; unit).
OBSERVABLES: dict[str, tuple[Callable[[RunData], tuple[float, float]], str]] = {
    "period": (_period, "time units"),
    "mean_elongation": (_mean_elongation, "dimensionless"),
    "area": (_area, "lattice units²"),
    "separation": (_separation, "lattice units"),
}


def _level_keys(parameter: str, phases: int) -> list[str]:
    """The scene keys one level of ``parameter`` sets: every phase's dt for "dt"."""
    if parameter not in PARAMETERS:
        raise ConvergenceError("parameter", parameter, f"one of {sorted(PARAMETERS)}")
    return [f"phases.{k}.dt" for k in range(phases)] if parameter == "dt" else [PARAMETERS[parameter][0]]


def study_sweep(scene: Path, parameter: str, values: list[float], phases: int) -> str:
    """The sweep file (TOML text) of a study: ``scene`` and the axis of ``parameter``
    (every phase's dt, zipped, for "dt")."""
    from femphase.sweep import STUDY_HEADER  # the sweep's module loads the run's: only where a study starts

    keys = _level_keys(parameter, phases)
    lines = [STUDY_HEADER, "[sweep]",
             f"scene = {toml_value(str(Path(scene).resolve()))}", f'mode = "{"zip" if len(keys) > 1 else "product"}"',
             "", "[axes]"]
    values = [str(Path(v).resolve()) for v in values] if parameter == "mesh" else [float(v) for v in values]
    lines += [f'"{k}" = {toml_value(values)}' for k in keys]
    return "\n".join(lines) + "\n"


def analyse(directory: Path, parameter: str, observables: list[str], expected_order: float | None = None) -> dict:
    """Read a study's runs and estimate every observable; writes convergence.csv, .nc and
    .png into ``directory`` and returns the estimates."""
    index = json.loads((directory / "sweep.json").read_text())
    keys = list(index["axes"])
    levels = []
    for entry in index["runs"]:
        run = open_run(directory / entry["directory"])
        info = run.info
        if parameter == "mesh":
            _check_mesh_unchanged(run, entry["id"])
        spacing = (run.domain.effective_spacing if parameter == "mesh"
                   else float(entry["values"][keys[0]]))
        measured = {name: OBSERVABLES[name][0](run) for name in observables}
        levels.append({"s": spacing, "run": entry["id"],
                       "cpu_s": float(info.get("cpu_time_s", math.nan)), **last_phase_substeps(info),
                       **{name: value for name, (value, _) in measured.items()},
                       "uncertainty": {name: uncertainty for name, (_, uncertainty) in measured.items()}})
    levels.sort(key=lambda level: -level["s"])
    spacings = [level["s"] for level in levels]
    formal = (formal_order(parameter, run.info["settings"], run.info.get("method", "fem"))
              if expected_order is None else expected_order)
    estimates = {name: richardson(spacings, [level[name] for level in levels], formal,
                                  [level["uncertainty"][name] for level in levels]) for name in observables}
    if parameter == "tolerance_t":
        warning = same_substeps(levels)
        if warning:
            unresolved = plateau_among_finest(levels)
            # an observable not measured keeps that reason first: the substeps are not why it has no limit
            estimates = {name: _without_limit(e, f"{e.note}; {warning}" if e.note.startswith("not measured") else
                                              warning) if unresolved else
                         replace(e, note=f"{e.note}; {warning}" if e.note else warning)
                         for name, e in estimates.items()}
    _write_tables(directory, parameter, levels, estimates)
    _plot(directory / "convergence.png", parameter, levels, estimates)
    return {"parameter": parameter, "levels": levels, "estimates": estimates}


def _without_limit(estimate: Estimate, reason: str) -> Estimate:
    """``estimate`` with no order, limit, error bar or errors (NaN), and ``reason`` as its note."""
    nan = (math.nan,) * len(estimate.errors)
    return replace(estimate, order=math.nan, order_used=math.nan, limit=math.nan, error_bar=math.nan, errors=nan,
                   note=f"no limit: {reason}")


def _check_mesh_unchanged(run: RunData, run_id: str) -> None:
    """ConvergenceError where a mesh study's run computed on another mesh than its file
    holds now: its spacing s is read from the file (run.json's ``domain`` records the mesh's
    digest; runs written without it are taken as they are)."""
    recorded = run.info.get("domain", {}).get("mesh_checksum")
    current = run.domain.describe().get("mesh_checksum")
    if recorded is not None and recorded != current:
        raise ConvergenceError("--mesh", run.scene["domain"]["mesh"], f"the mesh file run {run_id} computed on; "
                               f"it has changed since (digest {current}, the run's {recorded}), so its spacing "
                               "would be another mesh's: restore the file, or start the study in a new directory "
                               "(convergence.csv, .nc and .png there, if any, are an analysis from before the change)")


def last_phase_substeps(info: dict) -> dict:
    """``substeps``, ``rejected`` and ``capped`` (those a ceiling set: the area mode's, or the split repulsion's) of a
    run's last phase from its run.json (``info``), and ``mean_substep``, the phase's
    duration over its substeps (time units); NaN for schemes that do not count substeps and
    for runs that did not reach the last phase."""
    phases = info["settings"]["phases"]
    counted = {record["phase"]: record for record in info.get("substeps", [])}
    record = counted.get(len(phases) - 1)
    if record is None or record["accepted"] == 0:
        return {"substeps": math.nan, "rejected": math.nan, "capped": math.nan, "mean_substep": math.nan}
    return {"substeps": record["accepted"], "rejected": record["rejected"], "capped": record.get("capped", math.nan),
            "mean_substep": float(phases[-1]["duration"]) / record["accepted"]}


def same_substeps(levels: list[dict]) -> str:
    """For a tolerance study (levels coarse to fine): a note naming the neighbouring levels
    whose last phase took the same substeps, accepted and rejected, or "". Between them the
    tolerance did not change the step: the controller keeps a size while its estimate stays
    within about 20–65 % of the tolerance (docs/design/time-schemes.md), and the area-mode
    ceiling may cap it (``capped``, named in the note), so their difference is not that
    phase's time error, which the tolerance controls (at most what is left of earlier
    phases')."""
    pairs = [(coarse, fine) for coarse, fine in zip(levels, levels[1:])
             if math.isfinite(coarse["substeps"]) and coarse["substeps"] == fine["substeps"]
             and coarse["rejected"] == fine["rejected"]]
    if not pairs:
        return ""
    named = ", ".join(f"{coarse['s']:g} and {fine['s']:g}" for coarse, fine in pairs)
    finest = pairs[-1][1]
    involved = list({id(level): level for pair in pairs for level in pair}.values())
    capped = [level for level in involved if math.isfinite(level["capped"]) and level["capped"] > 0]
    ceiling = ("; a ceiling capped " + ", ".join(f"{level['capped']:g} at {level['s']:g}" for level in capped)
               if capped else "")
    return (f"tolerance_t = {named} took the same substeps in the last phase ({finest['substeps']:g}, mean "
            f"{finest['mean_substep']:.3g}{ceiling}), so their difference is not the time error the tolerance "
            f"controls; start the study below {finest['s']:g}")


def plateau_among_finest(levels: list[dict]) -> bool:
    """Whether a level of a :func:`same_substeps` pair is among the finest three (levels
    coarse to fine), the levels a limit comes from: a pair whose finer level is the third
    finest counts, though its coarser one is outside them (0.1 and 0.01 of 0.1, 0.01, 1e-3,
    3e-4 gave order 0.34 and a limit 0.004 from the time-converged value, inside its bar)."""
    return same_substeps(levels[-4:]) != ""


def _write_tables(directory: Path, parameter: str, levels: list[dict], estimates: dict[str, Estimate]) -> None:
    import xarray as xr

    parameter = "spacing" if parameter == "mesh" else parameter  # a mesh study's s is each mesh's spacing
    buffer = io.StringIO()
    out = csv.writer(buffer, lineterminator="\n")
    out.writerow(["observable", "unit", parameter, "run", "value", "uncertainty", "error", "cpu_s", "substeps",
                  "rejected", "capped", "mean_substep", "order", "order_observed", "order_used", "limit", "error_bar",
                  "note"])
    for name, estimate in estimates.items():
        unit = OBSERVABLES[name][1]
        for level, error in zip(levels, estimate.errors):
            out.writerow([name, unit, _number(level["s"]), level["run"], _number(level[name]),
                          _number(level["uncertainty"][name]), _number(error),
                          f"{level['cpu_s']:.3f}", *_counts(level), "", "", "", "", "", ""])
        out.writerow([name, unit, "limit", "", "", "", "", "", "", "", "", "", _number(estimate.order),
                      estimate.order_observed, _number(estimate.order_used), _number(estimate.limit),
                      _number(estimate.error_bar), estimate.note])
    atomic_write(directory / "convergence.csv", buffer.getvalue())
    names = list(estimates)
    dataset = xr.Dataset(
        {"value": (("observable", "level"), [[level[n] for level in levels] for n in names]),
         "uncertainty": (("observable", "level"), [[level["uncertainty"][n] for level in levels] for n in names]),
         "error": (("observable", "level"), [list(estimates[n].errors) for n in names]),
         "cpu_s": ("level", [level["cpu_s"] for level in levels]),
         **{key: ("level", [float(level[key]) for level in levels])
            for key in ("substeps", "rejected", "capped", "mean_substep")},
         "order": ("observable", [estimates[n].order for n in names]),
         "order_used": ("observable", [estimates[n].order_used for n in names]),
         "limit": ("observable", [estimates[n].limit for n in names]),
         "error_bar": ("observable", [estimates[n].error_bar for n in names])},
        coords={"observable": names, "level": np.arange(len(levels)), parameter: ("level", [lv["s"] for lv in levels]),
                "unit": ("observable", [OBSERVABLES[n][1] for n in names])},
        attrs={"format": "femphase-convergence", "parameter": parameter,
               "note": "error = value − limit (Richardson); error_bar: grid convergence index"})
    path = directory / "convergence.nc"
    temporary = path.with_suffix(".nc.tmp")
    dataset.to_netcdf(temporary, engine="h5netcdf")
    temporary.replace(path)


def _number(value: float) -> str:
    """A CSV cell: the shortest text that reads back as the same double ("nan", "inf" too)."""
    return repr(float(value))


def _counts(level: dict) -> list[str]:
    """A level's substeps, rejected, capped and mean substep as CSV cells (empty where not
    counted)."""
    if not math.isfinite(level["substeps"]):
        return ["", "", "", ""]
    capped = str(level["capped"]) if math.isfinite(level["capped"]) else ""
    return [str(level["substeps"]), str(level["rejected"]), capped, f"{level['mean_substep']:.6g}"]


def _plot(path: Path, parameter: str, levels: list[dict], estimates: dict[str, Estimate]) -> None:
    parameter = "effective spacing √(area / dofs)" if parameter == "mesh" else parameter
    from femphase.plot.figures import pyplot, save

    plt = pyplot()
    fig, (by_s, by_cpu) = plt.subplots(1, 2, figsize=(9, 3.6))
    s = np.array([level["s"] for level in levels])
    cpu = np.array([level["cpu_s"] for level in levels])
    undrawn = []
    for name, estimate in estimates.items():
        error = np.abs(np.asarray(estimate.errors))
        if not np.any(np.isfinite(error) & (error > 0)):
            undrawn.append(f"{name}: {estimate.note or 'no error against a limit'}")
            continue
        label = f"{name} (p = {estimate.order:.2f}{'' if estimate.order_observed else '*, assumed'})"
        by_s.loglog(s, error, "o-", label=label)
        by_cpu.loglog(cpu, error, "o-", label=label)
    by_s.set_xlabel(parameter)
    by_cpu.set_xlabel("CPU seconds")
    for ax in (by_s, by_cpu):
        ax.set_ylabel("|value − Richardson limit|")
        ax.grid(True, which="both", alpha=0.3)
    if by_s.lines:  # an observable without a finite error draws nothing
        by_s.legend(fontsize=8)
    if undrawn:  # said on the figure, which would otherwise be blank or silently short
        import textwrap

        text = "\n".join(textwrap.fill(f"not drawn, {line}", 120) for line in undrawn)
        # the figure grows by the note's lines (7 pt, spaced 1.3), which sit below the axes' labels
        note_height = (text.count("\n") + 1) * 1.3 * 7 / 72 + 0.1  # inches
        width, height = fig.get_size_inches()
        fig.set_size_inches(width, height + note_height)
        fig.text(0.01, 0.05 / (height + note_height), text, fontsize=7, va="bottom", ha="left", color="darkred")
        save(fig, path, rect=(0.0, note_height / (height + note_height), 1.0, 1.0))
    else:
        save(fig, path)


def option_of(scene_key: str) -> str:
    """The converge option that sets ``scene_key`` (``--dt`` for any phase's dt), else
    ``--set KEY``."""
    for name, (key, _) in PARAMETERS.items():
        if re.fullmatch(re.escape(key).replace(r"\*", r"\d+"), scene_key):
            return f"--{name.replace('_', '-')}"
    return f"--set {scene_key}"


def _study_error(exc: SceneError, refined: str, levels: list) -> ConvergenceError:
    """A sweep's refusal of a changed study (SweepError naming ``set.KEY``, ``axes`` or the
    scene) as the study's: the option that set the key, or the refined option ``refined``
    with the ``levels`` given."""
    key, value, valid = exc.key, exc.value, exc.valid
    if key.startswith("set."):
        option = option_of(key[4:])
        # an option or its --set spelling: both are the same assignment of every run
        key = option if option.startswith("--set") else f"{option} (or --set {key[4:]})"
        valid = re.sub(r"^unset ", "not given (the scene's own value) ", valid)
    elif key == "axes" or key.startswith("axes."):
        key = refined
        if isinstance(value, dict):  # the axes as the sweep file has them: the levels given
            value = next(iter(value.values()))
        elif isinstance(value, list) and all(isinstance(v, str) for v in value):  # another refined parameter
            value = levels
            valid = re.sub(r"the axes (\[[^]]*\]), in that order",
                           lambda match: f"levels of {_options_of(ast.literal_eval(match[1]))}, the option refined", valid)
    elif key == "sweep.mode":  # every phase's dt is refined zipped, one other key alone: another parameter
        where = re.search(r"as in the sweep of (.*?), which", valid)
        key, value = refined, levels
        valid = (f"levels of the parameter the study of {where[1] if where else 'this directory'} refines, which is "
                 "another; start a new directory for another study")
    elif key == "sweep.scene":
        key = "SCENE"  # the study's argument, as femphase run names its own
    valid = (valid.replace("as in the sweep of", "as in the study of")
             .replace("added values only", "added levels only").replace("another sweep", "another study"))
    return ConvergenceError(key, value, valid)


def _options_of(keys: list[str]) -> str:
    """The converge options that set scene keys (``--dt`` once for every phase's dt)."""
    return ", ".join(sorted({option_of(key) for key in keys}))


def _check_levels(scene: str | Path, parameter: str, levels: list, assignments: list[str], phases: int) -> None:
    """ConvergenceError naming the option and the level whose scene is invalid (``--h 0.7``
    where Lx is no multiple of it), or the mesh files of one spacing, before any run; the
    sweep would name its own keys, and the analysis would refuse equal spacings after every
    run."""
    from femphase.scene import load_scene

    keys = _level_keys(parameter, phases)
    spacings = {}
    for level in levels:
        value = toml_value(str(level) if parameter == "mesh" else float(level))
        try:
            with warnings.catch_warnings():  # the sweep warns once per run
                warnings.simplefilter("ignore")
                loaded = load_scene(scene, assignments + [f"{k}={value}" for k in keys])
        except SceneError as exc:
            raise ConvergenceError(f"--{parameter.replace('_', '-')}", str(level) if parameter == "mesh" else level,
                                   f"a level every run's scene accepts ({exc})") from None
        if parameter == "mesh":
            spacing = loaded.domain.effective_spacing
            twin = next((other for other, s in spacings.items() if math.isclose(s, spacing, rel_tol=1e-9)), None)
            if twin is not None:
                raise ConvergenceError("--mesh", [str(twin), str(level)], f"meshes of different spacings: both have "
                                       f"the effective spacing √(area/dofs) = {spacing:.6g}, one level twice")
            spacings[level] = spacing


def run_convergence(scene: str | Path, directory: str | Path, parameter: str, values: list[float],
                    observables: list[str], assignments: list[str] = (), *, expected_order: float | None = None,
                    workers: int | None = None, scheduler: str | None = None, client: Client | None = None,
                    log: Callable[[str], None] = print) -> dict:
    """Run (or continue) a convergence study of ``scene`` into ``directory`` and analyse it
    (module docstring); ``assignments`` are ``--set KEY=VALUE`` overrides of every run;
    ``expected_order`` overrides the parameter's :data:`FORMAL_ORDER`.
    Returns what :func:`analyse` returns."""
    from femphase.scene import load_scene
    from femphase.sweep import SweepError, run_sweep

    unknown = [name for name in observables if name not in OBSERVABLES]
    if unknown or not observables:
        raise ConvergenceError("--observable", ",".join(unknown) or "(none)", f"names from {sorted(OBSERVABLES)}")
    if expected_order is not None and not (math.isfinite(expected_order) and expected_order > 0):
        raise ConvergenceError("--order", expected_order, "a finite number > 0 (the formal order of the refined "
                               "parameter, e.g. 2)")
    option = f"--{parameter.replace('_', '-')}"
    if parameter == "mesh":
        if len(values) < 2 or any(not Path(v).is_file() for v in values):
            raise ConvergenceError(option, values, "two or more mesh files that exist, coarse to fine")
    elif len(values) < 2 or any(not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0) for v in values):
        raise ConvergenceError(option, values, "two or more numbers > 0, e.g. 1,0.5,0.25")
    levels = [Path(v).resolve() for v in values] if parameter == "mesh" else values
    ordered = sorted(values, reverse=True) if parameter != "mesh" else []
    if len(set(levels)) < len(levels) or any(a <= b * (1 + 1e-9) for a, b in zip(ordered, ordered[1:])):
        raise ConvergenceError(option, values, "distinct values, one per level (a value is listed twice, or two "
                               "agree to 1e-9)")
    with warnings.catch_warnings():  # the base scene's own levels (its dt, say) may be no run's; each run warns
        warnings.simplefilter("ignore")
        loaded = load_scene(scene, list(assignments))
    if "separation" in observables:  # checked before any run, which could not give it
        _require_pair(loaded.n_particles)
    if "period" in observables and all(phase.flow.get("type", "none") == "none" for phase in loaded.phases):
        raise ConvergenceError("--observable", "period", "an observable of this scene: period measures the "
                               "oscillation under flow, and no phase of it has one")
    if parameter == "tolerance_t" and loaded.numerics.scheme != "adaptive":
        raise ConvergenceError(option, values, f'a tolerance study of the adaptive scheme: the scene\'s '
                               f'numerics.scheme is "{loaded.numerics.scheme}", whose steps the tolerance does '
                               'not set (refine --dt instead, or --set numerics.scheme=adaptive)')
    if parameter == "dt" and loaded.numerics.scheme == "adaptive":
        warnings.warn("--dt with the adaptive scheme refines the outer step only: its substeps follow "
                      "numerics.tolerance_t (the substeps line of the report shows them), so the differences are "
                      "not a time error of order 2 in dt; refine --tolerance-t, or set numerics.scheme = \"sav2\" "
                      "for a study in dt, from dt ≤ 2.5 (sav2 has no area-mode ceiling: on examples/single.toml it "
                      "blows up at dt = 5 and is 31 % off in area at dt = 10)", stacklevel=2)
    kind = loaded.domain.kind
    if (parameter, kind) in (("h", "mesh"), ("mesh", "grid")):
        raise ConvergenceError(option, values, "--h on the structured channel, --mesh FILE1,FILE2,… on a mesh "
                               f"domain (this scene's domain is of kind {kind!r}; a mesh's spacing is its file's)")
    phases = len(loaded.phases)
    _check_levels(scene, parameter, levels, list(assignments), phases)
    directory = output_directory(directory)  # "" is refused, not taken for "."
    with tempfile.TemporaryDirectory() as scratch:  # the sweep keeps its own copy, DIR/sweep.toml
        sweep_file = Path(scratch) / "converge.toml"
        sweep_file.write_text(study_sweep(Path(scene), parameter, values, phases))
        try:
            index = run_sweep(sweep_file, directory, client, assignments=list(assignments), scheduler=scheduler,
                              workers=workers, log=log)
        except SweepError as exc:  # named as the study's options, not as its sweep file's keys
            raise _study_error(exc, option, list(values)) from None
    unfinished = [run for run in index["runs"] if run["status"] != "done"]
    if unfinished:
        listed = "; ".join(f"{run['id']} {run['status']}" + (f" ({run['error']})" if run.get("error") else "")
                           for run in unfinished)
        advice = ("failed runs start again as they were when the command is given again, and a study's scene, "
                  "--set and levels cannot change once it has run: to change what made them fail (e.g. --set "
                  "numerics.area_implicit=true, or other levels), start the study in a new directory; "
                  if any(run["status"] == "failed" for run in unfinished) else "")
        raise StudyIncomplete(f"{len(unfinished)} of {len(index['runs'])} runs of the study did not finish, so "
                              f"there is nothing to analyse: {listed}. The same command continues the study: "
                              f"{advice}interrupted and pending runs continue (sweep.json in {directory})")
    return analyse(directory, parameter, observables, expected_order)
