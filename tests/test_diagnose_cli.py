"""``samii frf`` and ``samii diagnose`` end to end, in process.

Data come from samii.diagnose.rig.EffectRig (eq 9.4 under the position loop, swept
sine 0.1-40 Hz x 3 at 0.1 V, 1 kHz, the DAQ's default sensor noise), written
as time-series CSVs without metadata lines: the record length has to be found
from r. Each file (16 MB) and each expensive run (a diagnosis takes 3-15 s) is
made once per module and shared by the tests that read it.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from samii.cli import main
from samii.diagnose.rig import EffectRig
from samii.diagnose.select import ALPHA
from samii.formats import csv_header, read_frf_csv, write_timeseries_csv
from samii.measure.excitation import SweptSine

FS = 1000.0
DELAY_S = 0.004
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _reject_constant(name):
    raise ValueError(f"not strict JSON: {name}")


def strict_json(text: str):
    """JSON as RFC 8259 has it: NaN, Infinity and -Infinity are refused."""
    return json.loads(text, parse_constant=_reject_constant)


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """``samii.cli.main`` with stdout and stderr captured (for module-scoped fixtures, where capsys is not available)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


def snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``folder`` (hidden ones too) with its content and mtime."""
    return {str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.rglob("*")) if p.is_file()}


# --------------------------------------------------------------------------- data, written once


@pytest.fixture(scope="module")
def sweep():
    sw = SweptSine(repetitions=3, amplitude_v=0.1)
    t = np.arange(int(round(sw.duration_s * FS))) / FS
    return sw, sw.signal(t)


def _write(tmp_path_factory, sweep, name: str, seed: int, **effects) -> Path:
    ts = EffectRig(**effects).simulate(sweep[1], sample_rate_hz=FS, rng=np.random.default_rng(seed))
    path = tmp_path_factory.mktemp("data") / name
    write_timeseries_csv(ts, path)
    assert "record_s" not in ts.metadata  # the length of a record must come from r
    return path


@pytest.fixture(scope="module")
def clean_csv(tmp_path_factory, sweep):
    return _write(tmp_path_factory, sweep, "clean.csv", 4)


@pytest.fixture(scope="module")
def delay_csv(tmp_path_factory, sweep):
    return _write(tmp_path_factory, sweep, "delay.csv", 4, command_delay_s=DELAY_S)


@pytest.fixture(scope="module")
def frf_clean(tmp_path_factory, clean_csv):
    """``samii frf clean.csv --out DIR --json``: (exit code, stdout, stderr, DIR)."""
    out = tmp_path_factory.mktemp("frf_clean") / "out"
    rc, text, err = run_cli(["frf", str(clean_csv), "--out", str(out), "--json"])
    return rc, text, err, out


@pytest.fixture(scope="module")
def delay_diagnosis(tmp_path_factory, delay_csv):
    """``samii diagnose delay.csv --json --out DIR``: (exit code, stdout, stderr, DIR)."""
    out = tmp_path_factory.mktemp("diag_delay") / "out"
    rc, text, err = run_cli(["diagnose", str(delay_csv), "--json", "--out", str(out)])
    return rc, text, err, out


@pytest.fixture(scope="module")
def clean_diagnosis_text(tmp_path_factory, clean_csv):
    """``samii diagnose clean.csv --out DIR`` (text): (exit code, stdout, stderr, DIR)."""
    out = tmp_path_factory.mktemp("diag_clean") / "out"
    rc, text, err = run_cli(["diagnose", str(clean_csv), "--out", str(out)])
    return rc, text, err, out


@pytest.fixture(scope="module")
def saved_fit_diagnosis(tmp_path_factory, delay_csv):
    """``samii frf delay.csv``, ``samii fit`` of its frf.csv, then ``samii diagnose delay.csv --baseline FITDIR/fit.json --json``."""
    root = tmp_path_factory.mktemp("saved_fit")
    rc, _, err = run_cli(["frf", str(delay_csv), "--out", str(root / "frf")])
    assert rc == 0, err
    rc, text, err = run_cli(["fit", str(root / "frf" / "frf.csv"), "--out", str(root / "fit"), "--json", "--no-progress"])
    assert rc == 0, err
    fit = strict_json(text)
    fit_json = root / "fit" / "fit.json"
    assert fit_json.is_file()
    rc, text, err = run_cli(["diagnose", str(delay_csv), "--baseline", str(fit_json), "--json"])
    return rc, text, err, fit_json, fit


# --------------------------------------------------------------------------- samii frf


def test_frf_of_a_time_series(frf_clean, sweep):
    rc, text, err, out = frf_clean
    assert rc == 0, err
    d = strict_json(text)
    assert d["records"]["n_records"] == 3
    assert d["records"]["record_s"] == pytest.approx(sweep[0].record_s, abs=0.01)
    assert "found from r" in d["records"]["how"]
    assert {"act", "total"} <= set(d["channels"])
    assert (out / "frf.csv").is_file() and (out / "bode.png").is_file()
    assert (out / "bode.png").read_bytes()[:8] == PNG_MAGIC
    assert "act_coh" in csv_header(out / "frf.csv")
    frf = read_frf_csv(out / "frf.csv")
    assert {"act", "total"} <= set(frf.channels)
    coh = frf.coherence("act")
    assert coh is not None and np.all((coh >= 0) & (coh <= 1)) and np.median(coh) > 0.9
    assert frf.freq_hz[0] == pytest.approx(0.1, rel=0.05) and frf.freq_hz[-1] == pytest.approx(40.0, rel=0.01)


def test_frf_second_run_refuses_to_overwrite(frf_clean, clean_csv, capsys):
    rc, _, _, out = frf_clean
    assert rc == 0
    before = snapshot(out)
    assert main(["frf", str(clean_csv), "--out", str(out), "--json"]) == 2
    cap = capsys.readouterr()
    assert cap.out == ""
    assert cap.err.count("\n") == 1 and cap.err.startswith("samii frf: error: ") and "--overwrite" in cap.err
    assert snapshot(out) == before


# --------------------------------------------------------------------------- samii diagnose


@pytest.mark.slow
def test_diagnose_finds_the_command_delay(delay_diagnosis):
    rc, text, err, _ = delay_diagnosis
    assert rc == 0, err
    d = strict_json(text)
    for key in ("verdict", "effects", "error_before", "error_after", "simulator", "unexplained", "baseline", "files"):
        assert key in d, key
    assert d["simulator"] is None
    assert d["verdict"] == "effects"
    assert len(d["effects"]) == 1
    e = d["effects"][0]
    assert {"category", "kind", "channel", "params", "stderr", "evidence"} <= set(e)
    assert (e["category"], e["kind"]) == ("delay", "command")
    assert e["expected"] is False
    # the file states its rate: the baseline carries a held command's half sample, and the delay found is beyond it
    # (the EffectRig's command is analogue, but the data hold the sum and cannot tell the two apart)
    hold = (d["sampling"]["hold_s"] or [0.0])[0]
    assert hold in (0.0, pytest.approx(0.5 / FS))
    assert e["params"]["delay_s"] + hold == pytest.approx(DELAY_S, abs=5e-4)
    se = e["stderr"]["delay_s"]
    assert isinstance(se, float) and 0 < se < 5e-4
    assert isinstance(e["evidence"], str) and e["evidence"]
    # the test that admitted it, as figures, and the sentence says them: its one parameter lowering chi2 by the
    # F-test, or (on this record) taking the place of an effect that had joined by it
    j = e["joined"]
    assert j["chi2_after"] < j["chi2_before"], j
    if j["how"] == "f_test":
        # (log10 p is null where F's tail underflows, below 1e-300: the sentence says "p < 1e-300")
        # (below the selection's level, ALPHA over the candidates, where it joined)
        small_p = "p < 1e-300" in e["evidence"] if j["log10_p"] is None else j["log10_p"] < math.log10(ALPHA)
        assert j["dof"][0] == 1 and small_p and f"F = {j['f_stat']:.3g} on (1, {j['dof'][1]}) dof" in e["evidence"]
    else:
        assert j["how"] == "swap" and f"it replaced {j['replaced']}, which had joined by F-test" in e["evidence"], j
    for which in ("error_before", "error_after"):
        for ch in ("act", "base"):
            assert {"rms_db", "rms_deg", "chi2"} <= set(d[which][ch]), (which, ch)
            assert all(math.isfinite(d[which][ch][k]) for k in ("rms_db", "rms_deg", "chi2"))
    before, after = d["error_before"], d["error_after"]
    assert after["act"]["rms_deg"] < before["act"]["rms_deg"]
    for ch in ("act", "total"):
        assert after[ch]["chi2"] < before[ch]["chi2"], ch
    # with the delay the model is at the noise (about 1.2 for 3-record spreads; 1.34 / 1.14 / 1.11 seen)
    assert all(after[ch]["chi2"] < 2.0 for ch in ("act", "base", "total"))
    assert d["files"][0]["records"]["n_records"] == 3


@pytest.mark.slow
def test_diagnose_out_writes_the_report(delay_diagnosis):
    rc, text, err, out = delay_diagnosis
    assert rc == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["bode.png", "diagnosis.json", "harmonics.png", "residuals.png"]
    for name in ("bode.png", "residuals.png", "harmonics.png"):
        assert (out / name).read_bytes()[:8] == PNG_MAGIC, name
    saved = strict_json((out / "diagnosis.json").read_text())
    printed = strict_json(text)
    assert saved["verdict"] == printed["verdict"] == "effects"
    assert saved == printed


@pytest.mark.slow
def test_diagnose_clean_text(clean_diagnosis_text):
    rc, text, err, out = clean_diagnosis_text
    assert rc == 0, err
    assert "verdict: none" in text
    assert "3 records of 84.2" in text  # the record length found from r
    assert f"wrote {out / 'diagnosis.json'}" in text
    assert sorted(p.name for p in out.iterdir()) == ["bode.png", "diagnosis.json", "harmonics.png", "residuals.png"]
    saved = strict_json((out / "diagnosis.json").read_text())
    assert saved["verdict"] == "none" and saved["effects"] == [] and saved["unexplained"] == []
    for name in ("bode.png", "residuals.png", "harmonics.png"):
        assert (out / name).read_bytes()[:8] == PNG_MAGIC, name


def test_diagnose_the_frf_file_samii_frf_wrote(frf_clean, capsys):
    rc, _, _, out = frf_clean
    assert rc == 0
    assert main(["diagnose", str(out / "frf.csv"), "--json"]) == 0
    d = strict_json(capsys.readouterr().out)
    assert d["verdict"] == "none" and d["effects"] == []
    assert "coherence" in d["files"][0]["noise"]
    assert d["files"][0]["records"] is None


@pytest.mark.slow
def test_diagnose_against_a_saved_fit(saved_fit_diagnosis):
    """A fit of the delayed data, held fixed: what does the diagnosis make of it?

    samii fit fits act (theta/v) and base (xdd/theta), both noise-dominated above ~9 Hz
    (theta is small there), so mode 3 is not determined by these data, which the fit says
    itself (a caveat naming w3 and z3). The delay is absorbed into it (the act residual before the effects is a few
    degrees where act is usable, <= 8.6 Hz), but xdd/v, clean up to 40 Hz, is far off
    (chi2 ~ 7700 per residual). So the verdict is "effects" -- the saved fit does lack
    something -- but the effects found are the library's best patches for a distorted fit
    (valve, extra modes, an accelerometer gain seen: none of them in the rig). A command delay,
    if one is reported, is what the fit did not absorb: no more than the rig's 4 ms (2.2 ms seen; 4.66 ms beside a
    phase-leading pole/zero pair once each point's noise was stated without bias).
    """
    rc, text, err, fit_json, fit = saved_fit_diagnosis
    assert rc == 0, err
    # samii fit says itself that these data do not determine mode 3 (a caveat: the rest is to be used)
    assert fit["verdict"] == "caveats" and fit["undetermined"] == ["w3", "z3"]
    d = strict_json(text)
    assert d["simulator"] is None
    assert str(fit_json) in d["baseline"] and "held fixed" in d["baseline"]
    assert d["baseline_params"] is None  # a saved fit is not refitted
    assert any("do not determine w3, z3" in n for n in d["notes"])  # the report passes on what the fit says of itself
    assert d["verdict"] == "effects"
    before, after = d["error_before"], d["error_after"]
    assert before["total"]["chi2"] > 100  # the saved fit misses xdd/v
    assert before["act"]["chi2"] < 5  # ...but not theta/v where it is measured: the delay was absorbed
    assert after["total"]["chi2"] < before["total"]["chi2"]
    # against a fixed model that absorbed part of the delay, what it still lacks is the rest: no more lag than the rig's
    # 4 ms gives, with the phase lead of any pole/zero pair found beside it (zero below pole) counted against it (seen:
    # 4.66 ms beside a 20/36.6 Hz pair, a net lag of 1.1 ms at 1 Hz and 3.6 ms at 40 Hz)
    f = np.linspace(1.0, 40.0, 79)
    lag = np.zeros_like(f)
    for e in d["effects"]:
        if e["category"] == "delay" and e["kind"] == "command":
            assert e["params"]["delay_s"] > 0.0
            lag += 2 * np.pi * f * e["params"]["delay_s"]
        if e["kind"] == "pole_zero":
            lag += np.arctan(f / e["params"]["pole_hz"]) - np.arctan(f / e["params"]["zero_hz"])
    assert np.all(lag / (2 * np.pi * f) <= DELAY_S + 5e-4)


@pytest.mark.slow
def test_residual_left_in_xdd_v_is_reported_as_unexplained(saved_fit_diagnosis):
    rc, text, err, _, _ = saved_fit_diagnosis
    assert rc == 0, err
    d = strict_json(text)
    assert d["error_after"]["total"]["chi2"] > 10  # far above the noise after every effect found
    assert d["unexplained"], "a significant residual remains in xdd/v but no band is reported"


# --------------------------------------------------------------------------- bad input: exit 2, one line, nothing written


def _one_line_error(err: str, prog: str = "samii diagnose") -> str:
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert err.startswith(f"{prog}: error: "), err
    return err


@pytest.fixture(scope="module")
def zero_r_csv(tmp_path_factory):
    n = 5000
    t = np.arange(n) / FS
    rng = np.random.default_rng(0)
    rows = np.column_stack([t, 1e-3 * rng.standard_normal(n), 5e-4 * rng.standard_normal(n), 1e-2 * rng.standard_normal(n), np.zeros(n)])
    path = tmp_path_factory.mktemp("zero") / "zero_r.csv"
    path.write_text("t,v,theta,accel,r\n" + "\n".join(",".join(f"{x:.9g}" for x in row) for row in rows) + "\n")
    return path


@pytest.fixture()
def bad_inputs(tmp_path):
    d = tmp_path / "inputs"
    d.mkdir()
    (d / "notes.txt").write_text("this is not a fit\n")
    (d / "no_params.json").write_text(json.dumps({"structure": {"n_modes": 3, "numerator": "s4", "tie_mode2": True}}))
    return d


def _check_refused(capsys, argv, *needles, prog="samii diagnose"):
    assert main(argv) == 2, argv
    cap = capsys.readouterr()
    assert cap.out == ""
    err = _one_line_error(cap.err, prog)
    for n in needles:
        assert n in err, (n, err)
    return err


def test_diagnose_bad_input(cwd, out_dir, bad_inputs, clean_csv, zero_r_csv, capsys):
    before = snapshot(out_dir)
    out = ["--out", str(out_dir)]
    missing = bad_inputs / "missing.csv"
    _check_refused(capsys, ["diagnose", str(missing), *out], str(missing), "not found")
    _check_refused(capsys, ["diagnose", str(zero_r_csv), *out], str(zero_r_csv), "zero throughout")
    _check_refused(capsys, ["diagnose", str(clean_csv), "--model", str(bad_inputs / "notes.txt"), *out], "--model", "--baseline sim only")
    _check_refused(
        capsys, ["diagnose", str(clean_csv), "--baseline", "sim", "--model", str(bad_inputs / "notes.txt"), *out], "--model", "parameter file (.json"
    )
    notes = bad_inputs / "notes.txt"
    _check_refused(capsys, ["diagnose", str(clean_csv), "--baseline", str(notes), *out], str(notes), "not JSON")
    no_params = bad_inputs / "no_params.json"
    _check_refused(capsys, ["diagnose", str(clean_csv), "--baseline", str(no_params), *out], str(no_params), "'params'")
    _check_refused(capsys, ["diagnose", str(clean_csv), "--band-hz", "10", "1", *out], "--band-hz 10 1", "LO < HI")
    _check_refused(capsys, ["diagnose", str(clean_csv), str(clean_csv), *out], str(clean_csv), "more than once")
    assert snapshot(out_dir) == before  # the user's file only: no output, no staging folder
    assert list(cwd.iterdir()) == []
    assert sorted(p.name for p in bad_inputs.iterdir()) == ["no_params.json", "notes.txt"]


def test_frf_bad_input(cwd, out_dir, frf_clean, clean_csv, zero_r_csv, capsys):
    frf_csv = frf_clean[3] / "frf.csv"
    before = snapshot(out_dir)
    out = ["--out", str(out_dir)]
    _check_refused(capsys, ["frf", str(frf_csv), *out], str(frf_csv), "already a frequency response", prog="samii frf")
    _check_refused(capsys, ["frf", str(zero_r_csv), *out], str(zero_r_csv), "zero throughout", prog="samii frf")
    _check_refused(capsys, ["frf", str(clean_csv), "--band-hz", "10", "1", *out], "--band-hz 10 1", "LO < HI", prog="samii frf")
    _check_refused(capsys, ["frf", str(cwd / "missing.csv"), *out], "missing.csv", "not found", prog="samii frf")
    assert snapshot(out_dir) == before
    assert list(cwd.iterdir()) == []


def test_diagnose_same_file_under_two_names(clean_csv, cwd, monkeypatch, capsys):
    import samii.diagnose.diagnosis as diagnosis

    def must_not_run(*args, **kwargs):  # a refusal comes before any fitting; don't spend 10 s to show it doesn't
        raise RuntimeError("the diagnosis ran on the same file twice")

    monkeypatch.setattr(diagnosis, "diagnose", must_not_run)
    other = f"{clean_csv.parent}/./{clean_csv.name}"
    assert Path(other).samefile(clean_csv)
    rc = main(["diagnose", str(clean_csv), other])
    err = capsys.readouterr().err
    assert rc == 2, err
    _one_line_error(err)
    assert "more than once" in err


@pytest.mark.slow
def test_refused_what_a_rig_file_gets_wrong(clean_csv, frf_clean, tmp_path, capsys):
    """Mistakes users make with rig files, each refused in one line that says what to fix, where each was taken
    as data before: theta recorded with the opposite sign (the notebook's gains sat on their bounds and "modes"
    at 0.1 Hz were reported; the simulator calibrated to it diverged), time in milliseconds (a numpy message), a
    header whose record_s is the sweep's length (4 "records" of 60 s across 84 s repetitions, no note), time
    stamps rounded to single precision, and an FRF file whose phase is in radians."""
    from dataclasses import replace

    from samii.formats import read_timeseries_csv

    ts = read_timeseries_csv(clean_csv)

    def write(name, **changes):
        path = tmp_path / name
        write_timeseries_csv(replace(ts, **changes), path)
        return str(path)

    flipped = write("flipped.csv", theta=-ts.theta)
    _check_refused(capsys, ["diagnose", flipped], flipped, "theta/v's phase below 1 Hz is +", "opposite sign (multiply that column by -1)")
    in_ms = write("in_ms.csv", t=1e3 * ts.t)
    _check_refused(capsys, ["diagnose", in_ms], in_ms, "1 samples per second", "is t in milliseconds?")
    _check_refused(capsys, ["frf", in_ms, "--out", str(tmp_path / "x")], in_ms, "is t in milliseconds?", prog="samii frf")
    sweep_s = write("sweep_s.csv", metadata={**ts.metadata, "record_s": "60.4579"})
    _check_refused(capsys, ["diagnose", sweep_s], sweep_s, "the stated record_s (60.4579 s", "r repeats every 84.2")
    _check_refused(capsys, ["diagnose", str(clean_csv), "--record-s", "80"], str(clean_csv), "the stated record_s (80 s")
    single = tmp_path / "float32.csv"
    t32 = (ts.t + 100.0).astype(np.float32)
    single.write_text(
        "t,v,theta,accel,r\n"
        + "\n".join(f"{a:.9g},{b:.6g},{c:.6g},{d:.6g},{e:.6g}" for a, b, c, d, e in zip(t32, ts.v, ts.theta, ts.accel, ts.r))
        + "\n"
    )
    _check_refused(capsys, ["diagnose", str(single)], str(single), "7 significant digits (single precision)")
    frf = (frf_clean[3] / "frf.csv").read_text().splitlines()
    head = [i for i, line in enumerate(frf) if not line.startswith("#")][0]
    cols = frf[head].split(",")
    k = cols.index("act_phase_deg")
    rows = [line.split(",") for line in frf[head + 1 :]]
    for row in rows:
        row[k] = f"{math.radians(float(row[k])):.9g}"
    radians = tmp_path / "radians.csv"
    radians.write_text("\n".join(frf[: head + 1] + [",".join(row) for row in rows]) + "\n")
    for prog in ("diagnose", "fit"):
        _check_refused(capsys, [prog, str(radians)], str(radians), "'act_phase_deg'", "that is a phase in radians", prog=f"samii {prog}")


# --------------------------------------------------------------------------- noise-free data (issue 32 item 3)


@pytest.mark.slow
@pytest.mark.parametrize("effects, found", [({}, []), ({"command_delay_s": DELAY_S}, ["command"])], ids=["clean", "delay"])
def test_noise_free_data_are_said_so_and_judged_against_the_floor(tmp_path, sweep, effects, found, capsys):
    """A simulation without noise (as `samii measure` writes by default): its records repeat exactly, so the
    diagnosis says so and judges the data against the stated floor (0.5 % relative and the estimator's own
    bias) in place of a noise they do not have. Nothing is invented by a zero denominator: the clean rig
    gets no effect, the delayed one its delay, exactly."""
    ts = EffectRig(**effects).simulate(sweep[1], sample_rate_hz=FS)  # no rng: no noise
    path = tmp_path / "noise_free.csv"
    write_timeseries_csv(ts, path)
    # one run: the words on stdout, diagnosis.json in --out (what --json prints: test_diagnose_out_writes_the_report)
    assert main(["diagnose", str(path), "--no-progress", "--out", str(tmp_path / "d")]) == 0
    assert f"NO NOISE in {path}" in capsys.readouterr().out
    d = strict_json((tmp_path / "d" / "diagnosis.json").read_text())
    assert d["files"][0]["noise_free"] is True and "NO NOISE" in d["files"][0]["noise"]
    assert [e["kind"] for e in d["effects"]] == found and d["unexplained"] == []
    for ch, after in d["error_after"].items():
        assert after["chi2"] < 1.0, ch  # within the floor: nothing left to find
    if found:
        assert d["effects"][0]["params"]["delay_s"] == pytest.approx(DELAY_S, rel=1e-3)
