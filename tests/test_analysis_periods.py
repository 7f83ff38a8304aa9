"""Oscillation periods of synthetic signals shaped like the paper's r(t), and the limit cycle."""

import numpy as np
import pytest

from femphase.analysis import periods

PERIOD = 314.159


def elongation(time: np.ndarray, *, secondary: float = 0.6, transient: float = 3.0) -> np.ndarray:
    """r(t) like the paper's: each cycle a sharp primary peak, then 0.2 periods later a
    smaller secondary one, on top of a transient decaying over half a period."""

    def pulse(centre: float, width: float) -> np.ndarray:
        phase = (time / PERIOD - centre + 0.5) % 1 - 0.5
        return np.exp(-0.5 * (phase / width) ** 2)

    return (
        1
        + 2 * pulse(0.0, 0.04)
        + 2 * secondary * pulse(0.2, 0.05)
        + transient * np.exp(-time / (0.5 * PERIOD))
    )


def uniform_times(n_cycles: float, per_cycle: int = 125) -> np.ndarray:
    return np.linspace(0, n_cycles * PERIOD, int(n_cycles * per_cycle) + 1)


def uneven_times(n_cycles: float, rng: np.random.Generator) -> np.ndarray:
    return np.sort(rng.uniform(0, n_cycles * PERIOD, int(n_cycles * 125)))


@pytest.mark.parametrize("noise", [0.0, 0.05, 0.2])
@pytest.mark.parametrize("sampling", ["uniform", "uneven"])
@pytest.mark.parametrize("seed", [0, 1])
def test_period_of_elongation_with_transient_and_secondary_peak(noise, sampling, seed):
    rng = np.random.default_rng(seed)
    time = uniform_times(12) if sampling == "uniform" else uneven_times(12, rng)
    signal = elongation(time) + noise * rng.standard_normal(time.size)

    estimate = periods.oscillation_period(time, signal)

    assert abs(estimate.period - PERIOD) <= estimate.uncertainty
    assert estimate.uncertainty < 0.01 * PERIOD
    # the last 9 of 12 cycles, one interval fewer than peaks
    assert 7 <= estimate.n_cycles <= 9


def test_discarding_the_transient_is_what_handles_it():
    # a transient five times the oscillation's height
    time = uniform_times(12)
    signal = elongation(time, transient=10.0)
    estimate = periods.oscillation_period(time, signal)
    assert abs(estimate.period - PERIOD) <= estimate.uncertainty
    # kept, the transient's slow decay under the first cycles shifts the peaks it adds to
    kept = periods.oscillation_period(time, signal, discard_fraction=0.0)
    assert abs(kept.period - PERIOD) > 3 * abs(estimate.period - PERIOD)


@pytest.mark.parametrize("seed", range(8))
def test_noise_as_large_as_the_oscillation_neither_halves_nor_shortens_the_period(seed):
    # a sine of amplitude 0.3 under white noise of s.d. 0.2: on three of these eight records
    # a wrinkle of the autocorrelation's central lobe passed for the period (2.6 for 37.3),
    # and on others the first of the wrinkled maxima of the peak put it 5–11 % short
    period = 37.3
    time = np.arange(0.0, 20 * period, 1.0)
    rng = np.random.default_rng(seed)
    signal = 0.3 * np.sin(2 * np.pi * time / period) + rng.normal(0.0, 0.2, time.size)
    estimate = periods.oscillation_period(time, signal)
    assert abs(estimate.period - period) <= 2 * estimate.uncertainty
    assert abs(estimate.period - period) < 0.05 * period


def test_period_of_the_lattice_angle():
    omega = np.pi / PERIOD
    time = uniform_times(8)
    angle = np.pi / 12 * np.cos(omega * time) ** 2 + np.pi / 4
    estimate = periods.oscillation_period(time, angle)
    assert abs(estimate.period - PERIOD) <= estimate.uncertainty
    assert estimate.uncertainty < 0.01 * PERIOD


def test_period_that_varies_from_cycle_to_cycle():
    # phase jitter: cycle k lasts PERIOD (1 + 3 % noise); the estimate is of the mean period
    rng = np.random.default_rng(3)
    lengths = PERIOD * (1 + 0.03 * rng.standard_normal(40))
    starts = np.concatenate([[0.0], np.cumsum(lengths)])
    time = uniform_times(38)
    cycle = np.searchsorted(starts, time, side="right") - 1
    signal = elongation(PERIOD * (time - starts[cycle]) / lengths[cycle], transient=0.0)

    estimate = periods.oscillation_period(time, signal)

    # the mean length of the cycles that were measured
    measured = lengths[10:37].mean()
    assert abs(estimate.period - measured) <= estimate.uncertainty
    # the uncertainty reflects the scatter of the cycles
    assert estimate.uncertainty > 0.5 * 0.03 * PERIOD / np.sqrt(estimate.n_cycles)


@pytest.mark.parametrize("start, end", [(100.0, 110.0), (100.0, 200.0), (100.0, 50.0)])
def test_a_drifting_period_has_an_uncertainty_that_spans_it(start, end):
    # the period changes steadily over the record; the intervals' scatter alone gave 106.2 ±
    # 0.6 where the local period runs from 102.5 to 110, and 159 ± 7 for 125 to 200
    time = np.arange(0.0, 2000.0, 5.0)
    local = np.linspace(start, end, time.size)
    signal = np.sin(2 * np.pi * np.cumsum(5.0 / local))

    estimate = periods.oscillation_period(time, signal)

    analysed = local[time >= 500.0]
    assert estimate.period - estimate.uncertainty <= analysed.min() + 0.1 * abs(end - start)
    assert estimate.period + estimate.uncertainty >= analysed.max() - 0.1 * abs(end - start)
    assert "drift" in estimate.method


def test_a_steady_period_has_no_drift():
    time = uniform_times(12)
    estimate = periods.oscillation_period(time, elongation(time, transient=0.0))
    assert "drift" not in estimate.method and estimate.uncertainty < 1e-3 * PERIOD


@pytest.mark.parametrize("onset", [2800.0, 3000.0, 3200.0])
@pytest.mark.parametrize("roundoff", [0.0, 1e-9])
def test_a_quiet_stretch_before_the_oscillation_neither_breaks_nor_counts_cycles(onset, roundoff):
    # exactly flat: the autocorrelation was NaN (0/0) or round-off divided by round-off at
    # lags where a segment is constant (ValueError "cannot convert float NaN", or a period
    # of 1210); with 1e-9 round-off each wiggle counted as a cycle's primary peak (34 cycles)
    time = np.arange(0.0, 4000.0, 5.0)
    signal = np.where(time < onset, 0.0, np.sin(2 * np.pi * (time - onset) / 100.0))
    signal = signal + roundoff * np.random.default_rng(0).normal(size=time.size)

    estimate = periods.oscillation_period(time, signal)

    assert estimate.period == pytest.approx(100.0, rel=1e-3)
    assert estimate.n_cycles == round((4000.0 - onset) / 100.0) - 1
    assert estimate.uncertainty < 0.5


@pytest.mark.parametrize("n_cycles", [1.5, 2.0, 2.5, 2.9])
def test_too_few_cycles_raise(n_cycles):
    time = uniform_times(n_cycles)
    with pytest.raises(ValueError, match="cycles"):
        periods.oscillation_period(time, elongation(time, transient=0.0), discard_fraction=0.0)


def test_a_settled_signal_with_a_tiny_periodic_wobble_has_no_period():
    # a settled r(t) = 0.3 wobbling by 1e-6 (grid crossings): a perfect sinusoid, but no oscillation
    time = uniform_times(12)
    settled = 0.3 + 1e-6 * np.sin(2 * np.pi * time / PERIOD)
    with pytest.raises(ValueError, match="no oscillation"):
        periods.oscillation_period(time, settled)
    assert periods.oscillation_period(time, settled, min_relative_amplitude=0.0).period == pytest.approx(PERIOD, rel=0.01)


def test_noise_alone_raises():
    time = uniform_times(12)
    noise = np.random.default_rng(4).standard_normal(time.size)
    with pytest.raises(ValueError, match="no oscillation"):
        periods.oscillation_period(time, noise)


@pytest.mark.parametrize(
    "time, signal, message",
    [
        (np.arange(10.0), np.zeros(9), "equal length"),
        (np.arange(10.0)[::-1], np.zeros(10), "increasing"),
        (np.arange(10.0), np.full(10, np.nan), "finite"),
        (np.arange(100.0), np.ones(100), "constant"),
    ],
)
def test_malformed_input_raises(time, signal, message):
    with pytest.raises(ValueError, match=message):
        periods.oscillation_period(time, signal)


def test_limit_cycle_is_the_polar_plane_of_r_and_2theta():
    x, y = periods.limit_cycle([1.0, 2.0, 0.5], [np.pi / 4, 0.0, -np.pi / 4])
    np.testing.assert_allclose(x, [0.0, 2.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(y, [1.0, 0.0, -0.5])
    # nematic: θ and θ + π are the same point
    np.testing.assert_allclose(
        np.column_stack(periods.limit_cycle([1.5], [0.3 + np.pi])),
        np.column_stack(periods.limit_cycle([1.5], [0.3])),
    )


def test_first_period_of_a_short_record_skips_secondary_peaks():
    # 1.8 cycles from t = T/4: primary peaks at T and 2T, each followed by a secondary peak
    # 0.2 T later; too short for oscillation_period
    time = np.linspace(0.25 * PERIOD, 2.05 * PERIOD, 600)
    signal = elongation(time, transient=0.0)
    assert periods.first_period(time, signal) == pytest.approx(PERIOD, rel=2e-3)
    # one primary peak only: no period, said explicitly
    assert np.isnan(periods.first_period(time[time < 1.5 * PERIOD], signal[time < 1.5 * PERIOD]))


def test_first_peaks_are_the_primary_peak_times():
    time = np.linspace(0.25 * PERIOD, 2.05 * PERIOD, 600)
    peaks = periods.first_peaks(time, elongation(time, transient=0.0))
    np.testing.assert_allclose(peaks, [PERIOD, 2 * PERIOD], rtol=2e-3)
    # a shifted record shifts its peaks by the same time
    shift = 0.3 * (time[1] - time[0])
    np.testing.assert_allclose(periods.first_peaks(time, elongation(time - shift, transient=0.0)), peaks + shift,
                               atol=0.05 * (time[1] - time[0]))


def test_the_uncertainty_is_the_documented_sum_of_its_parts(monkeypatch):
    # each part of the composition was loose in the tests: the standard error's ddof, the half
    # difference of the two estimates and the resolution's √6 could change unseen. The peaks
    # are set here, so every part is known: intervals 10, 11, 9, 11 (mean 10.25) against the
    # autocorrelation's period (10, refined between samples 0.5 apart)
    time = np.arange(0.0, 120.0, 0.5)
    signal = np.sin(2 * np.pi * time / 10.0)
    monkeypatch.setattr(periods, "_primary_peak_times", lambda grid, values, period: np.array([2.5, 12.5, 23.5, 32.5,
                                                                                                43.5]))
    monkeypatch.setattr(periods, "_period_drift", lambda intervals, resolution: 0.0)
    estimate = periods.oscillation_period(time, signal, discard_fraction=0.0)
    assert estimate.period == pytest.approx(10.0, rel=1e-3) and estimate.n_cycles == 4
    intervals = np.array([10.0, 11.0, 9.0, 11.0])
    standard_error = np.sqrt(np.sum((intervals - 10.25) ** 2) / 3) / 2  # s.d. with n − 1, over √n
    half_difference = (estimate.period - 10.25) / 2
    resolution = 0.5 / (np.sqrt(6) * 4)  # each end peak uniform within ± step/2: step/√12 each, √2 of them, over n
    assert estimate.uncertainty == pytest.approx(np.sqrt(standard_error**2 + half_difference**2 + resolution**2),
                                                 rel=1e-12)
