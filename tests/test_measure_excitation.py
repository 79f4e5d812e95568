"""Swept- and stepped-sine excitation: the sweep law, the envelope, the schedule."""

import numpy as np
import pytest

from samii.measure.excitation import SteppedSine, SweptSine

FS = 4000.0  # evaluation rate for the checks [Hz]: 100 samples per period at 40 Hz


def _one_record(sw: SweptSine):
    t = np.arange(int(sw.record_s * FS)) / FS
    return t, sw.signal(t)


def test_default_campaign_length_and_band():
    sw = SweptSine()
    # derivation in the module docstring: C = 3/ln2, L = 4/ln2, corner 0.75 Hz;
    # C (1/0.1 - 1/0.75) + L ln(40/0.75) = 37.51 + 22.95 s
    assert sw.corner_hz == pytest.approx(0.75)
    assert sw.sweep_s == pytest.approx(37.510 + 22.948, abs=1e-2)
    assert sw.record_s == pytest.approx(sw.lead_s + 2.5 + sw.sweep_s + 0.25 + sw.tail_s)
    assert sw.duration_s == pytest.approx(3 * sw.record_s)
    assert sw.duration_s < 6 * 60.0  # "simulated duration up to a few minutes"
    f = sw.frequency_hz(np.arange(0, sw.record_s, 1e-3))
    assert np.nanmin(f) == pytest.approx(0.1) and np.nanmax(f) == pytest.approx(40.0)


@pytest.mark.parametrize("direction", ["up", "down"])
def test_phase_is_the_integral_of_the_frequency(direction):
    # r = A env sin(2 pi cycles(t)): it crosses zero twice per cycle, so between any two
    # times the zero crossings count 2 * integral of the instantaneous frequency (+-1)
    sw = SweptSine(direction=direction)
    t, r = _one_record(sw)
    f = np.nan_to_num(sw.frequency_hz(t))
    crossings = np.flatnonzero(np.sign(r[1:]) * np.sign(r[:-1]) < 0)
    edges = sw.lead_s + np.linspace(0.5, sw.active_s - 0.5, 12)
    for a, b in zip(edges[:-1], edges[1:]):
        inside = (t >= a) & (t < b)
        expected = 2 * np.trapezoid(f[inside], t[inside])
        counted = np.count_nonzero((t[crossings] >= a) & (t[crossings] < b))
        assert abs(counted - expected) <= 1.0, (a, b, counted, expected)


def test_every_octave_gets_enough_cycles_and_time():
    sw = SweptSine(direction="up")
    octaves = [(0.1, 0.2), (0.2, 0.4), (0.4, 0.8), (1.25, 2.5), (5, 10), (20, 40)]
    tau = np.linspace(0, sw.sweep_s, 2_000_001)
    f = sw._up_frequency_hz(tau + sw.fade_low_s)
    for lo, hi in octaves:
        inside = (f >= lo) & (f < hi)
        duration = np.count_nonzero(inside) * (tau[1] - tau[0])
        cycles = np.sum(f[inside]) * (tau[1] - tau[0])
        assert cycles >= sw.cycles_per_octave * 0.999, (lo, cycles)
        assert duration >= sw.seconds_per_octave * 0.999, (lo, duration)
    # below the corner the cycle floor binds, above it the time floor
    lo_oct = (f >= 0.1) & (f < 0.2)
    assert np.sum(f[lo_oct]) * (tau[1] - tau[0]) == pytest.approx(3.0, rel=1e-3)
    hi_oct = (f >= 20) & (f < 40)
    assert np.count_nonzero(hi_oct) * (tau[1] - tau[0]) == pytest.approx(4.0, rel=1e-3)


@pytest.mark.parametrize("direction", ["up", "down"])
def test_envelope_starts_and_ends_at_rest_with_full_amplitude_in_band(direction):
    sw = SweptSine(direction=direction, amplitude_v=1.5)
    t, r = _one_record(sw)
    assert np.max(np.abs(r)) == pytest.approx(1.5, rel=1e-3)
    assert np.max(np.abs(r)) <= 1.5 + 1e-12
    rest = (t < sw.lead_s) | (t > sw.lead_s + sw.active_s)
    assert np.all(r[rest] == 0.0)
    # zero slope at the ends: 2 ms from rest the command is still < 0.1 % of A
    # (a sine starting at full slope would be at A sin(2 pi 40 Hz 2 ms) = 0.48 A)
    i0 = int(np.ceil(sw.lead_s * FS))
    i1 = int(np.floor((sw.lead_s + sw.active_s) * FS))
    assert np.max(np.abs(r[i0 : i0 + 8])) < 1e-3 * 1.5 and np.max(np.abs(r[i1 - 8 : i1 + 1])) < 1e-3 * 1.5
    # full amplitude while sweeping: every 40 Hz-ish and 0.1 Hz-ish peak reaches A
    sweeping = (t > sw.lead_s + (sw.fade_low_s if direction == "up" else sw.fade_high_s) + 1) & (
        t < sw.lead_s + sw.active_s - (sw.fade_high_s if direction == "up" else sw.fade_low_s) - 1
    )
    peaks = np.abs(r[sweeping])
    assert peaks.max() == pytest.approx(1.5, rel=1e-4)


def test_down_is_up_reversed_in_frequency():
    up, down = SweptSine(direction="up"), SweptSine(direction="down")
    t = np.linspace(0, up.record_s, 5001)
    fu, fd = up.frequency_hz(t), down.frequency_hz(2 * up.lead_s + up.active_s - t)  # u -> active_s - u
    ok = np.isfinite(fu) & np.isfinite(fd)
    np.testing.assert_allclose(fu[ok], fd[ok], rtol=1e-9)
    assert down.frequency_hz(down.lead_s + 0.01) == pytest.approx(40.0)


def test_repetitions_are_identical():
    sw = SweptSine(repetitions=3)
    t = np.arange(0, sw.record_s, 1.0 / FS)
    r0 = sw.signal(t)
    np.testing.assert_allclose(sw.signal(t + 2 * sw.record_s), r0, atol=1e-9)
    assert np.all(sw.signal(np.array([-1.0, sw.duration_s + 1])) == 0)


def test_sweptsine_validates():
    with pytest.raises(ValueError, match="stop_hz"):
        SweptSine(start_hz=10, stop_hz=5)
    with pytest.raises(ValueError, match="amplitude_v"):
        SweptSine(amplitude_v=0)
    with pytest.raises(ValueError, match="repetitions"):
        SweptSine(repetitions=0)
    with pytest.raises(ValueError, match="direction"):
        SweptSine(direction="sideways")


def test_stepped_schedule_whole_periods_and_steady_sine():
    st = SteppedSine(freqs_hz=(0.5, 3.0, 35.0), amplitude_v=1.0, settle_s=4.0, ramp_s=1.0)
    np.testing.assert_array_equal(st.n_cycles, [4, 6, 70])  # max(4 cycles, ceil(2 s * f))
    w = st.windows_s
    np.testing.assert_allclose((w[:, 1] - w[:, 0]) * np.asarray(st.freqs_hz), st.n_cycles)
    assert w[0, 0] == pytest.approx(st.lead_s + st.settle_s)
    assert np.all(w[1:, 0] > w[:-1, 1])  # windows do not overlap
    assert st.duration_s == pytest.approx(st.lead_s + np.sum(st.settle_s + w[:, 1] - w[:, 0] + st.ramp_s))
    for f, (a, b) in zip(st.freqs_hz, w):
        t = np.linspace(a, b, 2001)
        r = st.signal(t)
        start = a - st.settle_s
        np.testing.assert_allclose(r, np.sin(2 * np.pi * f * (t - start)), atol=1e-9)  # full amplitude while measuring
    assert st.signal(np.array([0.5]))[0] == 0.0  # lead-in rest
    assert st.signal(np.array([st.duration_s - 1e-6]))[0] == pytest.approx(0.0, abs=1e-6)


def test_stepped_validates():
    with pytest.raises(ValueError, match="positive"):
        SteppedSine(freqs_hz=(1.0, -2.0))
    with pytest.raises(ValueError, match="empty"):
        SteppedSine(freqs_hz=())
    with pytest.raises(ValueError, match="ramp_s"):
        SteppedSine(ramp_s=20.0, settle_s=5.0)
