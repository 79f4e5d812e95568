"""DAQ sampling: anti-alias filter, decimation, seeded sensor noise."""

import numpy as np
import pytest

from samii.measure.daq import SensorNoise, acquire
from samii.timeseries import TimeSeries

PHYS_HZ = 4000.0


def _physics(freq_hz, seconds=4.0, amplitude=1.0, offset=0.0, **extra):
    t = np.arange(int(seconds * PHYS_HZ)) / PHYS_HZ
    x = offset + amplitude * np.sin(2 * np.pi * freq_hz * t)
    return TimeSeries(t=t, v=x, theta=0.01 * x, accel=x, r=x, p_load=1e6 * x, spool=0.1 * x, extra=extra)


def _amplitude(x, t, f):
    basis = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t)])
    (a, b, _), *_ = np.linalg.lstsq(basis, x, rcond=None)
    return np.hypot(a, b)


def test_in_band_signal_passes_unchanged_and_channels_stay_aligned():
    ts = acquire(_physics(40.0), sample_rate_hz=1000.0)
    assert ts.sample_rate_hz == pytest.approx(1000.0)
    assert len(ts) == 4000 and ts.t[0] == 0.0
    late = ts.t > 1.0  # past the filter's start-up
    # 8th-order Butterworth at 250 Hz: |H(40 Hz)| = 1/sqrt(1 + (40/250)^16) = 1 - 9e-14
    assert _amplitude(ts.v[late], ts.t[late], 40.0) == pytest.approx(1.0, rel=1e-6)
    # every channel sees the same filter: ratios are exact
    np.testing.assert_allclose(ts.theta, 0.01 * ts.v, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ts.r, ts.accel, rtol=1e-12, atol=1e-15)
    assert ts.metadata["sample_rate_hz"] == "1000"
    assert "Butterworth" in ts.metadata["antialias"]


def test_content_above_nyquist_is_suppressed_not_aliased():
    # 900 Hz at a 1 kHz DAQ would alias to 100 Hz; the filter (250 Hz, order 8)
    # attenuates it by 20*8*log10(900/250) = 89 dB
    ts = acquire(_physics(900.0), sample_rate_hz=1000.0)
    late = ts.t > 1.0
    assert _amplitude(ts.v[late], ts.t[late], 100.0) < 10 ** (-80 / 20)
    naive = _physics(900.0).v[::4]  # sampling without the filter
    assert _amplitude(naive[1000:], ts.t[1000:], 100.0) > 0.99


def test_operating_point_starts_without_a_filter_transient():
    ts = acquire(_physics(5.0, amplitude=0.0, offset=3.0), sample_rate_hz=1000.0)
    np.testing.assert_allclose(ts.v, 3.0, rtol=1e-12)


def test_extra_columns_are_sampled_too():
    ts = acquire(_physics(10.0, valve_current=np.ones(16000)), sample_rate_hz=500.0)
    assert "valve_current" in ts.extra and len(ts.extra["valve_current"]) == 2000
    assert ts.p_load is not None and ts.spool is not None


def test_noise_is_seeded_with_the_stated_levels():
    phys = _physics(10.0, seconds=20.0, amplitude=0.0)
    noise = SensorNoise()
    a = acquire(phys, noise=noise, rng=np.random.default_rng(7))
    b = acquire(phys, noise=noise, rng=np.random.default_rng(7))
    c = acquire(phys, noise=noise, rng=np.random.default_rng(8))
    np.testing.assert_array_equal(a.accel, b.accel)
    assert not np.array_equal(a.accel, c.accel)
    for name, std in noise.std().items():
        assert np.std(getattr(a, name)) == pytest.approx(std, rel=0.05), name  # 20000 samples: 0.5 % sampling error of a std
    assert np.all(a.r == 0.0)  # the generator's own signal is recorded clean
    assert "theta 0.0005" in a.metadata["sensor_noise"]
    half = noise.scaled(0.5)
    assert half.theta_rad == pytest.approx(2.5e-4)


def test_bad_rates_and_missing_generator():
    phys = _physics(10.0)
    with pytest.raises(ValueError, match="integer multiple"):
        acquire(phys, sample_rate_hz=3000.0)
    with pytest.raises(ValueError, match="integer multiple"):
        acquire(phys, sample_rate_hz=8000.0)
    with pytest.raises(ValueError, match="Generator"):
        acquire(phys, noise=SensorNoise())
    with pytest.raises(ValueError, match="non-negative"):
        SensorNoise(theta_rad=-1.0)
