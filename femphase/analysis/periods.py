"""Period of the collective shape oscillations, and their limit cycle in the (r, 2θ) plane.

The period is measured on a scalar time series of the oscillation, e.g. the mean elongation
r(t) of the particles or the lattice angle φ(t).  The paper's r(t) is asymmetric: each cycle
has a large primary peak immediately followed by a smaller secondary peak, and the run starts
with a transient (from the initial lattice to the limit cycle).

Conventions: time is in whatever unit the ``time`` array is in (solver time units, or frame
numbers), and the period and its uncertainty come back in that unit; angles are in radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import find_peaks

__all__ = ["first_peaks", "first_period", "limit_cycle", "oscillation_period", "PeriodEstimate"]

#: An autocorrelation peak is "major" when at least this fraction of the highest one: the
#: peaks at multiples of the period are all about equally high, while those at the lag between
#: a primary and a secondary peak of the signal are well below.
_MAJOR_PEAK_FRACTION = 0.7

#: The autocorrelation at the period must reach this: the periodic part then carries at
#: least this fraction of the signal's variance.  Lower peaks come from noise, or from the
#: correlation of the primary peak of a cycle with its secondary peak when fewer than two
#: cycles fit in half the record.
_MIN_CORRELATION = 0.4

#: An autocorrelation peak counts only when it rises at least this far above the troughs
#: on either side (its prominence). Noise on the signal wrinkles the autocorrelation: on the
#: central lobe's falling flank a wrinkle can be as high as the peak at the period (0.50
#: against 0.57 for a sine of amplitude 0.3 under white noise of s.d. 0.2), and the flat
#: top of that peak splits into several maxima, of which the first lies short of the
#: period. The wrinkles rise by a few hundredths; a peak at the period by twice its height,
#: at least 0.4 (:data:`_MIN_CORRELATION`), where the correlation falls below zero between
#: periods, and still by far more than this above a transient's slow decay.
_MIN_PROMINENCE = 0.2

#: Primary peaks of the signal are at least this many periods apart.  Every instant is within
#: half a period of a primary peak, so any lower peak (a secondary, or noise) lies within this
#: distance of a higher one and is discarded, while primaries survive a cycle-to-cycle jitter
#: of up to 0.4 periods.
_PRIMARY_SEPARATION = 0.6

#: A primary peak rises at least this fraction of the retained signal's range above the
#: troughs beside it (its prominence). A cycle's primary rises by most of the range; the
#: round-off wiggles of a quiet stretch before an oscillation starts (1e-9 on a signal of
#: amplitude 1) would otherwise each count as a cycle's primary.
_PRIMARY_PROMINENCE = 0.1

#: A segment of the autocorrelation whose variance (sum of squared deviations) is at most
#: this fraction of the whole record's is constant up to round-off (:func:`_autocorrelation`).
_QUIET_VARIANCE = 1e-10

#: A linear trend of the intervals between primary peaks counts as a drift of the period
#: when its slope is this many of its standard errors from zero; the trend's change over
#: the record then enters the uncertainty (:func:`oscillation_period`).
_DRIFT_SIGNIFICANCE = 3.0

#: The autocorrelation and the peak spacing are two measurements of one period; when they
#: differ by more than this fraction, one of them has locked on to the wrong feature.
_METHOD_AGREEMENT = 0.25


@dataclass(frozen=True)
class PeriodEstimate:
    """The period of an oscillation and how well it is known.

    ============ ===================================================================
    period       the lag of the first major peak of the autocorrelation (time units)
    uncertainty  one standard uncertainty of `period` (time units), see
                 :func:`oscillation_period`
    n_cycles     number of complete cycles measured: intervals between successive
                 primary peaks
    method       how `period` and `uncertainty` were obtained
    ============ ===================================================================
    """

    period: float
    uncertainty: float
    n_cycles: int
    method: str


def oscillation_period(
    time: ArrayLike,
    signal: ArrayLike,
    *,
    discard_fraction: float = 0.25,
    min_cycles: float = 3.0,
    min_relative_amplitude: float = 1e-3,
) -> PeriodEstimate:
    """Period of a shape oscillation from a time series.

    1. Discard the first `discard_fraction` of the time span (the transient).
    2. Resample linearly onto a uniform grid with the median sampling interval (the samples
       may be unevenly spaced).
    3. The period is the lag of the first major peak of the autocorrelation: the first peak
       at least 0.7 times as high as the highest within half the record (a secondary peak in
       each cycle gives lower peaks at shorter lags), which must reach 0.4; peaks count that
       rise at least 0.2 above the troughs beside them (the wrinkles noise makes do not).  It is refined to
       a fraction of the sampling interval by a parabola through the peak and its two
       neighbours.  Each lag correlates the two overlapping segments with their own means and
       variances, so that the peak of a periodic signal is exactly at its period, whatever
       its mean, a linear drift (a slow remainder of the transient) or the fraction of a
       cycle at either end.
    4. Independently, the primary peak of every cycle is located: peaks at least 0.6 periods
       apart (a secondary peak has a higher primary closer than that) that rise at least a
       tenth of the signal's range above the troughs beside them (not a quiet stretch's
       wiggles), each refined by a parabola.  The intervals between successive primary peaks
       give a second estimate, their mean.

    The uncertainty combines, in quadrature,

    * the standard error of the mean interval, std / √n_cycles: the cycle-to-cycle scatter.
      It is conservative when the scatter is timing noise of the individual peaks (successive
      intervals then anticorrelate), and right when the period itself fluctuates;
    * half the difference between the two estimates: their systematic disagreement;
    * the error the mean interval would have with its first and last peak known only to the
      nearest sample, step / (√6 n_cycles): the floor for a noise-free signal, where the
      other two terms vanish;
    * where the period drifts (the intervals' least-squares slope is at least 3 of its
      standard errors from zero, with 4 or more intervals), half the fitted change of the
      period over the record: the reported period is then the record's mean, and the
      uncertainty spans the local periods (``method`` says so). A period changing from 100
      to 110 over a record reads 106.2 ± 3.6, not ± 0.6.

    Parameters
    ----------
    time
        Sample times, strictly increasing (any unit).
    signal
        Samples of the oscillating quantity at `time`.
    discard_fraction
        Fraction, in [0, 1), of the time span discarded at the start.
    min_cycles
        Fewest cycles the retained part must span for a period to be reported.
    min_relative_amplitude
        Smallest peak-to-peak of the retained signal, relative to its largest magnitude, that
        counts as an oscillation: below it (a settled r(t) wobbling by round-off or by the
        grid) no period is reported.

    Returns
    -------
    PeriodEstimate

    Raises
    ------
    ValueError
        If the inputs are malformed, or the retained signal does not show at least
        `min_cycles` cycles (and at least three primary peaks) of one consistent period.
    """
    time, signal = _steady_part(time, signal, discard_fraction)
    amplitude, scale = np.ptp(signal), np.max(np.abs(signal))
    if amplitude <= min_relative_amplitude * scale:
        raise ValueError(
            f"no oscillation: the signal after the transient is (nearly) constant, varying by {amplitude:.3g}, at most "
            f"{min_relative_amplitude:g} of its magnitude {scale:.3g} (min_relative_amplitude)"
        )
    grid, values = _uniform_resampling(time, signal)
    step = grid[1] - grid[0]

    period = step * _first_major_autocorrelation_lag(values)
    span_cycles = (time[-1] - time[0]) / period
    if span_cycles < min_cycles:
        raise ValueError(
            f"the signal after the transient spans only {np.floor(100 * span_cycles) / 100:.2f} cycles of period "
            f"{period:g}; need at least {min_cycles:g} (record longer, or lower "
            f"discard_fraction)"
        )

    peak_times = _primary_peak_times(grid, values, period)
    if len(peak_times) < 3:
        raise ValueError(
            f"found {len(peak_times)} primary peaks after the transient; need at least 3 "
            f"to measure cycle-to-cycle intervals"
        )
    intervals = np.diff(peak_times)
    mean_interval = intervals.mean()
    if abs(mean_interval - period) > _METHOD_AGREEMENT * period:
        raise ValueError(
            f"no consistent period: the autocorrelation gives {period:g} but the primary "
            f"peaks are {mean_interval:g} apart on average"
        )
    standard_error = intervals.std(ddof=1) / np.sqrt(len(intervals))
    # the first and last peak each known to the nearest sample (a uniform error of ± step/2)
    resolution = step / (np.sqrt(6) * len(intervals))
    drift = _period_drift(intervals, step / np.sqrt(6))
    method = ("autocorrelation peak; uncertainty from primary-peak intervals (standard error, half the "
              "difference between the two estimates, sampling resolution")
    if drift:
        method += f", and half the drift of the period over the record, {drift:.4g})"
    return PeriodEstimate(
        period=float(period),
        uncertainty=float(
            np.sqrt(standard_error**2 + ((period - mean_interval) / 2) ** 2 + resolution**2 + (drift / 2) ** 2)
        ),
        n_cycles=len(intervals),
        method=method + ("" if drift else ")"),
    )


def _period_drift(intervals: np.ndarray, resolution: float) -> float:
    """The change of the period over the record (its fitted value half an interval past the
    last, less that half an interval before the first): the least-squares slope of the
    intervals against their number, times their count. 0 unless the slope is
    :data:`_DRIFT_SIGNIFICANCE` of its standard errors from zero (4 intervals or more) and
    the change exceeds ``resolution``, how well an interval is known from its samples."""
    n = len(intervals)
    if n < 4:
        return 0.0
    index = np.arange(n) - (n - 1) / 2
    slope = float(index @ intervals / (index @ index))
    residuals = intervals - intervals.mean() - slope * index
    slope_error = np.sqrt(residuals @ residuals / (n - 2) / (index @ index))
    drift = abs(slope) * n
    return drift if abs(slope) > _DRIFT_SIGNIFICANCE * slope_error and drift > resolution else 0.0


def first_peaks(time: ArrayLike, signal: ArrayLike) -> np.ndarray:
    """Times of the first two primary peaks of a short record (one to two cycles), in the
    unit of ``time``; fewer when the record has fewer.

    Primary peaks: local maxima with a prominence of at least a quarter of the signal's range
    that reach at least 70 % of the way from its minimum to its maximum (a secondary peak
    is lower), each refined by the vertex of the parabola through it and its neighbours. The
    samples must be equally spaced.
    """
    time, signal = np.asarray(time, dtype=float), np.asarray(signal, dtype=float)
    span = np.ptp(signal)
    peaks, _ = find_peaks(signal, prominence=span / 4.0, height=signal.min() + 0.7 * span)
    peaks = peaks[(peaks > 0) & (peaks < len(signal) - 1)]
    step = time[1] - time[0]
    return np.array([time[i] + step * _parabolic_vertex_offset(signal[i - 1:i + 2]) for i in peaks[:2]])


def first_period(time: ArrayLike, signal: ArrayLike) -> float:
    """Time between the first two primary peaks (:func:`first_peaks`) of a short record, e.g.
    r̄(t) over one period of shear (too short for :func:`oscillation_period`). NaN with fewer
    than two peaks (the record did not oscillate), so comparisons stay explicit.
    """
    peaks = first_peaks(time, signal)
    return float(peaks[1] - peaks[0]) if len(peaks) == 2 else float("nan")


def limit_cycle(
    elongation: ArrayLike, orientation: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """The trajectory in the paper's polar plane (r, 2θ).

    x = r cos 2θ, y = r sin 2θ, with r the elongation (λ1/λ2 − 1 of the shape tensor,
    dimensionless; (a/b)² − 1 for an ellipse of similar level sets, docs/model.md) and
    θ the nematic angle of the elongation axis from the x axis (radians).  Doubling the angle
    makes the nematic θ and θ + π the same point.
    """
    elongation = np.asarray(elongation, dtype=float)
    doubled = 2 * np.asarray(orientation, dtype=float)
    return elongation * np.cos(doubled), elongation * np.sin(doubled)


def _steady_part(
    time: ArrayLike, signal: ArrayLike, discard_fraction: float
) -> tuple[np.ndarray, np.ndarray]:
    time = np.asarray(time, dtype=float)
    signal = np.asarray(signal, dtype=float)
    if time.ndim != 1 or time.shape != signal.shape:
        raise ValueError(
            f"time and signal must be 1-D of equal length; got shapes {time.shape} and "
            f"{signal.shape}"
        )
    if not (np.isfinite(time).all() and np.isfinite(signal).all()):
        raise ValueError("time and signal must be finite")
    if len(time) < 2 or (np.diff(time) <= 0).any():
        raise ValueError("time must be strictly increasing with at least two samples")
    if not 0 <= discard_fraction < 1:
        raise ValueError(f"discard_fraction must be in [0, 1); got {discard_fraction}")
    start = time[0] + discard_fraction * (time[-1] - time[0])
    kept = time >= start
    return time[kept], signal[kept]


def _uniform_resampling(
    time: np.ndarray, signal: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    if len(time) < 2:
        raise ValueError("fewer than two samples remain after discarding the transient")
    step = np.median(np.diff(time))
    grid = time[0] + step * np.arange(int(np.floor((time[-1] - time[0]) / step)) + 1)
    return grid, np.interp(grid, time, signal)


def _first_major_autocorrelation_lag(values: np.ndarray) -> float:
    """Lag, in samples, of the first major peak of the autocorrelation of `values`."""
    # a lag at which one segment is constant correlates nothing: 0, not NaN, which
    # find_peaks would carry into the lag
    correlation = np.nan_to_num(_autocorrelation(values), nan=0.0)
    peaks, _ = find_peaks(correlation, prominence=_MIN_PROMINENCE)
    heights = correlation[peaks]
    if heights.max(initial=-1.0) < _MIN_CORRELATION:
        raise ValueError(
            f"no oscillation found: the autocorrelation has no peak above "
            f"{_MIN_CORRELATION} within half the record (fewer than 2 clear cycles)"
        )
    major = peaks[heights >= _MAJOR_PEAK_FRACTION * heights.max()][0]
    return major + _parabolic_vertex_offset(correlation[major - 1 : major + 2])


def _autocorrelation(values: np.ndarray) -> np.ndarray:
    """Pearson correlation between ``values[:-lag]`` and ``values[lag:]``, for lags from 0 to
    half the record.

    Each lag uses the means and variances of its own two overlapping segments, so the
    correlation of a periodic signal is exactly 1 at its period, whatever its mean, a linear
    drift, or the fraction of a cycle at either end; a correlation normalised globally
    instead peaks slightly short of the period.  Beyond half the record fewer than half the
    samples overlap, too few to trust.
    """
    n_samples = len(values)
    # centred, so that the sums below do not cancel catastrophically
    values = values - values.mean()
    lags = np.arange(n_samples // 2 + 1)
    overlap = n_samples - lags
    spectrum = np.fft.rfft(values, 2 * n_samples)
    products = np.fft.irfft(np.abs(spectrum) ** 2)[: len(lags)]
    sums = np.concatenate([[0.0], np.cumsum(values)])
    squares = np.concatenate([[0.0], np.cumsum(values**2)])
    head_sum, tail_sum = sums[overlap], sums[-1] - sums[lags]
    head_squares, tail_squares = squares[overlap], squares[-1] - squares[lags]
    covariance = products - head_sum * tail_sum / overlap
    head_variance = head_squares - head_sum**2 / overlap
    tail_variance = tail_squares - tail_sum**2 / overlap
    if head_variance[0] <= 0:
        raise ValueError("no oscillation found: the signal is constant")
    # a segment that is constant (a quiet stretch as long as it) has no correlation: its
    # variance from the cumulative sums is then round-off, and divided by it, any number
    quiet = np.minimum(head_variance, tail_variance) <= _QUIET_VARIANCE * head_variance[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.sqrt(head_variance * tail_variance)
    correlation[quiet] = np.nan
    return correlation


def _primary_peak_times(grid: np.ndarray, values: np.ndarray, period: float) -> np.ndarray:
    step = grid[1] - grid[0]
    separation = max(1, int(_PRIMARY_SEPARATION * period / step))
    peaks, _ = find_peaks(values, distance=separation, prominence=_PRIMARY_PROMINENCE * np.ptp(values))
    # a peak within `separation` of an end was compared with one side only, so a secondary
    # whose primary the end cut off passes; keep such a peak only if it is as high as a
    # primary compared on both sides
    interior = (peaks >= separation) & (peaks < len(values) - separation)
    lowest_primary = values[peaks[interior]].min(initial=np.inf)
    primary = peaks[interior | (values[peaks] >= lowest_primary)]
    offsets = [_parabolic_vertex_offset(values[peak - 1 : peak + 2]) for peak in primary]
    return grid[primary] + step * np.asarray(offsets)


def _parabolic_vertex_offset(three: np.ndarray) -> float:
    """Offset, in samples from the middle one, of the vertex of the parabola through three
    equally spaced samples (a local maximum at the middle one)."""
    before, middle, after = three
    curvature = before - 2 * middle + after
    return 0.0 if curvature == 0 else 0.5 * (before - after) / curvature
