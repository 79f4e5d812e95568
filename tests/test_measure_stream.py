"""Streaming acquisition: the record does not depend on how the run is cut into chunks.

``samii measure`` simulates in chunks and has the DAQ sample and write each
chunk while the next is stepped; these tests hold that path to the one-shot
one (``simulate`` then ``acquire`` then ``write_timeseries_csv``) exactly, and
check that a failed run leaves no file behind.
"""

import numpy as np
import pytest

from samii.formats import TimeSeriesCsvWriter, read_timeseries_csv, write_timeseries_csv
from samii.measure.daq import Daq, SensorNoise, acquire
from samii.timeseries import TimeSeries

PHYS_HZ = 4000.0
COLUMNS = ("v", "theta", "accel", "r", "p_load", "spool")


def _physics(seconds=3.0):
    t = np.arange(int(seconds * PHYS_HZ)) / PHYS_HZ
    x = 0.3 + np.sin(2 * np.pi * 7.0 * t) + 0.2 * np.sin(2 * np.pi * 900.0 * t)
    return TimeSeries(t=t, v=x, theta=0.01 * x, accel=-x, r=x, p_load=1e6 * x, spool=0.1 * np.tanh(x))


@pytest.mark.parametrize("noise", [None, SensorNoise()])
@pytest.mark.parametrize("cuts", [(1,), (5, 999, 1001), (4000, 4001, 7777)])
def test_chunked_daq_equals_one_shot(noise, cuts):
    phys = _physics()
    whole = acquire(phys, sample_rate_hz=1000.0, noise=noise, rng=np.random.default_rng(3))
    daq = Daq(PHYS_HZ, sample_rate_hz=1000.0, noise=noise, rng=np.random.default_rng(3))
    cols = phys.columns()
    del cols["t"]
    edges = [0, *cuts, len(phys)]
    parts = [daq.process(phys.t[0], {k: v[a:b] for k, v in cols.items()}) for a, b in zip(edges[:-1], edges[1:])]
    t = np.concatenate([p[0] for p in parts])
    np.testing.assert_array_equal(t, whole.t)
    for name in cols:
        # sosfilt over pieces with carried state equals one pass up to rounding
        np.testing.assert_allclose(np.concatenate([p[1][name] for p in parts]), getattr(whole, name), rtol=0, atol=1e-12 * 1e6)


def test_streamed_csv_is_the_one_shot_file(tmp_path):
    ts = acquire(_physics(), sample_rate_hz=1000.0)
    one = write_timeseries_csv(ts, tmp_path / "one.csv")
    cols = {k: getattr(ts, k) for k in COLUMNS}
    with TimeSeriesCsvWriter(tmp_path / "two.csv", COLUMNS, ts.metadata) as w:
        for a, b in [(0, 1), (1, 1234), (1234, len(ts))]:
            w.write(ts.t[a:b], {k: v[a:b] for k, v in cols.items()})
    assert (tmp_path / "two.csv").read_bytes() == one.read_bytes()
    back = read_timeseries_csv(tmp_path / "two.csv")
    np.testing.assert_allclose(back.accel, ts.accel, rtol=1e-9)  # 10 significant digits written


def test_a_failed_stream_leaves_nothing_and_refuses_garbage(tmp_path):
    path = tmp_path / "ts.csv"
    t = np.arange(10) / 1000.0
    good = {"v": np.zeros(10), "theta": np.zeros(10), "accel": np.zeros(10)}
    with pytest.raises(RuntimeError, match="diverged"):
        with TimeSeriesCsvWriter(path, ["v", "theta", "accel"], {}) as w:
            w.write(t, good)
            raise RuntimeError("simulation diverged")
    assert list(tmp_path.iterdir()) == []  # no partial file, no temporary left over

    w = TimeSeriesCsvWriter(path, ["v", "theta", "accel"], {})
    with pytest.raises(ValueError, match=r"non-finite value in column 'accel'"):
        w.write(t, {**good, "accel": np.r_[np.zeros(9), np.nan]})
    with pytest.raises(ValueError, match="time must increase"):
        w.write(t[::-1].copy(), good)
    w.abort()
    assert list(tmp_path.iterdir()) == []

    path.write_text("precious")
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        TimeSeriesCsvWriter(path, ["v", "theta", "accel"], {})
    assert path.read_text() == "precious"
    with pytest.raises(ValueError, match="v, theta, accel"):
        TimeSeriesCsvWriter(tmp_path / "x.csv", ["v", "theta"], {})


def test_empty_chunk_and_zero_noise_levels():
    phys = _physics(1.0)
    cols = phys.columns()
    del cols["t"]
    daq = Daq(PHYS_HZ, sample_rate_hz=1000.0)
    t, out = daq.process(0.0, {k: v[:0] for k, v in cols.items()})
    assert t.size == 0 and all(v.size == 0 for v in out.values())
    # a channel's noise does not depend on another channel's level (one stream per channel)
    a = acquire(phys, sample_rate_hz=1000.0, noise=SensorNoise(), rng=np.random.default_rng(5))
    b = acquire(phys, sample_rate_hz=1000.0, noise=SensorNoise(v_v=0.0), rng=np.random.default_rng(5))
    np.testing.assert_array_equal(a.accel, b.accel)
    assert not np.array_equal(a.v, b.v)
