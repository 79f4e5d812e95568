"""Where the repetitions of an excitation lie in a record, read off the excitation itself.

A rig's file often says only ``# excitation: swept sine 0.1-40 Hz, 3 sweeps``:
no record length, no lead. The frequency-response estimator
(:func:`samii.measure.frf.estimate_frf`) needs both: the records to average,
and the rest before each sweep whose mean is the operating point. Both follow
from ``r``:

* **Repetition length.** The normalised autocorrelation of ``r``,
  ``rho(tau) = sum r[n] r[n+tau] / sqrt(E_head(tau) E_tail(tau))`` (energies of the two
  overlapping parts), is +-1 at a whole repetition and small elsewhere (a sweep
  does not resemble itself shifted). The first lag where ``|rho| >= 0.9``,
  with enough overlap, is the repetition (sign-alternating repetitions give -1);
  its multiples refine it to a fraction of a sample (parabolic peak of ``|rho|``
  at the largest multiple, divided by the multiple). Sweeps up or down, with or
  without rest between them, are found alike.
* **Where a record starts.** ``r^2`` folded modulo the repetition shows the quiet
  arc (rest) and the active arc. A record starts a little before the sweep's
  onset: a quarter of the rest, or what the file holds before its first onset
  if that is less; that part is each record's operating point (``baseline_s``).
  With no rest (sweeps back to back) a record starts where ``r`` is quietest among
  the phases that leave the most whole records, and no operating point is subtracted.

A stated ``# record_s:`` is used as given once it is checked to be a whole number
of ``r``'s repetitions (or, where ``r`` shows none, ``r`` shifted by it matches
itself; a file whose header gives the sweep's length for the record's is refused,
naming both); the start and the operating point are still read off ``r``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft

__all__ = ["RecordLayout", "find_records", "excitation_offset"]

#: |rho| above which a lag counts as a repetition.
_MIN_CORRELATION = 0.9
#: Both overlapping parts must hold this fraction of r's energy (a short overlap can correlate by chance).
_MIN_OVERLAP_ENERGY = 0.2
#: Shortest repetition considered [s]: a sweep down to 0.1 Hz lasts tens of seconds; 0.5 s leaves room for fast rigs.
_MIN_RECORD_S = 0.5
#: Fewest samples in a repetition found: a repetition of a few samples is no sweep (a time column far from seconds).
_MIN_RECORD_SAMPLES = 16
#: A stated repetition may differ from a whole multiple of the one found by this fraction (or 2 samples).
_STATED_RTOL = 1e-4
#: r^2 below this fraction of its largest folded value is rest (-40 dB in amplitude).
_QUIET = 1e-4
#: Rest shorter than this fraction of a record: the repetitions run back to back.
_MIN_REST_FRACTION = 0.01


@dataclass(frozen=True)
class RecordLayout:
    """Repetitions of the excitation in a time series.

    Attributes
    ----------
    record_s : float
        Length of one repetition [s].
    start_s : float
        Start of the first whole record, from the first sample [s].
    n_records : int
        Whole records from ``start_s``.
    baseline_s : float
        Rest at the start of every record, before the sweep's onset [s]: its mean is the operating point.
    rest_s : float
        Length of the rest between sweeps [s] (0: back to back).
    how : str
        Where ``record_s`` came from (stated or found) and how well the repetitions match.
    """

    record_s: float
    start_s: float
    n_records: int
    baseline_s: float
    rest_s: float
    how: str


def _normalised_autocorrelation(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rho(tau), overlap fraction min(E_head, E_tail)/E) for tau = 0 ... n-1."""
    n = r.size
    nfft = scipy.fft.next_fast_len(2 * n, real=True)
    spec = scipy.fft.rfft(r, nfft)
    ac = scipy.fft.irfft(spec * np.conj(spec), nfft)[:n]
    e = np.concatenate([[0.0], np.cumsum(r * r)])
    total = e[-1]
    tau = np.arange(n)
    head = e[n - tau]  # sum of r[0 : n - tau]^2
    tail = total - e[tau]  # sum of r[tau : n]^2
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = ac / np.sqrt(head * tail)
    overlap = np.minimum(head, tail) / total
    return np.nan_to_num(rho), overlap


def _peak(y: np.ndarray, i: int) -> float:
    """Sub-sample position of the maximum of ``y`` near index ``i`` (parabola through three points)."""
    i = int(np.clip(i, 1, y.size - 2))
    i = i - 1 + int(np.argmax(y[i - 1 : i + 2]))
    i = int(np.clip(i, 1, y.size - 2))
    a, b, c = y[i - 1], y[i], y[i + 1]
    den = a - 2 * b + c
    return float(i + (0.5 * (a - c) / den if den < 0 else 0.0))


def _repetition(r: np.ndarray, fs: float, where: str) -> tuple[float, float]:
    """(repetition length [samples, fractional], |rho| at it) found from the autocorrelation of ``r``."""
    rho, overlap = _normalised_autocorrelation(r)
    a = np.abs(rho)
    ok = (overlap >= _MIN_OVERLAP_ENERGY) & (np.arange(r.size) >= _MIN_RECORD_S * fs)
    cand = np.flatnonzero(ok & (a >= _MIN_CORRELATION))
    if cand.size == 0:
        best = float(np.max(a[ok])) if np.any(ok) else 0.0
        raise ValueError(
            f"{where}: the excitation r does not repeat (largest correlation of r with itself shifted is {best:.2f}, "
            f"a repetition needs {_MIN_CORRELATION}); give the length of one repetition with # record_s: (or --record-s), "
            "or record at least two repetitions"
        )
    # the first run of lags above the threshold holds the first repetition; its peak is the lag
    first = cand[0]
    run_end = first
    while run_end + 1 < r.size and ok[run_end + 1] and a[run_end + 1] >= _MIN_CORRELATION:
        run_end += 1
    t0 = _peak(a, first + int(np.argmax(a[first : run_end + 1])))
    # refine on the largest multiple that still overlaps enough
    k_best, t_best = 1, t0
    k = 2
    while True:
        i = int(round(k * t0))
        if i + 1 >= r.size or not ok[i] or a[i] < _MIN_CORRELATION:
            break
        k_best, t_best = k, _peak(a, i)
        k += 1
    return t_best / k_best, float(a[int(round(t0))])


def _whole_records(n_samples: int, start: float, period: float) -> int:
    """Records of ``floor(period)`` samples starting at ``start + round(k period)`` that fit in ``n_samples``
    (as :func:`samii.measure.frf.split_records` cuts them)."""
    s0 = int(round(start))
    k = int(np.floor((n_samples - s0) / period)) + 1
    while k > 0 and s0 + int(round((k - 1) * period)) + int(np.floor(period)) > n_samples:
        k -= 1
    return k


def _check_stated(r: np.ndarray, fs: float, period: float, where: str) -> None:
    """A stated repetition must be one of r: a whole multiple of the repetition r shows (two sign-alternating
    sweeps are one period of r, and pass), to within ``_STATED_RTOL`` or 2 samples. When r shows none (one
    record, or too little of a second), r shifted by the stated length must match itself (|rho| >= 0.9) where
    the data hold two of it; with less nothing can be checked."""
    if period < _MIN_RECORD_S * fs:
        raise ValueError(
            f"{where}: the stated record_s ({period / fs:.6g} s, from '# record_s:' or --record-s) is shorter than "
            f"any sweep's record ({_MIN_RECORD_S:g} s at least)"
        )
    try:
        found, c = _repetition(r, fs, where)
    except ValueError:
        found = None
    if found is not None:
        k = max(round(period / found), 1)
        if abs(period - k * found) <= max(2.0, _STATED_RTOL * period):
            return
        why = (
            f"r repeats every {found / fs:.6g} s (correlation {c:.4f} between repetitions), and the stated length is "
            f"{period / found:.5g} of that, not a whole number"
        )
    else:
        if 2 * period > r.size:
            return  # r shows no repetition and the data hold less than two of the stated one
        rho, overlap = _normalised_autocorrelation(r)
        i = int(round(period))
        near = float(np.max(np.abs(rho[max(i - 1, 1) : i + 2])))
        if overlap[i] >= _MIN_OVERLAP_ENERGY and near >= _MIN_CORRELATION:
            return
        why = f"r shifted by it correlates with itself by only {near:.2f} (a repetition gives {_MIN_CORRELATION} or more)"
    raise ValueError(
        f"{where}: the stated record_s ({period / fs:.6g} s, from '# record_s:' or --record-s) is not a repetition "
        f"of the excitation: {why}; correct the stated length, or leave it out to have it found from r"
    )


#: Samples at one value, as a fraction of the file, that make it r's rest level (a generated command rests exactly).
_REST_FRACTION = 0.01
#: A median of r this far from 0, as a fraction of r's swing about it, is an offset (a sweep's own median is a few %).
_OFFSET_FRACTION = 0.1


def excitation_offset(r: np.ndarray) -> float:
    """The level ``r`` rests at, 0 unless it is an offset: the value it holds exactly at 1 % or more of its samples (a
    generated command's rest), else its median where that is a tenth or more of its swing about it (an offset under
    back-to-back sweeps); a sweep's own median (2.6 % of its amplitude for 120 s up-sweeps from 0.1 Hz) is none."""
    r = np.asarray(r, float)
    if not r.size:
        return 0.0
    values, counts = np.unique(r, return_counts=True)
    k = int(np.argmax(counts))
    med = float(np.median(r))
    swing = float(np.max(np.abs(r - med)))
    if counts[k] >= _REST_FRACTION * r.size and counts[k] > 1:
        rest = float(values[k])
        return rest if abs(rest) > 1e-12 * swing else 0.0  # (a rest written as -5e-324 is 0)
    return med if swing > 0 and abs(med) >= _OFFSET_FRACTION * swing else 0.0


def find_records(r: np.ndarray, sample_rate_hz: float, *, record_s: float | None = None, where: str = "r") -> RecordLayout:
    """Find the repetitions of the excitation ``r`` (module docstring).

    Parameters
    ----------
    r : array
        Excitation samples [V].
    sample_rate_hz : float
    record_s : float, optional
        Stated repetition length [s]; found from ``r`` when not given.
    where : str
        Names the data in error messages (e.g. the file).

    Raises
    ------
    ValueError
        ``r`` is zero, does not repeat, or holds less than one whole repetition.
    """
    r = np.asarray(r, float)
    fs = float(sample_rate_hz)
    if r.size < 4 or not np.any(r != 0):
        raise ValueError(f"{where}: the excitation r is zero throughout: there is nothing to estimate a frequency response from")
    # an offset (a converter's, an operating point added to r) is no part of the excitation's repetition: with 0.05 V
    # under a 0.1 V sweep that alternates its sign, the repetitions no longer correlated to -1 and one record of two
    # sweeps was found, with no rest (r^2 never quiet)
    r = r - excitation_offset(r)
    if not np.any(r != 0):
        raise ValueError(f"{where}: the excitation r is constant throughout: there is nothing to estimate a frequency response from")
    if record_s is None:
        period, rho = _repetition(r, fs, where)
        if period < _MIN_RECORD_SAMPLES:
            raise ValueError(
                f"{where}: r repeats every {period:.3g} samples ({period / fs:.3g} s at {fs:.6g} samples/s): too short "
                "for a record of a sweep; is t in seconds?"
            )
        how = f"found from r: repetition {period / fs:.6g} s (correlation {rho:.4f} between repetitions)"
    else:
        if not (np.isfinite(record_s) and record_s > 0):
            raise ValueError(f"{where}: record_s must be a positive number of seconds, got {record_s!r}")
        period = float(record_s) * fs
        if period > r.size * (1 + 1e-9):
            raise ValueError(f"{where}: record_s {record_s:.6g} s is longer than the data ({r.size / fs:.6g} s)")
        _check_stated(r, fs, period, where)
        how = f"stated: record_s {record_s:.6g} s"
    n_bins = max(int(np.floor(period)), 2)
    # fold r^2 over the repetition; phase bins of one sample
    phase = np.floor(np.mod(np.arange(r.size), period)).astype(int)
    phase = np.minimum(phase, n_bins - 1)
    folded = np.bincount(phase, weights=r * r, minlength=n_bins) / np.maximum(np.bincount(phase, minlength=n_bins), 1)
    quiet = folded <= _QUIET * folded.max()
    # longest circular run of quiet bins
    if quiet.all():
        raise ValueError(f"{where}: the excitation r is too weak to tell its repetitions apart")
    shift = int(np.flatnonzero(~quiet)[0])  # rotate so that the sequence starts active
    q = np.roll(quiet, -shift)
    best_len, best_end = 0, 0
    run = 0
    for i, v in enumerate(q):
        run = run + 1 if v else 0
        if run > best_len:
            best_len, best_end = run, i
    rest = best_len / fs
    if best_len < _MIN_REST_FRACTION * period:
        # back to back: at a phase that leaves the most whole records (the count only falls as the start moves
        # later), where r is quietest (smoothed over 51 samples); no operating point is subtracted. Quiet first
        # and most records among the quiet phases lost one record in 3 or 5 of a file holding exactly whole sweeps
        # from its first sample: the smoothing carries the previous sweep's loud end into phase 0.
        smooth = np.convolve(np.concatenate([folded[-25:], folded, folded[:25]]), np.ones(51) / 51, mode="valid")
        most = _whole_records(r.size, 0.0, period)
        last = r.size - int(round((most - 1) * period)) - int(np.floor(period))  # the latest start that keeps them all
        start = float(np.argmin(smooth[: min(last, n_bins - 1) + 1]))
        baseline = 0.0
        rest = 0.0
    else:
        onset = float((best_end + 1 + shift) % n_bins)  # first active bin after the rest
        lead_in_file = onset  # rest the file holds before its first onset
        margin = min(0.25 * best_len, lead_in_file)
        # a record may start anywhere in the rest before its sweep: where a quarter of the rest would leave the
        # last record past the file's end (a file of exactly n repetitions whose lead is under a quarter of the
        # rest: samii measure --tail-s 2 lost one of its 3 records), the smallest margin that keeps them all
        widest = min(float(best_len), lead_in_file)
        most = _whole_records(r.size, onset - widest, period)
        if _whole_records(r.size, onset - margin, period) < most:
            lo, hi = margin, widest  # the count rises as the start moves earlier: bisect for the smallest margin
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if _whole_records(r.size, onset - mid, period) >= most else (mid, hi)
            margin = hi
        start = onset - margin
        baseline = 0.9 * margin / fs  # stops short of the onset: r is below -40 dB there, not zero
    n_records = _whole_records(r.size, start, period)
    if n_records < 1:
        raise ValueError(f"{where}: the data ({r.size / fs:.6g} s) hold no whole repetition of {period / fs:.6g} s")
    return RecordLayout(record_s=period / fs, start_s=start / fs, n_records=n_records, baseline_s=baseline, rest_s=rest, how=how)
