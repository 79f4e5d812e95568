"""Readers and writers of DATA_FORMATS.md: round trips, and one clear error per defect."""

import os

import numpy as np
import pytest
from scipy.io import savemat

from samii import FrequencyResponse
from samii.formats import (
    DataFormatError,
    read_frf_csv,
    read_mat_bode,
    read_timeseries_csv,
    write_frf_csv,
    write_timeseries_csv,
)
from samii.timeseries import TimeSeries

TS_HEADER = "t,v,theta,accel\n"


def _ts(n=50, rate_hz=1000.0, **extra_cols):
    t = np.arange(n) / rate_hz
    rng = np.random.default_rng(0)
    return TimeSeries(
        t=t,
        v=rng.normal(size=n),
        theta=rng.normal(size=n) * 0.01,
        accel=rng.normal(size=n),
        r=np.sin(2 * np.pi * 3 * t),
        p_load=rng.normal(size=n) * 1e6,
        extra=extra_cols,
        metadata={"sample_rate_hz": "1000", "excitation": "swept sine 0.1-40 Hz"},
    )


def _frf():
    f = np.geomspace(0.1, 40, 30)
    s = 2j * np.pi * f
    act = 28.0 / (s * (1 + s / 159.0))  # integrator with a lag: phase runs past -90 deg
    base = s**2 / (s**2 + 2 * 0.03 * 10.9 * s + 10.9**2) * -1.5
    return FrequencyResponse(f, act=act, base=base, total=act * base, act_coh=np.linspace(0.5, 1, 30), metadata={"method": "test"})


def _write(tmp_path, text, name="x.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


# ---------------------------------------------------------------- round trips


def test_timeseries_round_trip_keeps_columns_extra_and_metadata(tmp_path):
    ts = _ts(valve_current=np.linspace(0, 1, 50))
    p = write_timeseries_csv(ts, tmp_path / "ts.csv")
    back = read_timeseries_csv(p)
    for name, col in ts.columns().items():
        np.testing.assert_allclose(back.columns()[name], col, rtol=1e-9, atol=1e-300)
    assert list(back.columns()) == list(ts.columns())
    assert back.theta_ref is None and back.spool is None
    assert dict(back.metadata) == dict(ts.metadata)
    assert back.sample_rate_hz == pytest.approx(1000.0, rel=1e-12)


def test_timeseries_long_record_at_odd_rate_stays_uniform(tmp_path):
    # 1024 Hz for 200 s: t needs 13 significant digits; the writer keeps it within the 1e-6 rule
    n = 200 * 1024
    t = np.arange(n) / 1024.0 + 12345.0
    z = np.zeros(n)
    p = write_timeseries_csv(TimeSeries(t=t, v=z, theta=z, accel=z), tmp_path / "long.csv")
    back = read_timeseries_csv(p)
    np.testing.assert_allclose(back.t, t, rtol=0, atol=1e-9)


def test_frf_round_trip_and_phase_unwrapped(tmp_path):
    frf = _frf()
    p = write_frf_csv(frf, tmp_path / "frf.csv")
    back = read_frf_csv(p)
    assert back.channels == ("act", "base", "total")
    for ch in frf.channels:
        np.testing.assert_allclose(back.response(ch), frf.response(ch), rtol=1e-8)
    np.testing.assert_allclose(back.act_coh, frf.act_coh)
    assert back.base_coh is None
    assert back.metadata["method"] == "test"
    # total phase runs below -180 deg; the file holds it unwrapped
    assert frf.phase_deg("total").min() < -180
    text = p.read_text()
    assert "act_mag,act_phase_deg,act_coh" in text


def test_frf_reader_unwraps_wrapped_phase(tmp_path):
    f = [1.0, 2.0, 3.0, 4.0]
    ph = [-170.0, 175.0, 160.0, 150.0]  # wrapped: really -170, -185, -200, -210
    p = _write(tmp_path, "freq_hz,act_mag,act_phase_deg\n" + "".join(f"{a},1,{b}\n" for a, b in zip(f, ph)))
    np.testing.assert_allclose(read_frf_csv(p).phase_deg("act"), [-170, -185, -200, -210])


def test_metadata_and_plain_comments(tmp_path):
    p = _write(tmp_path, "# sample_rate_hz: 1000\n# just a note\n#excitation: a: b\n\n" + TS_HEADER + "0,0,0,0\n0.001,1,2,3\n")
    ts = read_timeseries_csv(p)
    assert dict(ts.metadata) == {"sample_rate_hz": "1000", "excitation": "a: b"}
    np.testing.assert_array_equal(ts.accel, [0, 3])


def test_column_order_is_free(tmp_path):
    p = _write(tmp_path, "accel,theta,t,v\n3,2,0,1\n6,5,0.5,4\n")
    ts = read_timeseries_csv(p)
    np.testing.assert_array_equal(ts.t, [0, 0.5])
    np.testing.assert_array_equal(ts.v, [1, 4])


def test_writer_refuses_to_overwrite_and_overwrites_atomically(tmp_path):
    p = tmp_path / "frf.csv"
    p.write_text("precious")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_frf_csv(_frf(), p)
    assert p.read_text() == "precious"
    write_frf_csv(_frf(), p, overwrite=True)
    assert read_frf_csv(p).channels == ("act", "base", "total")
    assert os.listdir(tmp_path) == ["frf.csv"]  # no temporary file left behind


def test_writer_rejects_multiline_metadata(tmp_path):
    ts = TimeSeries(t=[0, 1], v=[0, 0], theta=[0, 0], accel=[0, 0], metadata={"note": "a\nb"})
    with pytest.raises(ValueError, match="single line"):
        write_timeseries_csv(ts, tmp_path / "x.csv")
    assert not (tmp_path / "x.csv").exists()


# ---------------------------------------------------------------- bad time-series files


@pytest.mark.parametrize(
    "text, line, column, expected",
    [
        ("", None, None, "empty"),
        ("# only: metadata\n\n", None, None, "empty"),
        (TS_HEADER, 1, None, "not followed by any data row"),
        ("t,v,accel\n0,0,0\n", 1, None, "missing required column 'theta'"),
        ("t,V,theta,Accel\n0,0,0,0\n", 1, None, "'v', 'accel'"),
        (TS_HEADER + "0,0,0,0\n0.001,0,0,0\n0.0025,0,0,0\n0.003,0,0,0\n", 4, "t", "uniformly"),
        (TS_HEADER + "0,0,0,0\n0.002,0,0,0\n0.001,0,0,0\n", 3, "t", "uniformly"),
        (TS_HEADER + "0,0,0,0\n0.001,0,nan,0\n", 3, "theta", "finite"),
        (TS_HEADER + "0,0,0,0\n0.001,inf,0,0\n", 3, "v", "finite"),
        (TS_HEADER + "0,0,0,0\n0.001,0,0\n", 3, None, "expected 4 comma-separated values"),
        (TS_HEADER + "0,0,0,0\n0.001,0,0,0,7\n", 3, None, "got 5"),
        (TS_HEADER + "0,0,0,0\n0.001,0,abc,0\n", 3, "theta", "expected a number, got 'abc'"),
        (TS_HEADER + "0,0,0,0\n0.001,0,,0\n", 3, "theta", "expected a number, got ''"),
        (TS_HEADER + "0,0,0,0\n# late comment\n0.001,0,0,0\n", 3, None, "only before the header"),
        ("t,v,theta,accel,v\n0,0,0,0,0\n", 1, None, "duplicate"),
        ("t,v,,theta,accel\n0,0,0,0,0\n", 1, None, "header cell 3 is empty"),
        (TS_HEADER + "0,0,0,0\n", 2, None, "at least 2 samples"),
        ("t,v,theta,accel,spool\n0,0,0,0,0\n0.001,0,0,0,1.5\n", 3, "spool", "-1...1"),
    ],
)
def test_bad_timeseries_file_gives_one_clear_error(tmp_path, text, line, column, expected):
    p = _write(tmp_path, text, "bad.csv")
    with pytest.raises(DataFormatError, match=expected) as info:
        read_timeseries_csv(p)
    err = info.value
    assert isinstance(err, ValueError)
    assert str(p) in str(err)
    assert err.line == line
    assert err.column == column
    if line is not None:
        assert f"line {line}" in str(err)


def test_non_utf8_file(tmp_path):
    p = tmp_path / "bin.csv"
    p.write_bytes(b"t,v,theta,accel\n\xff\xfe\n")
    with pytest.raises(DataFormatError, match="UTF-8"):
        read_timeseries_csv(p)


# ---------------------------------------------------------------- bad FRF files

FRF_HEADER = "freq_hz,act_mag,act_phase_deg\n"


@pytest.mark.parametrize(
    "text, line, column, expected",
    [
        ("", None, None, "empty"),
        (FRF_HEADER, 1, None, "not followed"),
        ("act_mag,act_phase_deg\n1,0\n", 1, None, "missing required column 'freq_hz'"),
        (FRF_HEADER + "1,1,0\n2,1,0\n2,1,0\n", 4, "freq_hz", "strictly increasing"),
        (FRF_HEADER + "1,1,0\n0.5,1,0\n", 3, "freq_hz", "strictly increasing"),
        (FRF_HEADER + "0,1,0\n1,1,0\n", 2, "freq_hz", "positive"),
        (FRF_HEADER + "-1,1,0\n1,1,0\n", 2, "freq_hz", "positive"),
        (FRF_HEADER + "1,1,0\n2,-0.5,0\n", 3, "act_mag", "non-negative"),
        (FRF_HEADER + "1,1,0\n2,NaN,0\n", 3, "act_mag", "finite"),
        (FRF_HEADER + "1,1,0\n2,1,-inf\n", 3, "act_phase_deg", "finite"),
        (FRF_HEADER + "1,1,0\n2,1\n", 3, None, "expected 3"),
        (FRF_HEADER + "1,1,0\n2,1,x\n", 3, "act_phase_deg", "expected a number"),
        ("freq_hz,act_mag\n1,1\n", 1, "act_phase_deg", "needs its partner"),
        ("freq_hz,base_phase_deg\n1,1\n", 1, "base_mag", "needs its partner"),
        ("freq_hz,act_coh\n1,1\n", 1, "act_coh", "coherence without its channel"),
        ("freq_hz,other\n1,1\n", 1, None, "no channel found"),
        ("freq_hz,act_mag,act_phase_deg,act_coh\n1,1,0,0.5\n2,1,0,1.2\n", 3, "act_coh", "0...1"),
    ],
)
def test_bad_frf_file_gives_one_clear_error(tmp_path, text, line, column, expected):
    p = _write(tmp_path, text, "bad_frf.csv")
    with pytest.raises(DataFormatError, match=expected) as info:
        read_frf_csv(p)
    assert str(p) in str(info.value)
    assert info.value.line == line
    assert info.value.column == column


# ---------------------------------------------------------------- MATLAB


def _mat(tmp_path, name="bode.mat", **vectors):
    p = tmp_path / name
    savemat(p, vectors)
    return p


def test_mat_reader_reads_notebook_names(tmp_path):
    f = np.geomspace(0.1, 40, 20)
    ref = _frf()
    act, base = np.interp(f, ref.freq_hz, np.abs(ref.act)), np.interp(f, ref.freq_hz, np.abs(ref.base))
    act_ph = (np.interp(f, ref.freq_hz, ref.phase_deg("act")) + 180) % 360 - 180  # wrapped in the file
    base_ph = (np.interp(f, ref.freq_hz, ref.phase_deg("base")) + 180) % 360 - 180  # (a resonant magnitude with a phase of
    # 0 everywhere is no response: the reader takes such a column for radians)
    p = _mat(tmp_path, freq=f, mean_io_mr=act, mean_io_ph=act_ph, mean_a2_j2a_mr=base, mean_a2_j2a_ph=base_ph)
    frf = read_mat_bode(p)
    assert frf.channels == ("act", "base")
    np.testing.assert_allclose(frf.freq_hz, f)
    np.testing.assert_allclose(np.abs(frf.act), act)
    np.testing.assert_allclose(frf.phase_deg("act"), np.interp(f, ref.freq_hz, ref.phase_deg("act")), atol=1e-9)
    assert frf.metadata["freq_vector"] == "freq"


def test_mat_reader_user_named_frequency_in_rad_s(tmp_path):
    w = np.array([1.0, 2.0, 3.0])
    p = _mat(tmp_path, omega=w, mean_io_mr=[1.0, 1, 1], mean_io_ph=[0.0, 0, 0])
    with pytest.raises(DataFormatError, match="omega.*pass freq_name"):
        read_mat_bode(p)
    frf = read_mat_bode(p, freq_name="omega", freq_unit="rad/s")
    np.testing.assert_allclose(frf.freq_hz, w / (2 * np.pi))
    with pytest.raises(DataFormatError, match="no variable 'w'"):
        read_mat_bode(p, freq_name="w")


@pytest.mark.parametrize(
    "vectors, column, expected",
    [
        (dict(freq=[1.0, 2, 3], mean_io_mr=[1.0, 1, 1]), "mean_io_ph", "needs both"),
        (dict(freq=[1.0, 2, 3], other=[1.0]), None, "no Bode data"),
        (dict(freq=[1.0, 3, 2], mean_io_mr=[1.0, 1, 1], mean_io_ph=[0.0, 0, 0]), "freq", "strictly increasing"),
        (dict(freq=[0.0, 1, 2], mean_io_mr=[1.0, 1, 1], mean_io_ph=[0.0, 0, 0]), "freq", "positive"),
        (dict(freq=[1.0, 2, 3], mean_io_mr=[1.0, -1, 1], mean_io_ph=[0.0, 0, 0]), "mean_io_mr", "non-negative"),
        (dict(freq=[1.0, 2, 3], mean_io_mr=[1.0, np.nan, 1], mean_io_ph=[0.0, 0, 0]), "mean_io_mr", "finite"),
        (dict(freq=[1.0, 2, 3], mean_io_mr=[1.0, 1], mean_io_ph=[0.0, 0, 0]), "mean_io_mr", "expected 3 elements"),
        (dict(freq=[1.0, 2, 3], mean_io_mr=np.ones((3, 2)), mean_io_ph=[0.0, 0, 0]), "mean_io_mr", "vector"),
    ],
)
def test_bad_mat_file(tmp_path, vectors, column, expected):
    p = _mat(tmp_path, **vectors)
    with pytest.raises(DataFormatError, match=expected) as info:
        read_mat_bode(p)
    assert str(p) in str(info.value)
    assert info.value.column == column


def test_mat_reader_rejects_a_non_mat_file(tmp_path):
    p = _write(tmp_path, "not a mat file at all", "fake.mat")
    with pytest.raises(DataFormatError, match="fake.mat"):
        read_mat_bode(p)


# ---------------------------------------------------------------- the value itself


def test_timeseries_validates():
    with pytest.raises(ValueError, match="uniformly"):
        TimeSeries(t=[0, 1, 3], v=[0, 0, 0], theta=[0, 0, 0], accel=[0, 0, 0])
    with pytest.raises(ValueError, match="has 2 samples"):
        TimeSeries(t=[0, 1, 2], v=[0, 0], theta=[0, 0, 0], accel=[0, 0, 0])
    with pytest.raises(ValueError, match="NaN"):
        TimeSeries(t=[0, 1], v=[0, np.nan], theta=[0, 0], accel=[0, 0])
    with pytest.raises(ValueError, match="standard column"):
        TimeSeries(t=[0, 1], v=[0, 0], theta=[0, 0], accel=[0, 0], extra={"r": [0, 0]})
    ts = TimeSeries(t=[0, 1], v=[0, 0], theta=[0, 0], accel=[0, 0])
    with pytest.raises(ValueError):
        ts.v[0] = 1.0  # frozen data


@pytest.mark.parametrize("variant", ["blank lines", "spaces", "tabs", "comment after header", "trailing blank lines", "crlf"])
def test_rows_as_they_stand_and_rows_tidied_read_the_same(tmp_path, variant):
    """The reader takes the rows after the header at once when every one is a data row as it stands (no loop over
    361,000 lines of a 6-minute 1 kHz file) and line by line otherwise: the same table and line numbers either way,
    and a comment after the header still named with its line."""
    from samii.formats import DataFormatError
    from samii.formats.files import _read_table

    rows = [f"{k * 1e-3:.3f},{np.sin(k):.6f},{np.cos(k):.6f}" for k in range(50)]
    plain = tmp_path / "plain.csv"
    plain.write_text("# sample_rate_hz: 1000\nt,v,theta\n" + "\n".join(rows) + "\n")
    a = _read_table(plain)
    assert a.lines.tolist() == list(range(3, 53))
    edited = list(rows)
    if variant == "blank lines":
        edited[10:10] = ["", "   "]
    elif variant == "spaces":
        edited[5] = "  " + edited[5] + " "
    elif variant == "tabs":
        edited[7] = edited[7] + "\t"
    elif variant == "comment after header":
        edited[3:3] = ["# a note"]
    text = "# sample_rate_hz: 1000\nt,v,theta\n" + "\n".join(edited) + ("\n\n\n" if variant == "trailing blank lines" else "\n")
    if variant == "crlf":
        text = text.replace("\n", "\r\n")
    other = tmp_path / "other.csv"
    other.write_text(text)
    if variant == "comment after header":
        with pytest.raises(DataFormatError, match="comment lines are allowed only before the header row") as err:
            _read_table(other)
        assert "line 6" in str(err.value)
        return
    b = _read_table(other)
    assert np.array_equal(a.data, b.data) and b.header == a.header and b.metadata == a.metadata
    expected = list(range(3, 13)) + list(range(15, 55)) if variant == "blank lines" else list(range(3, 53))
    assert b.lines.tolist() == expected
