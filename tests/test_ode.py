"""The paper's minimal ODE model: φ(t), the closed-form and integrated θ(t), and r(t)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
from scipy.signal import find_peaks

from femphase.cli.ode import register
from femphase.errors import SceneError
from femphase.model.minimal import (
    MinimalModelError,
    MinimalModelParameters,
    elongation_rate,
    lattice_angle,
    orientation,
    period,
    solve_minimal_model,
    t1_times,
    wrap_orientation,
)

PAPER_RATES = (0.0778, 0.1487, 0.3857)


@pytest.fixture(scope="module")
def solutions():
    """Four periods at each of the paper's rates, sampled every ~P/5000 to resolve the T1s."""
    return {rate: solve_minimal_model(rate, 4 * period(rate), n_samples=20001) for rate in PAPER_RATES}


def after_transient(solution, periods: float = 2.0) -> np.ndarray:
    """Which samples lie past the first `periods` periods (the transient lasts ~1 time unit)."""
    return solution.time >= periods * solution.period


def test_lattice_angle_spans_square_to_hexagonal_with_period_pi_over_omega():
    rate = 0.1487
    P = period(rate)
    t = np.linspace(0.0, 3 * P, 3001)
    phi = lattice_angle(t, rate)
    assert np.all(phi >= np.pi / 4 - 1e-15) and np.all(phi <= np.pi / 3 + 1e-15)
    assert phi.min() == pytest.approx(np.pi / 4) and phi.max() == pytest.approx(np.pi / 3)
    np.testing.assert_allclose(lattice_angle(t + P, rate), phi, atol=1e-12)
    np.testing.assert_allclose(lattice_angle(t1_times(rate, 3 * P), rate), np.pi / 4, atol=1e-12)


def test_t1_times_are_the_odd_multiples_of_half_a_period():
    rate, k = 0.0778, 0.02
    omega = k * rate
    tau = t1_times(rate, 7 * np.pi / (2 * omega) + 1.0, k)
    n = np.arange(4)
    np.testing.assert_allclose(tau, (2 * n + 1) * np.pi / (2 * omega), rtol=1e-14)


def test_closed_form_orientation_matches_the_integrated_one(solutions):
    for rate, solution in solutions.items():
        closed_form = orientation(solution.time, rate)
        assert np.all(closed_form > -np.pi / 2) and np.all(closed_form <= np.pi / 2)
        # nematic difference, so that −π/2 + δ and π/2 count as close
        difference = wrap_orientation(closed_form - solution.orientation)
        assert np.max(np.abs(difference)) < 1e-6, rate


def test_closed_form_orientation_at_the_paper_landmarks():
    rate = 0.1487
    half = period(rate) / 2
    # θ(0) = π/2; θ → π/4 just before τ_0; reset to −π/4 at τ_0; −π/2 ≡ π/2 halfway to τ_1
    theta = orientation(np.array([0.0, half * (1 - 1e-9), half, 2 * half]), rate)
    np.testing.assert_allclose(theta, [np.pi / 2, np.pi / 4, -np.pi / 4, np.pi / 2], atol=1e-9)


def test_orientation_resets_to_minus_pi_over_4_exactly_at_the_t1_times(solutions):
    solution = solutions[0.1487]
    tau = t1_times(solution.rate, solution.time[-1])
    assert tau.size == 4
    at_t1 = np.flatnonzero(np.isin(solution.time, tau))
    assert at_t1.size == tau.size
    np.testing.assert_allclose(solution.orientation[at_t1], -np.pi / 4, atol=1e-12)
    # one sample earlier θ is still at its pre-T1 value π/4: the jump happens at τ_n itself
    np.testing.assert_allclose(solution.orientation[at_t1 - 1], np.pi / 4, atol=1e-6)
    np.testing.assert_allclose(orientation(tau, solution.rate), -np.pi / 4, atol=1e-12)


def test_elongation_is_periodic_with_period_pi_over_omega(solutions):
    for rate, solution in solutions.items():
        keep = after_transient(solution, periods=1.0)
        t, r = solution.time[keep], solution.elongation[keep]
        peaks, _ = find_peaks(r)
        np.testing.assert_allclose(np.diff(t[peaks]), solution.period, rtol=0.01)
        # upward crossings of the mid level, placed by interpolation between samples
        level = 0.5 * (r.min() + r.max())
        up = np.flatnonzero((r[:-1] < level) & (r[1:] >= level))
        crossings = t[up] + (level - r[up]) / (r[up + 1] - r[up]) * (t[up + 1] - t[up])
        assert crossings.size == 3
        np.testing.assert_allclose(np.diff(crossings), solution.period, rtol=0.01)


def test_periodic_state_does_not_depend_on_the_initial_elongation():
    rate = 0.1487
    t_end = 2 * period(rate)
    near_circle = solve_minimal_model(rate, t_end, initial_elongation=0.01)
    elongated = solve_minimal_model(rate, t_end, initial_elongation=1.0)
    settled = near_circle.time >= 0.1 * near_circle.period
    np.testing.assert_allclose(
        near_circle.elongation[settled], elongated.elongation[settled], atol=1e-6
    )


def primary_peak_and_shoulder(solution):
    """r at the one maximum per cycle, and r where the fast drop after that T1 levels off.

    The drop levels off where dr/dt, negative all along, comes closest to zero: the first
    local maximum of dr/dt after the T1.
    """
    keep = after_transient(solution)
    t, r = solution.time[keep], solution.elongation[keep]
    drdt = elongation_rate(
        r, solution.orientation[keep], solution.lattice_angle[keep], solution.rate,
        solution.parameters,
    )
    peaks, _ = find_peaks(r)
    primary = peaks[0]
    shoulder = primary + find_peaks(drdt[primary:])[0][0]
    return t, r, drdt, primary, shoulder


def test_secondary_peak_at_rate_0_0778_is_a_shoulder_not_a_second_maximum(solutions):
    # The paper reads a "large primary peak immediately followed by a smaller secondary
    # peak" off its figure. In the model r has one maximum per cycle, a cusp at the T1; the
    # reset θ: π/4 → −π/4 flips sin 2θ and r drops within a few time units (≪ π/ω) onto the
    # slowly decaying branch that starts flat at τ_n⁺ — on the scale of a period that reads
    # as a second, smaller peak.
    solution = solutions[0.0778]
    t, r, drdt, primary, shoulder = primary_peak_and_shoulder(solution)
    peaks, _ = find_peaks(r)
    assert peaks.size == 2
    np.testing.assert_allclose(t[peaks], t1_times(solution.rate, t[-1])[-2:], rtol=1e-12)

    assert t[shoulder] - t[primary] < 0.01 * solution.period
    assert np.all(drdt[primary + 1 : shoulder + 1] < 0)
    assert abs(drdt[shoulder]) < 1e-3
    assert r.min() + 0.5 * (r[primary] - r.min()) < r[shoulder] < r[primary] - 0.05


def test_primary_peak_grows_and_secondary_shrinks_with_rate(solutions):
    heights = [primary_peak_and_shoulder(solutions[rate]) for rate in PAPER_RATES]
    primary = [r[p] for _, r, _, p, _ in heights]
    secondary = [r[s] for _, r, _, _, s in heights]
    assert np.all(np.diff(primary) > 0)
    assert np.all(np.diff(secondary) < 0)


def parse(argv):
    parser = argparse.ArgumentParser(prog="femphase")
    register(parser.add_subparsers())
    return parser.parse_args(argv)


def test_cli_writes_csv_and_json(tmp_path):
    args = parse(["ode", "--rate", "0.1487", "-o", str(tmp_path / "run"), "--K", "0.02"])
    assert args.func(args) == 0

    csv_path = tmp_path / "run" / "ode.csv"
    assert csv_path.read_text().splitlines()[0] == "time,elongation,orientation,lattice_angle"
    table = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    assert table.shape[1] == 4 and table.shape[0] >= 2001

    metadata = json.loads((tmp_path / "run" / "ode.json").read_text())
    assert metadata["rate"] == 0.1487
    assert metadata["parameters"] == {"A": 2.0, "epsilon": 2.3, "K": 0.02, "k": 0.01}
    assert metadata["period"] == pytest.approx(np.pi / (0.01 * 0.1487))
    assert metadata["t_end"] == pytest.approx(5 * metadata["period"])
    assert table[-1, 0] == pytest.approx(metadata["t_end"])


@pytest.mark.parametrize("rate", [0.0778, 0.1487, 1.0])
def test_ode_csv_times_increase_strictly_and_a_t1_row_is_after_the_reset(tmp_path, rate):
    # a grid point 5e-13 from a T1 time printed as the same time (2–4 repeated rows),
    # and anything differentiating or re-integrating ode.csv met dt = 0
    args = parse(["ode", "--rate", str(rate), "-o", str(tmp_path / "run")])
    assert args.func(args) == 0
    table = np.loadtxt(tmp_path / "run" / "ode.csv", delimiter=",", skiprows=1)
    assert (np.diff(table[:, 0]) > 0).all()
    first = np.flatnonzero(np.isclose(table[:, 0][:, None], t1_times(rate, table[-1, 0])[None], rtol=0,
                                      atol=1e-6).any(axis=1))
    assert first.size and np.allclose(table[first, 2], -np.pi / 4)
    assert not np.isclose(table[first - 1, 2], -np.pi / 4).any()


def test_the_ode_never_starts_before_the_flow():
    # aligned by the first T1 alone, a random packing's first rearrangement 400 after
    # onset put the ODE's start 1050 time units into the relaxation (rate 0.1083)
    from types import SimpleNamespace

    from femphase.oscillations import ode_alignment, ode_solution

    half = np.pi / (2 * 0.01 * 0.1083)
    early = SimpleNamespace(flow_phase=1, shear_start=2000.0, t1_times=np.array([2400.0]),
                            time=np.linspace(0.0, 6000.0, 61))
    assert ode_alignment(early, 0.1083, 0.01) == (2000.0, "shear onset")
    assert ode_solution(early, 0.1083)[1] == 2000.0
    late = SimpleNamespace(flow_phase=1, shear_start=2000.0, t1_times=np.array([3600.0]), time=early.time)
    offset, how = ode_alignment(late, 0.1083, 0.01)
    assert how == "first T1" and offset == pytest.approx(3600.0 - half)
    none = SimpleNamespace(flow_phase=1, shear_start=2000.0, t1_times=np.zeros(0), time=early.time)
    assert ode_alignment(none, 0.1083, 0.01) == (2000.0, "shear onset")


@pytest.mark.parametrize(
    ("call", "named"),
    [
        (lambda: solve_minimal_model(0.0, 100.0), "rate = 0.0"),
        (lambda: solve_minimal_model(-0.1, 100.0), "rate = -0.1"),
        (lambda: solve_minimal_model(0.1, 0.0), "t_end = 0.0"),
        (lambda: solve_minimal_model(0.1, 100.0, initial_elongation=0.0), "initial_elongation"),
        (lambda: MinimalModelParameters(A=-1.0), "A = -1.0"),
        (lambda: MinimalModelParameters(epsilon=-2.3), "epsilon = -2.3"),
        (lambda: MinimalModelParameters(K=-0.01), "K = -0.01"),
        (lambda: MinimalModelParameters(k=0.0), "k = 0.0"),
        (lambda: orientation(np.zeros(3), float("nan")), "rate = nan"),
    ],
)
def test_bad_values_raise_value_error_naming_them(call, named):
    with pytest.raises(ValueError, match=named):
        call()


@pytest.mark.parametrize("options, named", [
    (["--rate", "-0.1"], r"option '--rate' = -0\.1 is invalid: .*> 0"),
    (["--rate", "0.1", "--t-end", "0"], r"option '--t-end' = 0\.0 is invalid"),
    (["--rate", "0.1", "--initial-elongation", "-1"], r"option '--initial-elongation' = -1\.0 is invalid"),
    (["--rate", "0.1", "--K", "-1"], r"option '--K' = -1\.0 is invalid"),
])
def test_cli_names_a_bad_option_as_given_and_writes_nothing(tmp_path, options, named):
    args = parse(["ode", *options, "-o", str(tmp_path)])
    with pytest.raises(SceneError, match=named):
        args.func(args)
    assert not (tmp_path / "ode.csv").exists()


def test_cli_refuses_an_output_path_that_is_a_file(tmp_path):
    (tmp_path / "taken").write_text("")
    args = parse(["ode", "--rate", "0.1", "-o", str(tmp_path / "taken")])
    with pytest.raises(SceneError, match=r"option '-o' = .*taken' is invalid: a directory"):
        args.func(args)


def test_cli_names_an_output_directory_it_cannot_make():
    # "internal error (FileNotFoundError …)", exit 1, as the other commands named -o
    args = parse(["ode", "--rate", "0.1", "-o", "/proc/femphase-nope"])
    with pytest.raises(SceneError, match=r"option '-o' = '/proc/femphase-nope' is invalid: a directory femphase can "
                                         r"write to"):
        args.func(args)


def test_cli_refuses_to_replace_a_solution_without_overwrite(tmp_path):
    run = parse(["ode", "--rate", "0.1", "-o", str(tmp_path)])
    assert run.func(run) == 0
    first = (tmp_path / "ode.json").read_text()
    again = parse(["ode", "--rate", "0.2", "-o", str(tmp_path)])
    with pytest.raises(SceneError,
                       match=r"option '-o' = .* is invalid: .*ode\.csv, ode\.json; replace them with --overwrite"):
        again.func(again)
    assert (tmp_path / "ode.json").read_text() == first
    replace = parse(["ode", "--rate", "0.2", "-o", str(tmp_path), "--overwrite"])
    assert replace.func(replace) == 0
    assert json.loads((tmp_path / "ode.json").read_text())["rate"] == 0.2


def test_a_run_with_more_half_periods_than_samples_solves_and_a_far_longer_one_is_refused():
    # γ̇ = 10: half periods of π/(2·0.1) ≈ 15.7; 127 of them and 11 samples, so most
    # segments hold no sample (scipy's dense output fails on an empty time array)
    solution = solve_minimal_model(10.0, 2000.0, n_samples=11)
    assert solution.time[-1] == 2000.0 and np.all(np.isfinite(solution.elongation))
    with pytest.raises(ValueError, match=r"t_end = 1000000000.0 is invalid: at most 10000 half periods"):
        solve_minimal_model(0.1, 1e9)


@pytest.mark.filterwarnings("ignore:lsoda")  # LSODA warns before it fails; the error is what is tested
@pytest.mark.parametrize("rate, t_end, options, reason", [
    (1e-10, None, {}, r"on t ∈ \[3\.14159e\+12, .*LSODA"),  # t far beyond the relaxation time's resolution
    (1.0, 400.0, {"parameters": MinimalModelParameters(A=1e300)}, r"A = 1e\+300.*r reached nan"),
    # within the first half period (1571 at γ̇ = 0.1): NaN samples were written, exit 0
    (0.1, 1000.0, {"parameters": MinimalModelParameters(A=1e300)}, r"on t ∈ \[0, 1000\].*r reached nan"),
    (1.0, None, {"parameters": MinimalModelParameters(epsilon=1e12)}, r"ε = 1e\+12.*more than 2000 evaluations"),
    (1e8, 1e-3, {}, r"γ̇ = 1e\+08.*below the resolution of t"),
])
def test_extreme_parameters_stop_with_a_message_naming_them(monkeypatch, rate, t_end, options, reason):
    # a small budget keeps the stalling case fast; the paper's parameters need 600–1900
    monkeypatch.setattr("femphase.model.minimal.MAX_EVALUATIONS", 2000)
    with pytest.raises(MinimalModelError, match=reason):
        solve_minimal_model(rate, t_end or 5 * period(rate), **options)


def test_the_evaluation_budget_leaves_the_paper_range_room(monkeypatch):
    # γ̇ = 1 takes the most evaluations per half period among the paper's rates (about 1900)
    monkeypatch.setattr("femphase.model.minimal.MAX_EVALUATIONS", 4000)
    for rate in (1e-5, 0.0161, 1.0, 1e4):
        assert np.all(np.isfinite(solve_minimal_model(rate, 5 * period(rate)).elongation))


def test_cli_reports_a_failed_integration_as_an_error_and_writes_nothing(tmp_path, capsys):
    from femphase.cli import main

    assert main(["ode", "--rate", "1", "--A", "1e300", "-o", str(tmp_path / "run")]) == 2
    assert "error: the minimal model could not be integrated" in capsys.readouterr().err
    assert not (tmp_path / "run" / "ode.csv").exists()
