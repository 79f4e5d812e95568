"""Recordings a user can keep (issue 32 item 6): a swept run's recording keeps what the eye needs, not
every DAQ sample. Where the sweep is fast every sample and frame stays; where it is slow each signal keeps
its envelope (each bucket's smallest and largest sample: the peaks and the noise band's width are the
record's) and the animation the frames its motion needs (samii.viz.thinning)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from samii.cli import main
from samii.viz.thinning import BUCKETS_PER_PERIOD, MIN_BUCKET_RATE_HZ, buckets, envelope, kept

FS = 1000.0


def _log_sweep(seconds=60.0, f0=40.0, f1=0.1):
    t = np.arange(int(seconds * FS)) / FS
    f = f0 * (f1 / f0) ** (t / t[-1])
    return t, f


def test_buckets_follow_the_frequency_driven():
    t, f = _log_sweep()
    b = buckets(t, f, per_period=BUCKETS_PER_PERIOD, min_rate=MIN_BUCKET_RATE_HZ)
    start = np.concatenate([[True], np.diff(b) > 0])
    width = np.diff(np.append(np.flatnonzero(start), t.size)) / FS  # each bucket's span [s]
    first = t[start]
    # at the start (40 Hz, 12 buckets per period: 480/s) a bucket is 2-3 samples
    assert width[first < 1.0].max() <= 1 / (BUCKETS_PER_PERIOD * 40 * 0.9) + 1 / FS
    # never longer than 1/min_rate, and no longer than the frequency driven in the last RING_S asks
    assert width.max() <= 1 / MIN_BUCKET_RATE_HZ + 1 / FS
    # the sweep is below 2 Hz for the last half of its log range: there buckets are the min rate's
    assert np.median(width[first > 0.75 * t[-1]]) == pytest.approx(1 / MIN_BUCKET_RATE_HZ, abs=1 / FS)
    # ringing: 2 s after the sweep has left 10 Hz the buckets are still 10 Hz's
    at = np.searchsorted(f[::-1], 10.0)  # (f falls)
    t10 = t[::-1][at]
    near = (first > t10 + 1.0) & (first < t10 + 2.0)
    assert width[near].max() <= 1 / (BUCKETS_PER_PERIOD * 9.0) + 1 / FS


def test_envelope_is_the_records_envelope():
    rng = np.random.default_rng(3)
    t, f = _log_sweep()
    x = 0.1 * np.sin(2 * np.pi * np.cumsum(f) / FS) + 0.01 * rng.standard_normal(t.size)
    x[30000:30010] = np.nan  # a gap stays a gap
    b = buckets(t, f, per_period=BUCKETS_PER_PERIOD, min_rate=MIN_BUCKET_RATE_HZ)
    keep = envelope(x, b)
    assert keep[0] and keep[-1] and keep[30000] and keep[30009] and not keep[30001:30009].any()
    assert keep.mean() < 0.3  # far fewer samples
    # in any window of whole buckets, the kept samples' smallest and largest are the record's
    for lo in range(0, t.size - 2000, 997):
        i0 = np.flatnonzero(b == b[lo])[0]
        i1 = np.flatnonzero(b == b[lo + 1500])[-1] + 1
        w, k = x[i0:i1], keep[i0:i1]
        assert np.nanmax(w[k]) == np.nanmax(w) and np.nanmin(w[k]) == np.nanmin(w)
    frames = kept(t[::10], f[::10], per_period=8, min_rate=25.0)
    assert frames[0] and frames[-1] and frames[:50].all()  # 40 Hz: 320 frames/s asked, 100/s there


@pytest.mark.slow
def test_default_measurement_recording_is_small_and_keeps_what_is_seen(tmp_path, capsys):
    """`samii measure --noise --rerun` (the main job's measure.rrd): under 20 MB (58 MB with every sample),
    its size printed; theta read back has the record's envelope in every half second, and the animation
    keeps every frame where the sweep is fast."""
    from samii.formats import read_timeseries_csv
    from samii.viz.recording import read_scalars

    rrd = tmp_path / "m.rrd"
    assert main(["measure", "--noise", "--seed", "1", "--out", str(tmp_path / "m"), "--rerun", str(rrd), "--no-progress"]) == 0
    out = capsys.readouterr().out
    size = rrd.stat().st_size / 1e6
    assert size < 20.0, size
    assert re.search(rf"wrote {re.escape(str(rrd))} \({size:.1f} MB\)", out), out
    ts = read_timeseries_csv(tmp_path / "m" / "timeseries.csv")
    got = read_scalars(rrd, ["/swept/angle_deg/theta", "/swept/displacement_mm/tip"])
    t, th = got["/swept/angle_deg/theta"]
    assert t.size < 0.3 * ts.t.size
    full = np.degrees(ts.theta)
    for lo in np.arange(0.0, ts.t[-1] - 1.0, 7.3):
        w = (ts.t >= lo) & (ts.t < lo + 0.5)
        k = (t >= lo) & (t < lo + 0.5)
        # within one bucket of the window's edges the kept extremes may fall outside: compare the inner window
        inner = (ts.t >= lo + 0.05) & (ts.t < lo + 0.45)
        assert th[k].max() >= full[inner].max() - 1e-9 and th[k].min() <= full[inner].min() + 1e-9
        assert w.any()
    tf, _ = got["/swept/displacement_mm/tip"]
    fast = tf[(tf > 1.5) & (tf < 3.0)]  # the sweep at about 40 Hz (after its 1 s lead at rest): every frame (100/s)
    assert fast.size > 100 and np.allclose(np.diff(fast), 0.01, atol=1e-9)
    assert np.diff(tf).max() <= 1 / 25.0 + 1e-9  # and never fewer than 25 a second
