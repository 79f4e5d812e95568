"""Sensor drift (samii.measure.drift, samii.measure.measured._without_drift): a level that changes from record to
record is subtracted as the line through consecutive records' means and said; a file without one is left exactly as
recorded. Checked on drawn rigs (eq 9.4's parameters spread 15 %), with sign-alternating records (the drift cancels
from the estimate and inflates the spread) and with repeats of one sign (it biases the estimate), for a linear drift
and for a warm-up that bends (an exponential)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from samii.diagnose.rig import EffectRig
from samii.measure.drift import drift_from_rests
from samii.measure.excitation import SweptSine
from samii.measure.measured import from_timeseries

FS = 1000.0


def test_the_drift_read_off_the_rests_is_a_drift_exactly_and_nothing_of_the_response():
    n, starts = 1000, np.array([100, 1100, 2100])
    k = np.arange(3100)
    response = np.zeros(k.size)
    for sign, s0 in zip((1.0, -1.0, 1.0), starts):  # a sign-alternating response between rests (its own mean nonzero)
        response[s0 + 50 : s0 + 800] = sign * (0.3 + np.sin(2 * np.pi * np.arange(750) / 75.0))
    rests = np.array([[starts[0], starts[0] + 50]] + [[s0 + n - 100, s0 + n] for s0 in starts])
    centre0 = starts[0] + 24.5
    assert drift_from_rests(response, rests) is None  # the rests agree: no drift
    noisy = response + 1e-3 * np.random.default_rng(3).standard_normal(k.size)
    assert drift_from_rests(noisy, rests) is None  # they agree to within their noise
    assert drift_from_rests(noisy + 2e-5 * k, rests) is not None  # 0.02 per record, 20x the noise of a sample
    assert np.allclose(drift_from_rests(response + 2e-3 * k, rests), 2e-3 * (k - centre0), atol=1e-9)
    cubic = 1e-10 * (k - 900.0) ** 3  # a cubic: exact through four rests (not-a-knot)
    assert np.allclose(drift_from_rests(response + cubic, rests), cubic - 1e-10 * (centre0 - 900.0) ** 3, atol=2e-3)  # (a window's mean, 0.2 %)
    assert np.allclose(drift_from_rests(response + 2e-3 * k, rests[:2]), 2e-3 * (k - centre0), atol=1e-9)  # a line through two
    assert drift_from_rests(response, rests[:1]) is None


def _rig_file(seed: int, alternate: bool):
    """A drawn rig's record with sensor noise, and the same rig's noise-free estimate (the truth the noisy one errs from)."""
    rng = np.random.default_rng(seed)
    rig = EffectRig.drawn(rng)
    sw = SweptSine(repetitions=3, amplitude_v=0.1, seconds_per_octave=4.0, alternate_sign=alternate)
    r = sw.signal(np.arange(int(round(sw.duration_s * FS))) / FS)
    return rig.simulate(r, sample_rate_hz=FS, rng=rng), from_timeseries(rig.simulate(r, sample_rate_hz=FS), source="truth.csv")


def _chi2(m, truth) -> dict[str, float]:
    """Mean squared error of each channel against the noise-free estimate, in its stated variances (1 = as stated),
    over the points the response stands above the noise (a stated relative error under 30 %: below 0.3 Hz xdd is
    noise at 0.1 V, and a ratio to a response far below the noise is no relative error)."""
    out = {}
    for ch in ("act", "base", "total"):
        ok = m.var[ch] < 0.1
        out[ch] = float(np.mean(np.abs(getattr(m.frf, ch)[ok] / getattr(truth.frf, ch)[ok] - 1.0) ** 2 / m.var[ch][ok]))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("seed, alternate", [(11, True), (12, False), (13, True)])
def test_a_drift_is_subtracted_and_said_and_a_clean_file_is_left_as_recorded(seed, alternate):
    ts, truth = _rig_file(seed, alternate)
    clean = from_timeseries(ts, source="clean.csv")
    assert not any("drift" in w for w in clean.warnings)
    # a linear drift of theta (an encoder's reference slipping) and the accelerometer warming up (0.1 m/s², 5 min)
    t = ts.t
    drifting = replace(ts, theta=ts.theta + 2e-5 * t, accel=ts.accel + 0.1 * (1.0 - np.exp(-t / 300.0)))
    m = from_timeseries(drifting, source="drift.csv")
    said = [w for w in m.warnings if "drift" in w]
    assert len(said) == 1 and said[0].startswith("drift.csv: ") and "theta +" in said[0] and "accel +" in said[0], said
    assert "read off the records' rests" in said[0]
    # what is left errs from the rig's truth as its stated noise says, as the clean file does
    before, after = _chi2(clean, truth), _chi2(m, truth)
    for ch in ("act", "base", "total"):
        assert 0.5 < before[ch] < 2.0 and 0.5 < after[ch] < 2.0, (ch, before, after)
    # without the subtraction it is not so (the drift moves or spreads the low end of the band far beyond its noise)
    import samii.measure.measured as measured

    kept = measured.DRIFT_STANDARD_ERRORS, measured.DRIFT_SPREAD_FACTOR
    try:
        measured.DRIFT_STANDARD_ERRORS = measured.DRIFT_SPREAD_FACTOR = np.inf
        raw = from_timeseries(drifting, source="drift.csv")
    finally:
        measured.DRIFT_STANDARD_ERRORS, measured.DRIFT_SPREAD_FACTOR = kept
    low = raw.frf.freq_hz < 0.3
    spread = np.max(raw.var["base"][low] / m.var["base"][low])
    biased = np.max(np.abs(raw.frf.base[low] / truth.frf.base[low] - 1.0) ** 2 / m.var["base"][low])
    assert spread > 10 or biased > 10, (spread, biased)
