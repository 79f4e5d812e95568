"""Measured data for a diagnosis: a frequency response with the random error of every point.

A diagnosis weighs the residual between data and model against the data's own
noise, so each point carries ``var``: the variance of the complex relative error
``E|H_est/H - 1|^2`` of the estimate (its log magnitude and phase each have half
of it). Where it comes from, best first:

* **Record-to-record spread** (a time series with >= 2 repetitions): each record's own ratio, the spread
  between records pooled over the FFT bins around each point (:mod:`samii.measure.frf_variance`).
* **Coherence** (an FRF file with ``*_coh``): Bendat & Piersol's
  ``eps^2 = (1 - g)/(2 n g)`` for each of log magnitude and phase, so
  ``var = 2 eps^2``, with the estimated coherence's bias allowed for
  (``sum w^2/(1 - sum w^2)`` in place of ``1/n``: ``1/(n - 1)`` for equal weights, the
  weights from the file's ``frf_record_weights`` line when it gives them),
  pooled over ``POOL`` neighbouring points; ``n`` from the
  file's ``frf_records`` or ``averages`` line, else 3 (the rig's averages,
  notebook ch. 9), said so.
* **A stepped sine's coherence** (samii's stepped frf.csv or timeseries.csv):
  each dwell's sine fit over thousands of samples, ``g = |Y|^2/(|Y|^2 + 4 s^2/N)``
  with ``s^2`` the noise next to the dwell's frequency, so ``var = (1 - g)/g``,
  each point its own (:func:`_stepped_var`).
* **The residual's roughness** (no coherence, one record: a rig-era .mat):
  the random error varies with frequency by orders of magnitude (theta/v is
  noise above some 9 Hz at 0.1 V), so uniform weights would let noise pass
  for modes. :func:`with_roughness_noise` estimates it from the residual
  against the baseline fitted with uniform weights: the difference of
  nearby points cancels a smooth misfit and keeps the noise,
  ``var = pool(|e[k+2] - e[k]|^2) / 2`` over ``POOL`` points (two points
  apart: on a zero-padded FFT grid neighbours share part of their error and
  their difference would understate it). A narrow misfit (a few points)
  raises it locally, so this is the weakest of the three.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from samii.formats import MAG_RANGE, DataFormatError, csv_header, is_mat_file, read_frf_csv, read_mat_bode, read_timeseries_csv, stated_sample_rate
from samii.frequency_response import CHANNEL_NAMES, FrequencyResponse
from samii.identify.cost import MIN_FREQUENCIES
from samii.identify.lack_of_fit import MIN_COHERENCE, ROUGHNESS_LAG, averages_from_metadata, is_stepped_sine, noise_only, roughness_variance
from samii.measure.drift import drift_from_rests
from samii.measure.excitation import SteppedSine
from samii.measure.floor import QUANT_FUNDAMENTAL, REL_FLOOR, Floor, quantisation_step
from samii.measure.frf import CHANNEL_PAIRS
from samii.measure.frf_variance import POOL, pool_mean, timeseries_frf
from samii.measure.lines import remove_lines
from samii.measure.records import RecordLayout, excitation_offset, find_records
from samii.measure.stepped import estimate_stepped
from samii.timeseries import TimeSeries

__all__ = ["Measured", "from_timeseries", "from_frf", "with_roughness_noise"]

#: Averages assumed behind a coherence when a file does not say.
DEFAULT_AVERAGES = 3


@dataclass(frozen=True, eq=False)
class Measured:
    """One file's frequency response and the random error of each point.

    Attributes
    ----------
    source : str
        The file (or a label).
    frf : FrequencyResponse
        act, base and total where the data have them.
    var : mapping channel -> array or None
        Variance of the complex relative error of each point (module docstring).
    noise_source : str
        Where ``var`` came from.
    corr_length : float
        Points one independent error spans (>= 1).
    amplitude_v : float or None
        Peak excitation [V] (the file's ``amplitude_v``, or the peak of ``r``).
    sample_rate_hz : float or None
    timeseries : TimeSeries or None
    layout : RecordLayout or None
        The records a time series was cut into.
    model_var : mapping channel -> array, or None
        Variance the model's own approximation adds to each point, beside the noise: the fit weighs
        the point by ``var + model_var``, the error reported is against ``var`` alone (set by
        :func:`samii.diagnose.nonlinear.distortion_var`: the distortion measured, and
        :func:`samii.diagnose.nonlinear.linearised`: a describing function's neglected harmonics).
    floor : samii.measure.floor.Floor or None
        The systematic floor already added to ``var`` (what repeats in every record: the estimator's bias,
        quantisation, a stated relative floor; :mod:`samii.measure.floor`), None before it is added.
    """

    source: str
    frf: FrequencyResponse
    var: Mapping[str, np.ndarray | None]
    noise_source: str
    corr_length: float = 1.0
    amplitude_v: float | None = None
    sample_rate_hz: float | None = None
    timeseries: TimeSeries | None = None
    layout: RecordLayout | None = None
    model_var: Mapping[str, np.ndarray] | None = None
    floor: Floor | None = None
    #: The band [Hz] a time series' FRF was estimated over (its grid is made from it).
    band_hz: tuple[float, float] | None = None
    #: What the reader should know before trusting the estimate (a sweep beyond the sampling's Nyquist frequency, a
    #: record cut short and left out...).
    warnings: tuple[str, ...] = ()
    #: Those of ``warnings`` that say the estimate is aliased (aliasing_warnings): a cause of a refusal, and the figure's.
    aliasing: tuple[str, ...] = ()


def _float_meta(meta: Mapping[str, str], key: str) -> float | None:
    text = meta.get(key)
    if text is None:
        return None
    m = re.match(r"\s*([-+0-9.eE]+)", str(text))
    try:
        value = float(m.group(1)) if m else float("nan")
    except ValueError:
        return None
    return value if np.isfinite(value) else None


#: Slowest sampling a time series is analysed at [samples/s]: SAMII's base modes reach 25 Hz and the sweep 40 Hz; a
#: file whose t is in milliseconds reads as 1 sample per second.
MIN_SAMPLE_RATE_HZ = 10.0
#: The default band of a time series ends at this fraction of its sample rate, short of the Nyquist frequency (0.5 x).
BAND_TOP_OF_RATE = 0.45


def _without_mains(ts: TimeSeries) -> tuple[TimeSeries, list[str]]:
    """``ts`` with the mains lines of v, theta and accel subtracted (:mod:`samii.measure.lines`: leaking through the
    records' rectangular window they repeat in every record that lasts whole mains periods), and what was removed."""

    fs = ts.sample_rate_hz
    cols, said = {}, []
    for name, unit in (("v", "V"), ("theta", "rad"), ("accel", "m/s²")):
        x = getattr(ts, name)
        if quantisation_step(x) is not None:
            continue  # (rounded after any hum it picked up: its lattice is kept for the floor)
        y, lines = remove_lines(x, fs, excitation=ts.r)
        if lines:
            cols[name] = y
            said.append(
                f"{name}: "
                + ", ".join(
                    f"{ln.freq_hz:.2f} Hz ({ln.amplitude:.3g} {unit})" + ("" if ln.removed else ", NOT removed: it drifts beyond one sinusoid")
                    for ln in lines
                )
            )
    return (replace(ts, **cols) if cols else ts), said


#: A drift is subtracted (and said) when doing so moves some point of the FRF by at least this many of its standard
#: errors: one changes what the residual tests could read there; below it the data are left exactly as recorded.
DRIFT_STANDARD_ERRORS = 1.0
#: ... or when it raises the records' spread (the noise the tests weigh by) this many times in variance somewhere (a
#: doubled standard error): a sign-alternating sweep's weights (1/4, -1/2, 1/4) cancel a drift the same in every
#: record from the estimate, not from each record's deviation from it.
DRIFT_SPREAD_FACTOR = 4.0
#: Longest stretch of a record's closing rest whose mean is read as the drift's level there [s].
DRIFT_REST_S = 2.0


def _drift_effect(frf: FrequencyResponse, var, frf2: FrequencyResponse, var2) -> list[str]:
    """What a subtraction that turned (``frf``, ``var``) into (``frf2``, ``var2``) did, where it matters (none: []): a point moved
    by :data:`DRIFT_STANDARD_ERRORS` of the new estimate, a spread that fell :data:`DRIFT_SPREAD_FACTOR`-fold, each
    with the relative floor (samii.measure.floor.REL_FLOOR) added to the variances (noise-free data's rests differ
    by the sweep's last ringing, and a zero spread made any change count)."""

    moved, spread = [], []
    for ch in CHANNEL_PAIRS:
        h0, h1, v0, v1 = getattr(frf, ch), getattr(frf2, ch), var.get(ch), var2.get(ch)
        if h0 is None or h1 is None or v0 is None or v1 is None:
            continue
        # (with the stated floor, which the diagnosis adds: on noise-free data a change under it is none)
        v0, v1 = v0 + REL_FLOOR**2, v1 + REL_FLOOR**2
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.abs(h1 / h0 - 1.0) / np.sqrt(v1)
            g = v0 / v1
        z[~np.isfinite(z)] = 0.0
        g[~np.isfinite(g)] = 1.0
        i, j = int(np.argmax(z)), int(np.argmax(g))
        if z[i] >= DRIFT_STANDARD_ERRORS:
            moved.append((float(z[i]), f"moved {CHANNEL_NAMES[ch]} by up to {z[i]:.3g} standard errors (at {frf.freq_hz[i]:.3g} Hz)"))
        if g[j] >= DRIFT_SPREAD_FACTOR:
            spread.append(
                (float(g[j]), f"raised the records' spread of {CHANNEL_NAMES[ch]} {g[j]:.3g}-fold in variance (at {frf.freq_hz[j]:.3g} Hz)")
            )
    return ([max(moved)[1]] if moved else []) + ([max(spread)[1]] if spread else [])


def _without_drift(
    ts: TimeSeries, layout: RecordLayout, frf: FrequencyResponse, var: Mapping[str, np.ndarray | None], *, band_hz: tuple[float, float], source: str
) -> tuple[TimeSeries, list[str]]:
    """``ts`` with the drift of the level it rests at subtracted (:mod:`samii.measure.drift`) from each channel where that
    matters (:func:`_drift_effect`, channel by channel against the FRF ``frf`` estimated without it, point variances
    ``var``), and what was subtracted; else ``ts`` unchanged. Only records that rest give a drift; a column on a
    lattice keeps it (as for hum)."""

    if not (layout.rest_s > 0 and layout.baseline_s > 0):
        return ts, []
    fs = ts.sample_rate_hz
    n = int(np.floor(layout.record_s * fs))
    starts = np.round((layout.start_s + np.arange(layout.n_records) * layout.record_s) * fs).astype(int)
    # the first record's operating point and the last part of every record's closing rest (at most DRIFT_REST_S, its
    # later half: the sweep's ringing has died away there)
    tail = int(round(min(0.5 * layout.rest_s, DRIFT_REST_S) * fs))
    rests = np.array([[starts[0], starts[0] + int(round(layout.baseline_s * fs))]] + [[k + n - tail, k + n] for k in starts])
    units = {"v": "V", "theta": "rad", "accel": "m/s²"}
    centres = starts + (n - 1) / 2.0
    cols, per, did = {}, [], []
    for name in ("v", "theta", "accel"):
        x = np.asarray(getattr(ts, name), float)
        if quantisation_step(x) is not None:
            continue
        curve = drift_from_rests(x, rests)
        if curve is None:  # (its rests agree to within their noise)
            continue
        y = x - curve
        frf2, var2, _, _ = timeseries_frf(replace(ts, **{name: y}), layout, band_hz=band_hz)
        said = _drift_effect(frf, var, frf2, var2)
        if said:
            cols[name] = y
            at = np.interp(centres[[0, -1]], np.arange(x.size), curve)
            per.append(f"{name} {(at[1] - at[0]) / max(layout.n_records - 1, 1):+.3g} {units[name]} per record")
            did += [f"{name}'s drift {d}" for d in said]
    if not cols:
        return ts, []
    return replace(ts, **cols), [
        f"{source}: the level the signals rest at drifts from record to record ({', '.join(per)}; a repeated excitation "
        f"from rest to rest leaves it the same): {'; '.join(did)}; the drift read off the records' rests is subtracted "
        f"from {' and '.join(cols)} before the estimate (samii.measure.drift)"
    ]


#: A sample of r beyond this many times the excitation's 99.9th percentile (about its amplitude) is no part of it ...
SPIKE_FACTOR = 5.0
#: ... where at most this many samples are so (more are an excitation of another level, not a damaged sample).
SPIKE_MAX_SAMPLES = 10


def _check_r_spikes(ts: TimeSeries, source: str) -> None:
    """Refuse an excitation with a few samples far beyond all the others: a damaged or cut line (a last line cut
    mid-number turned r's -4.940656458e-324 into -4.940656 V, 49x the 0.1 V sweep), which moved the records found
    (two from t = 79 s instead of three from 0) and made the amplitude 4.94 V, without a word. r is the instrument
    every estimate divides by: no sample of it can be guessed."""
    r = np.asarray(ts.r, float)
    x = np.abs(r - np.median(r))
    typical = float(np.percentile(x, 99.9)) if x.size else 0.0
    if typical <= 0:
        return
    far = np.flatnonzero(x > SPIKE_FACTOR * typical)
    if 0 < far.size <= SPIKE_MAX_SAMPLES:
        at = ", ".join(f"t = {ts.t[i]:.6g} s ({r[i]:.6g} V)" for i in far[:3]) + (" ..." if far.size > 3 else "")
        last = " (the file's last line: is it cut short?)" if far[-1] == r.size - 1 else ""
        raise ValueError(
            f"{source}: column 'r' has {far.size} sample(s) more than {SPIKE_FACTOR:g} times the excitation's "
            f"amplitude ({typical:.3g} V) elsewhere: {at}{last}; a damaged line? r is the instrument every "
            "estimate divides by: mend or remove the line(s)"
        )


def from_timeseries(ts: TimeSeries, *, source: str, band_hz: tuple[float, float] | None = None, record_s: float | None = None) -> Measured:
    """A time series with its excitation ``r``: records found (or as stated), FRF and spread estimated."""
    if ts.r is None:
        raise ValueError(
            f"{source}: the time series has no column 'r' (the excitation added to the valve command); "
            "a closed-loop frequency response needs it as the instrument (DATA_FORMATS.md)"
        )
    fs = ts.sample_rate_hz
    if fs < MIN_SAMPLE_RATE_HZ:
        raise ValueError(
            f"{source}: t steps by {1.0 / fs:.6g} s, {fs:.6g} samples per second: too slow for a frequency response of "
            "this arm (its modes lie between 1.7 and 25 Hz); is t in milliseconds? t must be in seconds (DATA_FORMATS.md)"
        )
    # a channel that never moves: no response to estimate (an r without excitation is refused by find_records)
    for name, unit, what in (
        ("v", "V", "no excitation reached the valve (is the v channel connected?)"),
        ("theta", "rad", "the joint never moved (is the encoder connected?): theta/v is undefined"),
        ("accel", "m/s²", "the base never moved (is the accelerometer connected?): xdd/theta is undefined"),
    ):
        x = np.asarray(getattr(ts, name), float)
        if x.size and np.all(x == x[0]):
            raise ValueError(f"{source}: column '{name}' is {x[0]:g} {unit} at every sample: {what}; there is no frequency response to estimate")
    _check_r_spikes(ts, source)
    ts, hum = _without_mains(ts)
    stated = record_s if record_s is not None else _float_meta(ts.metadata, "record_s")
    layout = find_records(ts.r, fs, record_s=stated, where=source)
    aliasing = aliasing_warnings(ts.metadata, fs, source=source)
    said = aliasing + short_record_warnings(layout, ts.t.size / fs, source=source) + coarse_encoder_warnings(ts.theta, source=source)
    if band_hz is None:
        lo = _float_meta(ts.metadata, "start_hz")
        hi = _float_meta(ts.metadata, "stop_hz")
        band_hz = (lo or 0.1, min(hi or 40.0, BAND_TOP_OF_RATE * fs))
    elif not 0.0 < band_hz[0] < band_hz[1] < fs / 2:
        raise ValueError(
            f"{source}: --band-hz {band_hz[0]:g} {band_hz[1]:g}: expected 0 < LO < HI < {fs / 2:g} Hz, the Nyquist "
            f"frequency of its {fs:g} samples per second"
        )
    frf, var, corr, how = timeseries_frf(ts, layout, band_hz=band_hz)
    ts, drift = _without_drift(ts, layout, frf, var, band_hz=band_hz, source=source)
    if drift:
        frf, var, corr, how = timeseries_frf(ts, layout, band_hz=band_hz)
        said += drift
    _check_scale(frf, ts, source)
    check_testable(frf, source=source)
    if hum:
        how += "; mains hum subtracted first (" + "; ".join(hum) + ")"
    amp = _float_meta(ts.metadata, "amplitude_v") or float(np.max(np.abs(ts.r - excitation_offset(ts.r))))  # (an offset is none of it)
    # what a diagnosis of the FRF file alone needs: the sampling (a delay of one sample is expected), the
    # excitation's amplitude, and how many neighbouring points share one error on this grid
    meta = dict(frf.metadata)
    meta.setdefault("sample_rate_hz", f"{fs:.10g}")
    meta.setdefault("amplitude_v", f"{amp:.6g}")
    meta["frf_corr_length"] = f"{corr:.3g} (points one independent error spans, from the record-to-record deviations)"
    frf = replace(frf, metadata=meta)
    return Measured(
        source=source,
        frf=frf,
        var=var,
        noise_source=how,
        corr_length=corr,
        amplitude_v=amp,
        sample_rate_hz=fs,
        timeseries=ts,
        layout=layout,
        band_hz=(float(band_hz[0]), float(band_hz[1])),
        warnings=tuple(said),
        aliasing=tuple(aliasing),
    )


def _check_scale(frf: FrequencyResponse, ts: TimeSeries, source: str) -> None:
    """Refuse a response no FRF file can hold (samii.formats.MAG_RANGE; its own readers would refuse what frf wrote):
    a sample far out of scale, which the time series' reader accepts (up to 1e100), names its column and time."""

    lo, hi = MAG_RANGE
    for ch in frf.channels:
        mag = np.abs(frf.response(ch))
        bad = np.flatnonzero(~np.isfinite(mag) | (mag < lo) | (mag > hi))
        if bad.size:
            k = int(bad[np.argmax(np.abs(np.log10(np.maximum(mag[bad], 1e-300))))])
            worst = max(
                ("v", "theta", "accel"), key=lambda c: float(np.max(np.abs(getattr(ts, c)))) / max(float(np.median(np.abs(getattr(ts, c)))), 1e-300)
            )
            x = np.abs(getattr(ts, worst))
            i = int(np.argmax(x))
            raise ValueError(
                f"{source}: the estimated {ch} ({CHANNEL_NAMES.get(ch, ch)}) magnitude is {mag[k]:.3g} at {frf.freq_hz[k]:.4g} Hz, outside "
                f"{lo:g}...{hi:g}, what a frequency response file holds; a sample far out of scale? (column "
                f"'{worst}' reaches {getattr(ts, worst)[i]:.3g} at t = {ts.t[i]:.6g} s, {x[i] / max(float(np.median(x)), 1e-300):.3g} "
                "times its median)"
            )


#: theta swinging fewer of its encoder's counts than this (amplitude, counts) is said: a sine of amplitude A rounded to q
#: is off at its own frequency by up to 0.53 (q/A)^1.5 (samii.measure.floor), 4.7 % at 5 counts, 53 % at one.
COARSE_COUNTS = 5.0


def coarse_encoder_warnings(theta: np.ndarray, *, source: str) -> list[str]:
    """theta on a lattice (an encoder's count) that it barely leaves: its FRF is the rounding's, and the coherence does
    not show it (the rounding follows the excitation). `samii frf` wrote theta/v 30-45 dB low with coherence 0.96 from
    a 10-bit encoder (theta on -1, 0, +1 counts) and said nothing; diagnose refused every theta point, rightly."""

    q = quantisation_step(theta)
    if q is None:
        return []
    lo, hi = np.percentile(theta, [0.1, 99.9])
    amp = 0.5 * float(hi - lo) / q
    if amp >= COARSE_COUNTS:
        return []
    worst = QUANT_FUNDAMENTAL * max(amp, 0.25) ** -1.5
    return [
        f"{source}: theta lies on a lattice of step {q:.3g} rad (an encoder's count) and swings only {amp:.2g} count(s) either "
        f"way: its rounding can be off by up to {min(100 * worst, 100):.0f} % of theta at the sweep's own frequency, so theta/v "
        "and xdd/theta are the rounding's, whatever their coherence says (it follows the excitation); excite more "
        "(a larger amplitude) or read a finer encoder"
    ]


#: The part of a record after the last whole one that is said, as a fraction of a record.
SHORT_RECORD_FRACTION = 0.5


def short_record_warnings(layout, duration_s: float, *, source: str) -> list[str]:
    """A record cut short at the file's end is left out (the records are averaged whole): said when more than half of
    one is there. A file that stopped 5 ms into the last record's 20 s rest lost a third of its data without a word
    (and the noise estimate one of its 3 records)."""
    tail = duration_s - (layout.start_s + layout.n_records * layout.record_s)
    if tail <= SHORT_RECORD_FRACTION * layout.record_s:
        return []
    return [
        f"{source}: the file ends {layout.record_s - tail:.3g} s short of one more record of {layout.record_s:.6g} s "
        f"({100 * tail / layout.record_s:.0f} % of it is there, from t = {layout.start_s + layout.n_records * layout.record_s:.6g} s): "
        f"that part is left out, {layout.n_records} whole record(s) are used; a file that ends after its last rest keeps them all"
    ]


def aliasing_warnings(meta: Mapping[str, str], fs: float, *, source: str) -> list[str]:
    """What the header says about aliasing at ``fs`` samples per second: a sweep (``stop_hz``) or a stated anti-alias
    filter (``antialias``: its first "N Hz") beyond the Nyquist frequency ``fs/2``. Sampled, a component at f above
    fs/2 is indistinguishable from one at |f - k fs| in the band: both r and the responses fold, and the estimate at a
    frequency mixes the response there with the response at its images."""
    nyquist = fs / 2
    out = []
    stop = _float_meta(meta, "stop_hz")
    if stop is not None and stop > nyquist:
        out.append(
            f"{source}: the sweep reached {stop:g} Hz (stop_hz) but {fs:g} samples per second resolve only up to the "
            f"Nyquist frequency {nyquist:g} Hz: the sweep's part above it folds into the band (the estimate mixes the "
            f"response at each frequency with the response at its images); sample at least {stop / BAND_TOP_OF_RATE:.3g} "
            f"times per second (a band ends at {BAND_TOP_OF_RATE:g} x the rate), or sweep below {BAND_TOP_OF_RATE * fs:g} Hz"
        )
    aa = re.search(r"([0-9.]+(?:[eE][-+]?[0-9]+)?)\s*(k?)hz", str(meta.get("antialias", "")), re.IGNORECASE)
    try:
        corner = float(aa.group(1)) * (1e3 if aa.group(2) else 1.0) if aa else None
    except ValueError:
        corner = None
    if corner is not None and corner > nyquist:
        out.append(
            f"{source}: the stated anti-alias filter ({corner:g} Hz, antialias) is above the Nyquist frequency {nyquist:g} Hz "
            f"of {fs:g} samples per second: what the sensors saw between {nyquist:g} and {corner:g} Hz is aliased into the band"
        )
    return out


def _weights_squared(meta: Mapping[str, str], n: int) -> tuple[float, str]:
    """sum w_k^2 of the records' weights: from the file's ``frf_record_weights`` line ("..., weights 0.25, 0.5,
    0.25: ...", what ``samii frf`` writes), else equal weights 1/n."""
    m = re.search(r"weights\s+([0-9.eE+-]+(?:\s*,\s*[0-9.eE+-]+)+)", str(meta.get("frf_record_weights", "")))
    if m:
        try:
            w = np.array([float(x) for x in m.group(1).split(",")])
        except ValueError:
            w = None
        if w is not None and w.size == n and np.all(w > 0) and abs(w.sum() - 1.0) < 1e-3:
            return float(np.sum(w**2)), f"records weighted {', '.join(f'{x:.4g}' for x in w)}"
    return 1.0 / n, "equal weights"


def check_testable(frf: FrequencyResponse, *, source: str) -> None:
    """Refuse data a diagnosis could test nothing on: fewer frequencies than a fit takes, or coherence below
    the lack-of-fit test's floor at every point of every channel (the data are noise: without this, every
    point's error is so large that any baseline would be said to explain them)."""

    n = frf.freq_hz.size
    if n < MIN_FREQUENCIES:
        raise ValueError(
            f"{source}: {n} frequency point(s) (after --band-hz, if given); a diagnosis fits the data's frequency "
            f"response and needs at least {MIN_FREQUENCIES}"
        )
    channels = [ch for ch in frf.channels if frf.coherence(ch) is not None]
    best = noise_only(frf, channels) if channels else None
    if best is not None:
        raise ValueError(
            f"{source}: no point has coherence >= {MIN_COHERENCE:g} in any channel (the highest is {best:.3g}): "
            "the data are noise (was the rig excited? are the sensors connected?); nothing could be tested"
        )


def _averaged_var(frf: FrequencyResponse, meta: Mapping[str, str]) -> tuple[dict, list[str], str]:
    """Each point's variance from a coherence averaged over records (Bendat & Piersol), the channels that have one,
    and how (the text after "coherence of ...")."""
    n = averages_from_metadata(meta)
    if n is None:
        n = DEFAULT_AVERAGES
        averages = f"{DEFAULT_AVERAGES} averages assumed (the file does not say; the rig's, notebook ch. 9)"
    else:
        averages = f"{int(n)} averages (the file's metadata)"
    sw2, weighting = _weights_squared(meta, int(n))
    averages += f", {weighting}"
    var, have = {}, []
    for ch in frf.channels:
        coh = frf.coherence(ch)
        if coh is None or n < 2:  # (one average: the coherence is 1 whatever the noise)
            var[ch] = None
            continue
        g = np.clip(coh, 1e-6, 1.0 - 1e-12)
        # Bendat & Piersol: 2 eps^2 = (1 - g)/(n g) with the true coherence. The estimate is biased high, E(1 - g_est) =
        # (1 - g)(1 - sum w^2), and the averaged estimate's error is sum w^2 (1 - g)/g: so var = sum w^2/(1 - sum w^2)
        # (1 - g_est)/g_est, 1/(n - 1) for equal weights (Monte Carlo, the 3 records of a sign-alternating sweep
        # weighted 1/4, 1/2, 1/4: (1 - g)/(n g) stated 1.6-1.85x short of the error). Pooled as the spread is: a
        # coherence from a few averages scatters widely (pure noise from 3 averages gives g > 0.57 one time in 5) and
        # alone would give noise-dominated points a small error; its neighbours' mean of (1 - g)/g does not.
        var[ch] = np.maximum(pool_mean((1.0 - g) / g) * sw2 / (1.0 - sw2), 1e-30)
        have.append(ch)
    return var, have, f" ({averages}), pooled over {POOL} neighbouring points"


def _stepped_var(frf: FrequencyResponse) -> tuple[dict, list[str], str]:
    """A stepped sine's: each point's error from its own coherence, which for a dwell is no estimate from a few
    averages but its sine fit's residual over thousands of samples, ``g = |Y|^2/(|Y|^2 + 4 s^2/N)``
    (:mod:`samii.measure.stepped`): ``(1 - g)/g`` is the relative error's variance of the amplitude ``E|dY|^2/|Y|^2``,
    a channel's coherence the product of its two signals', so its ``(1 - g)/g`` is about the sum of theirs. Not
    pooled: the dwells lie far apart in frequency. (Read as 3 averages it was halved, and pooled over nine dwells
    spanning the band.)"""
    var, have = {}, []
    for ch in frf.channels:
        coh = frf.coherence(ch)
        if coh is None:
            var[ch] = None
            continue
        g = np.clip(coh, 1e-6, 1.0 - 1e-12)
        var[ch] = np.maximum((1.0 - g) / g, 1e-30)
        have.append(ch)
    return var, have, " (each dwell's sine fit: its residual over the window's samples)"


def from_frf(frf: FrequencyResponse, *, source: str) -> Measured:
    """An FRF file: the error of each point from its coherence, if it has one (a stepped sine's read as its own)."""
    check_testable(frf, source=source)
    meta = frf.metadata
    var, have, what = _stepped_var(frf) if is_stepped_sine(meta) else _averaged_var(frf, meta)
    how = f"coherence of {', '.join(have)}{what}" if have else "unknown (no coherence in the file)"
    if have and len(have) < len(frf.channels):  # one noise model for the whole file: a half-known one would mix real and placeholder weights
        var = dict.fromkeys(frf.channels)
        how = f"unknown (coherence for {', '.join(have)} only)"

    sr = stated_sample_rate(meta.get("sample_rate_hz"))  # (as the reader reads it: "1 kHz" is no rate of 1 per second)
    amp = _float_meta(meta, "amplitude_v")
    corr = _float_meta(meta, "frf_corr_length")
    corr = corr if corr is not None and 1.0 <= corr <= 20.0 else 1.0
    # (an FRF file keeps its time series' header, as samii frf and samii measure write it: the aliasing is still known)
    sr = sr if sr is not None and 0 < sr < np.inf else None
    said = aliasing_warnings(meta, sr, source=source) if sr is not None else []
    return Measured(
        source=source,
        frf=frf,
        var=var,
        noise_source=how,
        corr_length=corr,
        amplitude_v=amp,
        sample_rate_hz=sr,
        warnings=tuple(said),
        aliasing=tuple(said),
    )


def from_stepped(ts: TimeSeries, *, source: str, band_hz: tuple[float, float] | None = None) -> Measured:
    """A stepped-sine time series (samii measure --method stepped, or any file whose header states the same schedule):
    each dwell's measurement window estimated as ``samii measure`` does (:func:`samii.measure.stepped.estimate_stepped`),
    then read as an FRF file is (:func:`from_frf`). The windows are where the header's schedule puts them, counted
    from the file's first sample."""

    try:
        sched = SteppedSine.from_metadata(ts.metadata)
    except KeyError as exc:
        raise ValueError(
            f"{source}: the header says the excitation is a stepped sine but has no '# {exc.args[0]}:' line; the "
            "dwells' schedule (freqs_hz, amplitude_v, settle_s, ramp_s, measure_cycles, measure_s, lead_s, as samii "
            "measure writes them) places each dwell's measurement window"
        ) from None
    except ValueError as exc:
        raise ValueError(f"{source}: the header's stepped-sine schedule: {exc}") from None
    windows = sched.windows_s + float(ts.t[0])
    end = float(ts.t[-1]) + 1.0 / ts.sample_rate_hz
    missing = [f"{f:g} Hz ({a:.6g}-{b:.6g} s)" for f, (a, b) in zip(sched.freqs_hz, windows) if b > end + 1e-9]
    if missing:
        raise ValueError(
            f"{source}: the file ends at t = {end:.6g} s, before the measurement window of the dwell(s) at "
            f"{', '.join(missing)} that its header's stepped-sine schedule lists: is it cut short, or its schedule "
            "another file's?"
        )
    frf = estimate_stepped(ts, freqs_hz=sched.freqs_hz, windows_s=windows)
    if band_hz is not None:
        frf = frf.band(*band_hz)
    m = from_frf(frf, source=source)
    aliasing = aliasing_warnings(ts.metadata, ts.sample_rate_hz, source=source)
    said = aliasing + coarse_encoder_warnings(ts.theta, source=source)
    return replace(
        m,
        sample_rate_hz=ts.sample_rate_hz,
        warnings=tuple(said),
        aliasing=tuple(aliasing),
        noise_source=f"stepped sine of {len(sched.freqs_hz)} dwells: " + m.noise_source,
    )


def load(
    path,
    *,
    band_hz: tuple[float, float] | None = None,
    record_s: float | None = None,
    mat_freq_name: str | None = None,
    mat_freq_unit: str = "hz",
    name: str | None = None,
) -> Measured:
    """Read a time-series CSV, an FRF CSV or a rig-era .mat file (chosen by content) as :class:`Measured`, its
    ``source`` ``name`` (default: the path as given)."""

    path = Path(path)
    source = str(path) if name is None else name
    if is_mat_file(path):
        return from_frf(read_mat_bode(path, freq_name=mat_freq_name, freq_unit=mat_freq_unit), source=source)
    header = csv_header(path)
    if "t" in header and "freq_hz" not in header:
        ts = read_timeseries_csv(path)
        try:
            if is_stepped_sine(ts.metadata):
                return from_stepped(ts, source=source, band_hz=band_hz)
            return from_timeseries(ts, source=source, band_hz=band_hz, record_s=record_s)
        except ValueError as exc:
            text = str(exc)
            raise DataFormatError(path, text[len(source) + 2 :] if text.startswith(source + ": ") else text) from None
    frf = read_frf_csv(path)
    if band_hz is not None:
        frf = frf.band(*band_hz)
    return from_frf(frf, source=source)


def with_roughness_noise(m: Measured, model: Mapping[str, np.ndarray]) -> Measured:
    """``m`` with the variance of every point estimated from the roughness of its residual against ``model``
    (channel -> complex response on ``m.frf.freq_hz``), for a file that says nothing of its noise (module docstring)."""
    var = {}
    for ch in m.frf.channels:
        if ch not in model:
            var[ch] = None
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            e = np.log(m.frf.response(ch) / model[ch])
        e = np.nan_to_num(e, nan=0.0, posinf=0.0, neginf=0.0)
        var[ch] = np.maximum(roughness_variance(e, ROUGHNESS_LAG, POOL), 1e-30)
    how = (
        f"estimated from the roughness of the residual against the baseline (differences of points {ROUGHNESS_LAG} apart, pooled over "
        f"{POOL}): "
        "the file gives no coherence and no records"
    )
    return replace(m, var=var, noise_source=how)


#: theta/v's phase is checked below this frequency [Hz], well below the actuator's resonance (8.8 Hz in eq 9.4),
#: where a valve-controlled actuator is an integrator: -90 deg, between -180 and 0 with a leak either way.
SIGN_CHECK_HZ = 1.0
#: Data that begin at or above SIGN_CHECK_HZ are checked over their lowest octave, if it ends below this [Hz]: still
#: under half the actuator's resonance (8.8 Hz in eq 9.4), where its lag adds less than 30 deg to the integrator's
#: -90 (a flipped file that began at 1 Hz, +79 deg there, was diagnosed: "pole_zero at 1e4 Hz", a leak of -5.8 1/s).
SIGN_CHECK_MAX_HZ = 2.5
#: A phase within this of +90 deg there is theta/v with its sign flipped [deg] (a valid one lies in -180...0).
SIGN_MARGIN_DEG = 60.0


def check_actuator_sign(m: Measured) -> None:
    """Refuse data whose theta/v is an integrator of the wrong sign: below ``SIGN_CHECK_HZ`` a valve-controlled
    actuator's theta/v is 1/s (-90 deg), or 1/(s - a) with a leak (between -180 and 0 deg, whichever the sign of a).
    A phase near +90 deg there says theta (or v) is recorded with the opposite sign, and every model would be fitted
    upside down (the notebook's gains on their bounds, "modes" at 0.1 Hz; the simulator calibrated to it diverges)."""
    if "act" not in m.frf.channels:
        return
    f = m.frf.freq_hz
    h = m.frf.response("act")
    ok = np.isfinite(h) & (np.abs(h) > 0)
    var = m.var.get("act") if m.var else None
    if var is not None:
        ok &= np.asarray(var) < 0.1  # (Measured's noise-only points are left out)
    if not ok.any():
        return
    top = max(SIGN_CHECK_HZ, min(2.0 * float(f[ok].min()), SIGN_CHECK_MAX_HZ))  # (below 1 Hz, else the lowest octave)
    use = ok & (f < top)
    if use.sum() < 5:
        return
    u = h[use] / np.abs(h[use])
    phase = float(np.degrees(np.angle(np.sum(u))))
    if abs(phase - 90.0) < SIGN_MARGIN_DEG:
        raise ValueError(
            f"{m.source}: theta/v's phase below {top:.3g} Hz is {phase:+.0f} deg over {int(use.sum())} points, where "
            "a valve-controlled actuator integrates (-90 deg; -180...0 with a leak): theta or v is recorded with the "
            "opposite sign (multiply that column by -1)"
        )
