"""The readers and writers under hostile input: every bad file gives one InputError line, nothing hangs or crashes.

Covers what a tester found (non-regular files, BOM, the line of a dropped
sample, .mat access errors, absurd values, time in ms against the stated rate,
numpy reprs in messages, the overwrite wording, temporary files) and a sweep of
further bad inputs for both CSV readers.
"""

import io
import os
import socket
import threading

import numpy as np
import pytest
from scipy.io import savemat

import samii.formats.files as files
import samii.formats.mat as mat_reader
import samii.formats.timeseries_csv as timeseries_csv
from samii import FrequencyResponse
from samii.errors import InputError
from samii.formats import (
    DataFormatError,
    TimeSeriesCsvWriter,
    read_frf_csv,
    read_mat_bode,
    read_timeseries_csv,
    write_frf_csv,
    write_text,
    write_timeseries_csv,
)
from samii.timeseries import TimeSeries

TS_HEADER = "t,v,theta,accel\n"
FRF_HEADER = "freq_hz,act_mag,act_phase_deg\n"
READERS = [read_timeseries_csv, read_frf_csv, read_mat_bode]


def _rows(n=200, rate=1000.0, skip=()):
    return "".join(f"{k / rate:.15g},{k % 5},0.{k % 7},-{k % 3}\n" for k in range(n) if k not in skip)


def _frf_rows(n=20):
    return "".join(f"{k + 1},{1 + k / 10:g},{-9 * k}\n" for k in range(n))


def _write(tmp_path, data, name="x.csv"):
    p = tmp_path / name
    p.write_bytes(data if isinstance(data, bytes) else data.encode())
    return p


def _mat(tmp_path, name="bode.mat", **vectors):
    p = tmp_path / name
    savemat(p, vectors)
    return p


def _raises(reader, path, match=None, *, line=None, column=None):
    """Call ``reader(path)``: one InputError line naming the file (and line/column), returned."""
    with pytest.raises(InputError) as info:
        reader(path)
    err = info.value
    text = str(err)
    assert isinstance(err, DataFormatError)
    assert "\n" not in text and "\r" not in text, text
    assert str(path) in text, text
    assert "np.float64" not in text and "np.int64" not in text, text
    if match is not None:
        assert match in text, text
    if line is not None:
        assert err.line == line and f"line {line}" in text, text
    if column is not None:
        assert err.column == column and repr(column) in text, text
    return err


def _runs_within(fn, seconds=10.0):
    """Run ``fn`` in a thread; fail (not hang) if it has not returned in time. Returns its exception."""
    result = {}

    def target():
        try:
            fn()
        except BaseException as exc:  # noqa: BLE001 - handed back to the test
            result["exc"] = exc

    th = threading.Thread(target=target, daemon=True)
    th.start()
    th.join(seconds)
    return th.is_alive(), result.get("exc")


def test_data_format_error_is_input_error():
    assert issubclass(DataFormatError, InputError) and issubclass(DataFormatError, ValueError)


# ---------------------------------------------------------------- 1. not a regular file; bounded reads


@pytest.mark.parametrize("reader", READERS)
def test_dev_zero_and_dev_null_are_refused(reader):
    for dev in ("/dev/zero", "/dev/null"):
        if os.path.exists(dev):
            alive, exc = _runs_within(lambda: reader(dev), 10)  # noqa: B023 - called within this iteration
            assert not alive, f"{reader.__name__}({dev}) hangs"
            assert isinstance(exc, DataFormatError) and "character device" in str(exc) and "regular file" in str(exc)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("reader", READERS)
def test_fifo_is_refused_without_hanging(tmp_path, reader):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    alive, exc = _runs_within(lambda: reader(fifo), 10)
    if alive:  # release the blocked reader before failing
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        os.close(fd)
    assert not alive, f"{reader.__name__} blocks on a FIFO"
    assert isinstance(exc, DataFormatError) and "named pipe" in str(exc) and str(fifo) in str(exc)


@pytest.mark.parametrize("reader", READERS)
def test_folder_socket_missing_file(tmp_path, reader):
    _raises(reader, tmp_path, "is a folder; expected a regular file")
    _raises(reader, tmp_path / "absent.csv", "file not found")
    _raises(reader, tmp_path / "no_folder" / "x.csv", "folder")
    plain = _write(tmp_path, "x", "plain.txt")
    _raises(reader, plain / "x.csv", "not a folder")
    if hasattr(socket, "AF_UNIX"):
        sock_path = tmp_path / "s.sock"
        with socket.socket(socket.AF_UNIX) as s:
            s.bind(str(sock_path))
            _raises(reader, sock_path, "is a socket")


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root reads any file")
@pytest.mark.parametrize("reader", READERS)
def test_unreadable_file(tmp_path, reader):
    p = _write(tmp_path, TS_HEADER + _rows(), "locked.mat" if reader is read_mat_bode else "locked.csv")
    p.chmod(0)
    try:
        _raises(reader, p, "permission denied")
    finally:
        p.chmod(0o644)


@pytest.mark.parametrize("reader", READERS)
def test_unreadable_file_even_as_root(tmp_path, monkeypatch, reader):
    # root reads any file: make open() refuse as it would for another user
    p = _write(tmp_path, TS_HEADER + _rows(), "locked.mat" if reader is read_mat_bode else "locked.csv")

    def refuse(*a, **k):
        raise PermissionError(13, "Permission denied", str(p))

    monkeypatch.setattr(files.os, "open", refuse)
    _raises(reader, p, "is not readable (permission denied)")


@pytest.mark.parametrize("reader", READERS)
def test_file_size_is_bounded_and_stated(tmp_path, monkeypatch, reader):
    monkeypatch.setattr(files, "MAX_FILE_BYTES", 1000)
    p = _write(tmp_path, TS_HEADER + _rows(), "big.mat" if reader is read_mat_bode else "big.csv")
    _raises(reader, p, "at most 1000 bytes (samii.formats.files.MAX_FILE_BYTES)")


def test_read_is_bounded_even_if_the_file_grows(tmp_path, monkeypatch):
    # stat says small, the file then holds more: the reader stops at the bound
    p = _write(tmp_path, TS_HEADER + _rows(2000))
    real_stat = os.stat

    class SmallStat:
        def __init__(self, st):
            self._st = st

        def __getattr__(self, name):
            return 10 if name == "st_size" else getattr(self._st, name)

    monkeypatch.setattr(files.os, "stat", lambda path, *a, **k: SmallStat(real_stat(path, *a, **k)))
    monkeypatch.setattr(files, "MAX_FILE_BYTES", 5000)
    _raises(read_timeseries_csv, p, "grew beyond that")


def test_huge_single_line(tmp_path):
    p = _write(tmp_path, "1," * (files.MAX_LINE_CHARS // 2 + 10))
    for reader in (read_timeseries_csv, read_frf_csv):
        _raises(reader, p, f"expected at most {files.MAX_LINE_CHARS}", line=1)
    p = _write(tmp_path, TS_HEADER + "0,0,0,0\n" + "9" * (files.MAX_LINE_CHARS + 1) + "\n", "late.csv")
    _raises(read_timeseries_csv, p, "characters long", line=3)


def test_line_count_is_bounded(tmp_path, monkeypatch):
    monkeypatch.setattr(files, "MAX_LINES", 100)
    _raises(read_timeseries_csv, _write(tmp_path, TS_HEADER + _rows(200)), "at most 100 (samii.formats.files.MAX_LINES)")


def test_huge_header_is_cut_in_the_message(tmp_path):
    p = _write(tmp_path, "a" * 100_000 + ",b\n1,2\n")
    err = _raises(read_timeseries_csv, p, "missing required columns", line=1)
    assert len(str(err)) < 500


# ---------------------------------------------------------------- 2. BOM, line endings


def test_bom_is_accepted_before_metadata_and_header(tmp_path):
    text = "# sample_rate_hz: 1000\n" + TS_HEADER + _rows()
    ts = read_timeseries_csv(_write(tmp_path, b"\xef\xbb\xbf" + text.encode()))
    assert ts.metadata["sample_rate_hz"] == "1000" and len(ts) == 200
    ts = read_timeseries_csv(_write(tmp_path, b"\xef\xbb\xbf" + (TS_HEADER + _rows()).encode(), "bom2.csv"))
    assert list(ts.columns()) == ["t", "v", "theta", "accel"]
    frf = read_frf_csv(_write(tmp_path, b"\xef\xbb\xbf" + (FRF_HEADER + _frf_rows()).encode(), "frf.csv"))
    assert frf.channels == ("act",)


@pytest.mark.parametrize("eol", ["\r\n", "\r"])
def test_windows_and_old_mac_line_endings(tmp_path, eol):
    text = "# sample_rate_hz: 1000\n# note: x\n\n" + TS_HEADER + _rows()
    ref = read_timeseries_csv(_write(tmp_path, text, "lf.csv"))
    for data in (text.replace("\n", eol).encode(), b"\xef\xbb\xbf" + text.replace("\n", eol).encode()):
        ts = read_timeseries_csv(_write(tmp_path, data))
        np.testing.assert_array_equal(ts.theta, ref.theta)
        assert dict(ts.metadata) == dict(ref.metadata)
    frf = read_frf_csv(_write(tmp_path, (FRF_HEADER + _frf_rows()).replace("\n", eol), "frf.csv"))
    assert frf.freq_hz.size == 20
    # line numbers still count lines
    bad = (TS_HEADER + "0,0,0,0\n0.001,0,x,0\n").replace("\n", eol)
    _raises(read_timeseries_csv, _write(tmp_path, bad, "bad.csv"), "expected a number, got 'x'", line=3, column="theta")


# ---------------------------------------------------------------- 3. the line of a dropped sample


def test_dropped_sample_is_reported_where_it_is(tmp_path):
    # one comment line, the header on line 2, sample k on line k + 3: sample 123 is missing
    p = _write(tmp_path, "# sample_rate_hz: 1000\n" + TS_HEADER + _rows(skip=(123,)))
    err = _raises(read_timeseries_csv, p, "1 sample missing?", line=3 + 123, column="t")
    assert "0.002 s" in str(err) and "0.001 s" in str(err) and f"from line {2 + 123}" in str(err)


def test_repeated_and_backward_time_steps(tmp_path):
    rows = _rows(50).splitlines(keepends=True)
    rows[30] = rows[29]
    _raises(read_timeseries_csv, _write(tmp_path, TS_HEADER + "".join(rows)), "repeats or runs backwards", line=32, column="t")
    _raises(read_timeseries_csv, _write(tmp_path, TS_HEADER + "0,0,0,0\n0,0,0,0\n0,0,0,0\n", "flat.csv"), "increasing time", column="t")


def test_timeseries_value_reports_the_gap_too():
    t = np.delete(np.arange(200) / 1000.0, 123)
    with pytest.raises(ValueError, match=r"step 123 is 0.002 s, the typical \(median\) step is 0.001 s"):
        TimeSeries(t=t, v=t, theta=t, accel=t)


# ---------------------------------------------------------------- 4. .mat access and content


def test_mat_not_a_matlab_file(tmp_path):
    _raises(read_mat_bode, _write(tmp_path, b"", "empty.mat"), "the file is empty")
    _raises(read_mat_bode, _write(tmp_path, FRF_HEADER + _frf_rows(), "text.mat"), "not a MATLAB .mat file")
    _raises(read_mat_bode, _write(tmp_path, FRF_HEADER + _frf_rows(), "text2.mat"), "it looks like text: a samii CSV")
    _raises(read_mat_bode, _write(tmp_path, bytes(range(256)) * 20, "garbage.mat"), "not a MATLAB .mat file")
    hdf = b"MATLAB 7.3 MAT-file".ljust(512, b" ") + b"\x89HDF\r\n\x1a\n" + b"\0" * 100
    _raises(read_mat_bode, _write(tmp_path, hdf, "v73.mat"), "v7.3")


def test_mat_file_that_crashes_scipy_is_an_error_not_a_crash(tmp_path):
    # a damaged name element: the next tag's type code becomes 232, which scipy's compiled
    # MAT-5 reader (1.17) follows into a segmentation fault when it runs in this process
    buf = io.BytesIO()
    savemat(buf, dict(freq=np.arange(1.0, 30), mean_io_mr=np.ones(29), mean_io_ph=np.zeros(29)))
    data = buf.getvalue()
    assert data.count(b"freq\x09") == 1
    p = _write(tmp_path, data.replace(b"freq\x09", b"f"), "damaged.mat")
    _raises(read_mat_bode, p)


def test_mat_non_numeric_variable(tmp_path):
    p = _mat(tmp_path, freq=np.array([1.0, 2.0]), mean_io_mr="abc", mean_io_ph=np.zeros(2))
    _raises(read_mat_bode, p, "expected a non-empty real numeric vector", column="mean_io_mr")


def test_mat_reads_through_the_child_and_in_process_alike(tmp_path, monkeypatch):
    p = _mat(tmp_path, freq=np.array([1.0, 2.0, 3.0]), mean_io_mr=np.ones(3), mean_io_ph=np.array([0.0, -90, -180]), note="x")
    a = read_mat_bode(p)
    monkeypatch.setattr(mat_reader, "_loadmat_isolated", mat_reader._loadmat_in_process)
    b = read_mat_bode(p)
    np.testing.assert_array_equal(a.act, b.act)
    np.testing.assert_array_equal(a.freq_hz, b.freq_hz)


# ---------------------------------------------------------------- 5. absurd values


@pytest.mark.parametrize(
    "row, column, expected",
    [
        ("2,1,2.7e12", "act_phase_deg", "within +-100000 deg"),
        ("2,1,-100001", "act_phase_deg", "within +-100000 deg"),
        ("2,1e300,0", "act_mag", "within +-1e+100"),
        ("2,1e25,0", "act_mag", "1e-20...1e+20 (-400...+400 dB)"),
        ("2,1e-25,0", "act_mag", "1e-20...1e+20"),
        ("2,0,0", "act_mag", "a magnitude of 0 has no dB value"),
        ("2,-3,0", "act_mag", "non-negative"),
        ("2e9,1,0", "freq_hz", "up to 1e+06 Hz"),
        ("1e300,1,0", "freq_hz", "within +-1e+100"),
    ],
)
def test_absurd_frf_values(tmp_path, row, column, expected):
    p = _write(tmp_path, FRF_HEADER + "1,1,0\n" + row + "\n")
    _raises(read_frf_csv, p, expected, line=3, column=column)


def test_large_but_physical_values_pass(tmp_path):
    # a long delay unwrapped far round, a deep notch, a high resonance: all measured phases/magnitudes
    p = _write(tmp_path, FRF_HEADER + "1,1e-12,-50000\n2000,1e12,-99999\n")
    frf = read_frf_csv(p)
    assert abs(frf.act[0]) == pytest.approx(1e-12)
    p = _write(tmp_path, TS_HEADER + "0,1e90,0,0\n0.001,0,0,-1e90\n", "ts.csv")
    assert read_timeseries_csv(p).v[0] == 1e90


def test_absurd_timeseries_value(tmp_path):
    p = _write(tmp_path, TS_HEADER + "0,0,0,0\n0.001,0,0,1e300\n")
    _raises(read_timeseries_csv, p, "within +-1e+100", line=3, column="accel")


@pytest.mark.parametrize(
    "vectors, column, expected",
    [
        (dict(freq=[1.0, 2], mean_io_mr=[1.0, 1], mean_io_ph=[0.0, 2.7e12]), "mean_io_ph", "within +-100000 deg"),
        (dict(freq=[1.0, 2], mean_io_mr=[1.0, 1e300], mean_io_ph=[0.0, 0]), "mean_io_mr", "within +-1e+100"),
        (dict(freq=[1.0, 2], mean_io_mr=[1.0, 0], mean_io_ph=[0.0, 0]), "mean_io_mr", "1e-20...1e+20"),
        (dict(freq=[1.0, 2e7], mean_io_mr=[1.0, 1], mean_io_ph=[0.0, 0]), "freq", "up to 1e+06 Hz"),
    ],
)
def test_absurd_mat_values(tmp_path, vectors, column, expected):
    err = _raises(read_mat_bode, _mat(tmp_path, **vectors), expected, column=column)
    assert "element 2" in str(err)


# ---------------------------------------------------------------- 6. time column against # sample_rate_hz


@pytest.mark.parametrize(
    "rate, step, expected",
    [
        ("1000", 1.0, "is the time in ms?"),
        ("1000000", 1.0, "is the time in us?"),
        ("1", 0.001, "is the rate in kHz?"),
        ("1500", 0.001, "which of the two is wrong?"),
        ("500", 0.002 * 2, "decimated by 2"),
    ],
)
def test_time_step_must_match_the_stated_rate(tmp_path, rate, step, expected):
    p = _write(tmp_path, f"# excitation: x\n# sample_rate_hz: {rate}\n" + TS_HEADER + _rows(100, rate=1 / step))
    err = _raises(read_timeseries_csv, p, expected, line=2, column="t")
    assert f"steps by {step:.9g} s but '# sample_rate_hz: {rate}' (line 2) says {1 / float(rate):.9g} s" in str(err)


def test_stated_rate_within_tolerance_passes(tmp_path):
    # %g writes 3333.33 for 10000/3 Hz: 1e-6 off, well within SAMPLE_RATE_RTOL
    read_timeseries_csv(_write(tmp_path, "# sample_rate_hz: 3333.33\n" + TS_HEADER + _rows(100, rate=10000 / 3)))
    read_timeseries_csv(_write(tmp_path, "# sample_rate_hz: 1e3\n" + TS_HEADER + _rows(100), "b.csv"))
    read_timeseries_csv(_write(tmp_path, TS_HEADER + _rows(100, rate=1.0), "c.csv"))  # no rate stated: nothing to check


@pytest.mark.parametrize("value", ["1 kHz", "fast", "0", "-1000", "nan", "inf", ""])
def test_stated_rate_must_be_a_positive_number(tmp_path, value):
    p = _write(tmp_path, f"# sample_rate_hz: {value}\n" + TS_HEADER + _rows(10))
    _raises(read_timeseries_csv, p, "expected '# sample_rate_hz:' to give a positive number", line=1)


def test_writer_output_passes_the_rate_check(tmp_path):
    t = np.arange(300) / 1024.0
    ts = TimeSeries(t=t, v=t, theta=t, accel=t, metadata={"sample_rate_hz": "1024"})
    assert len(read_timeseries_csv(write_timeseries_csv(ts, tmp_path / "ts.csv"))) == 300


# ---------------------------------------------------------------- 7. numbers in messages


@pytest.mark.parametrize(
    "reader, text",
    [
        (read_frf_csv, FRF_HEADER + "0.16,1,0\n0.16,1,0\n"),
        (read_frf_csv, FRF_HEADER + "-0.16,1,0\n"),
        (read_frf_csv, FRF_HEADER + "0.16,-0.5,0\n"),
        (read_frf_csv, "freq_hz,act_mag,act_phase_deg,act_coh\n0.16,1,0,1.5\n"),
        (read_timeseries_csv, "t,v,theta,accel,spool\n0,0,0,0,0\n0.001,0,0,0,1.25\n"),
        (read_timeseries_csv, TS_HEADER + "0,0,0,0\n0.001,nan,0,0\n"),
        (read_timeseries_csv, TS_HEADER + "0,0,0,0\n0.16,0,0,0\n0.17,0,0,0\n"),
    ],
)
def test_messages_show_plain_numbers(tmp_path, reader, text):
    err = _raises(reader, _write(tmp_path, text))
    assert "np." not in str(err) and "float64" not in str(err)


def test_mat_and_writer_messages_show_plain_numbers(tmp_path):
    err = _raises(read_mat_bode, _mat(tmp_path, freq=[0.16, 0.16], mean_io_mr=[1.0, 1], mean_io_ph=[0.0, 0]))
    assert "got 0.16 after 0.16" in str(err)
    with TimeSeriesCsvWriter(tmp_path / "w.csv", ["v", "theta", "accel"], {}) as w:
        with pytest.raises(ValueError) as info:
            w.write(np.array([0.16]), {"v": [np.nan], "theta": [0.0], "accel": [0.0]})
        w.abort()
    assert "t = 0.16 s" in str(info.value) and "np." not in str(info.value)
    with pytest.raises(ValueError) as info:
        TimeSeries(t=[0, 1], v=[0, np.inf], theta=[0, 0], accel=[0, 0])
    assert "np." not in str(info.value)


# ---------------------------------------------------------------- 8. overwrite wording


def test_refusal_to_overwrite_names_both_spellings(tmp_path):
    p = _write(tmp_path, "precious")
    frf = FrequencyResponse([1.0, 2.0], act=[1.0, 1.0])
    with pytest.raises(FileExistsError) as info:
        write_frf_csv(frf, p)
    assert "exists; refusing to overwrite it unless asked to (overwrite=True / --overwrite)" in str(info.value)
    assert "pass overwrite=True" not in str(info.value)
    assert p.read_text() == "precious"


def test_losing_the_write_race_names_both_spellings_and_leaves_no_temp_file(tmp_path):
    target = tmp_path / "ts.csv"
    w = TimeSeriesCsvWriter(target, ["v", "theta", "accel"], {"sample_rate_hz": "1000"})
    w.write(np.arange(5) / 1000.0, {"v": np.zeros(5), "theta": np.zeros(5), "accel": np.zeros(5)})
    target.write_text("the other run")  # a concurrent run finished first
    with pytest.raises(FileExistsError, match=r"\(overwrite=True / --overwrite\)"):
        w.close()
    assert target.read_text() == "the other run"
    assert os.listdir(tmp_path) == ["ts.csv"]


# ---------------------------------------------------------------- 9. temporary files


class _Boom(KeyboardInterrupt):
    pass


def _only(tmp_path, *names):
    assert sorted(os.listdir(tmp_path)) == sorted(names)


@pytest.mark.parametrize("where", ["write", "link", "replace"])
def test_write_atomic_removes_its_temp_file_on_ctrl_c(tmp_path, monkeypatch, where):
    overwrite = where == "replace"
    if where == "write":
        real_open = open

        class Exploding:
            def __init__(self, fh):
                self.fh = fh

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                self.fh.close()

            def write(self, text):
                self.fh.write(text[:10])
                raise _Boom()

        monkeypatch.setattr(files, "open", lambda *a, **k: Exploding(real_open(*a, **k)), raising=False)
    else:

        def boom(*a, **k):
            raise _Boom()

        monkeypatch.setattr(files.os, where, boom)
    with pytest.raises(_Boom):
        write_text(tmp_path / "out.txt", "hello\n" * 100, overwrite=overwrite)
    _only(tmp_path)


def test_streaming_writer_removes_its_temp_file_whatever_happens(tmp_path, monkeypatch):
    cols = {"v": np.zeros(3), "theta": np.zeros(3), "accel": np.zeros(3)}
    # Ctrl-C inside the with block
    with pytest.raises(_Boom):
        with TimeSeriesCsvWriter(tmp_path / "a.csv", ["v", "theta", "accel"], {}) as w:
            w.write(np.arange(3) / 1000.0, cols)
            raise _Boom()
    _only(tmp_path)
    # Ctrl-C while moving the finished file into place
    w = TimeSeriesCsvWriter(tmp_path / "b.csv", ["v", "theta", "accel"], {})
    w.write(np.arange(3) / 1000.0, cols)

    def boom(*a, **k):
        raise _Boom()

    with monkeypatch.context() as m:
        m.setattr(files.os, "link", boom)
        with pytest.raises(_Boom):
            w.close()
    _only(tmp_path)
    # too few rows
    w = TimeSeriesCsvWriter(tmp_path / "c.csv", ["v", "theta", "accel"], {})
    with pytest.raises(ValueError, match="at least 2 samples"):
        w.close()
    _only(tmp_path)
    # a writer dropped without close() or abort()
    w = TimeSeriesCsvWriter(tmp_path / "d.csv", ["v", "theta", "accel"], {})
    del w
    _only(tmp_path)


def test_streaming_writer_cleans_up_when_the_header_write_fails(tmp_path, monkeypatch):
    real_open = open

    class HeaderFails:
        def __init__(self, fh):
            self.fh = fh

        def write(self, text):
            raise _Boom()

        def close(self):
            self.fh.close()

    monkeypatch.setattr(timeseries_csv, "open", lambda *a, **k: HeaderFails(real_open(*a, **k)), raising=False)
    with pytest.raises(_Boom):
        TimeSeriesCsvWriter(tmp_path / "a.csv", ["v", "theta", "accel"], {})
    _only(tmp_path)


def test_stale_temp_files_are_ignored(tmp_path):
    stale = _write(tmp_path, FRF_HEADER + "1,1,0\n", ".frf.csv.12345.0123456789ab.tmp")
    for reader in READERS:
        _raises(reader, stale, "temporary file of a write that was interrupted")
    # a stale temp file next to the target changes nothing for the writer or the reader
    frf = FrequencyResponse([1.0, 2.0], act=[1.0, 1.0j])
    write_frf_csv(frf, tmp_path / "frf.csv")
    np.testing.assert_allclose(read_frf_csv(tmp_path / "frf.csv").act, frf.act, atol=1e-12)
    _only(tmp_path, "frf.csv", stale.name)


# ---------------------------------------------------------------- 10. a sweep of bad inputs


@pytest.mark.parametrize(
    "data, line, column, expected",
    [
        ("", None, None, "the file is empty"),
        ("\n\n  \n", None, None, "the file is empty"),
        (b"\xef\xbb\xbf", None, None, "the file is empty"),
        ("# a: b\n", None, None, "empty apart from comment lines"),
        (TS_HEADER, 1, None, "not followed by any data row"),
        (b"\x89\x13\xff\x00\x01garbage\x00", 1, None, "binary data"),
        (bytes(range(1, 256)) * 40, 3, None, "got the byte 0x80 at character 115"),  # after the \n (10) and the \r (13)
        ("t;v;theta;accel\n0;0;0;0\n", 1, None, "separated by ';'; expected commas"),
        ("t\tv\ttheta\taccel\n0\t0\t0\t0\n", 1, None, "separated by tabs"),
        (TS_HEADER + "0;0;0;0\n", 2, None, "got 1; the row seems separated by ';'"),
        (TS_HEADER + "0,0,0,0\n0.001,NaN,0,0\n", 3, "v", "expected a finite number, got 'NaN'"),
        (TS_HEADER + "0,0,0,0\n0.001,0,Infinity,0\n", 3, "theta", "finite"),
        ("t,v,theta\n0,0,0\n0.001,0,0\n", 1, None, "missing required column 'accel'"),
        (TS_HEADER + "0,0,0,0,1\n", 2, None, "expected 4 comma-separated values"),
        (TS_HEADER + "0,0,0,0,\n", 2, None, "got 5"),
        ("# operator: M\xfcller\n".encode("latin-1") + (TS_HEADER + "0,0,0,0\n").encode(), 1, None, "byte 0xfc at character 14"),
        (TS_HEADER.encode() + b"0,0,0,0\n0.001,\xe9,0,0\n", 3, None, "character 7"),
        ((TS_HEADER + _rows(5)).encode("utf-16"), None, None, "UTF-16"),
        (b"PK\x03\x04" + b"\x00" * 50, None, None, "xlsx"),
        (b"MATLAB 5.0 MAT-file" + b"\x00" * 200, None, None, "a MATLAB .mat file"),
        (_rows(5), 1, None, "the first row holds numbers"),
        ('"t","v","theta","accel"\n0,0,0,0\n', 1, None, "not quoted"),
        ("T,V,Theta,Accel\n0,0,0,0\n", 1, None, "case-sensitive"),
        (TS_HEADER + "0,0,0,0\n0.001,1_000,0,0\n", 3, "v", "expected a number, got '1_000'"),
        (TS_HEADER + "0,0,0,0\n0.001,0x1F,0,0\n", 3, "v", "expected a number, got '0x1F'"),
        (TS_HEADER + "0,0,0,0\n0.001,1.5.2,0,0\n", 3, "v", "expected a number"),
        (TS_HEADER + "0,0,0,0\n0.001,\u0661,0,0\n", 3, "v", "expected a number"),  # an Arabic-Indic digit: Python's float takes it
    ],
)
def test_bad_timeseries_inputs(tmp_path, data, line, column, expected):
    _raises(read_timeseries_csv, _write(tmp_path, data), expected, line=line, column=column)


@pytest.mark.parametrize(
    "data, line, column, expected",
    [
        ("", None, None, "the file is empty"),
        (FRF_HEADER, 1, None, "not followed by any data row"),
        (bytes(np.random.default_rng(3).integers(0, 256, 4000, dtype=np.uint8)), None, None, None),
        ("freq_hz;act_mag;act_phase_deg\n1;1;0\n", 1, None, "separated by ';'"),
        (FRF_HEADER + "1,nan,0\n", 2, "act_mag", "finite"),
        (FRF_HEADER + "1,1,-inf\n", 2, "act_phase_deg", "finite"),
        (FRF_HEADER + "1,1,0\n3,1,0\n2,1,0\n", 4, "freq_hz", "got a decreasing 2 after 3 (line 3)"),
        (FRF_HEADER + "1,1,0\n2,1,0\n2,1,0\n", 4, "freq_hz", "got a repeated 2 after 2 (line 3)"),
        ("freq_hz,act_mag,act_phase_deg,act_coh\n1,1,0,1.0000001\n", 2, "act_coh", "in 0...1"),
        ("freq_hz,act_mag,act_phase_deg,act_coh\n1,1,0,-0.01\n", 2, "act_coh", "in 0...1"),
        ("freq_hz,act_mag\n1,1\n", 1, "act_phase_deg", "needs its partner"),
        ("act_mag,act_phase_deg\n1,0\n", 1, None, "missing required column 'freq_hz'"),
        (FRF_HEADER + "1,1,0,7\n", 2, None, "expected 3 comma-separated values"),
        (FRF_HEADER + "1,1\n", 2, None, "got 2"),
        ("# note: caf\xe9\n".encode("latin-1") + (FRF_HEADER + "1,1,0\n").encode(), 1, None, "UTF-8"),
        ("x" * (files.MAX_LINE_CHARS + 5), 1, None, "characters long"),
        ("freq_hz,other\n1,1\n", 1, None, "no channel found"),
    ],
)
def test_bad_frf_inputs(tmp_path, data, line, column, expected):
    _raises(read_frf_csv, _write(tmp_path, data), expected, line=line, column=column)


def test_extra_columns_are_fine(tmp_path):
    frf = read_frf_csv(_write(tmp_path, "freq_hz,act_mag,act_phase_deg,operator\n1,1,0,3\n2,1,0,4\n"))
    assert frf.channels == ("act",)
    ts = read_timeseries_csv(_write(tmp_path, "t,v,theta,accel,valve_current\n0,0,0,0,1\n0.001,0,0,0,2\n", "ts.csv"))
    np.testing.assert_array_equal(ts.extra["valve_current"], [1, 2])


def test_random_damage_gives_input_errors_only(tmp_path):
    """Damaged copies of good files: each read succeeds or raises InputError, never another type."""
    rng = np.random.default_rng(7)
    good_ts = ("# sample_rate_hz: 1000\n" + TS_HEADER + _rows(40)).encode()
    good_frf = ("freq_hz,act_mag,act_phase_deg,act_coh\n" + "".join(f"{k + 1},{1 + k / 10},{-9 * k},0.9\n" for k in range(30))).encode()
    tokens = [b",", b"\n", b"\r\n", b"#", b"nan", b"-", b"e", b"1e400", b"\xff", b"\x00", b"\xef\xbb\xbf", b";", b" ", b"_", b'"']
    for _ in range(300):
        for reader, good in ((read_timeseries_csv, good_ts), (read_frf_csv, good_frf)):
            data = bytearray(good)
            for _ in range(int(rng.integers(1, 4))):
                i = int(rng.integers(0, len(data)))
                op = rng.random()
                if op < 0.35:
                    del data[i : i + int(rng.integers(1, 6))]
                elif op < 0.75:
                    data[i:i] = tokens[int(rng.integers(len(tokens)))]
                else:
                    data[i] = int(rng.integers(256))
            p = _write(tmp_path, bytes(data), "damaged.csv")
            try:
                reader(p)
            except InputError as exc:
                assert "\n" not in str(exc) and str(p) in str(exc) and "np." not in str(exc)
