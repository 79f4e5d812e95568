"""samii's own stepped-sine time series read back by frf and diagnose (issue 36, F10), and a stepped sine's noise.

`samii measure --method stepped` writes timeseries.csv with its schedule in the header (freqs_hz, settle_s, ramp_s,
measure_cycles, measure_s, lead_s); frf and diagnose said "the excitation r does not repeat" and, given --record-s,
"r has no energy at ...": DATA_FORMATS says samii's own data can be fed back in like measured data. Each dwell's
window is now estimated as the measurement did (samii.measure.measured.from_stepped).

A dwell's coherence is its sine fit's residual over thousands of samples, ``g = |Y|^2/(|Y|^2 + 4 s^2/N)``, so the
relative error's variance is ``(1 - g)/g``: read as 3 averages and pooled over nine dwells the observed error was
0.000x to 42x the stated one in a 12-seed Monte Carlo of six dwells (0.5-35 Hz); as ``(1 - g)/g`` 0.5-1.7x wherever
the response stands above the noise (xdd at 0.5 Hz does not: coherence 0.06-0.6, its phase random).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_diagnose_cli import run_cli

from samii.formats import read_frf_csv
from samii.measure.measured import from_frf, load


@pytest.fixture(scope="module")
def stepped(tmp_path_factory):
    root = tmp_path_factory.mktemp("stepped_ts")
    rc, _, err = run_cli(
        [
            "measure",
            "--method",
            "stepped",
            "--freqs-hz",
            "0.5",
            "2",
            "8",
            "20",
            "35",
            "--noise",
            "--seed",
            "3",
            "--out",
            str(root / "m"),
            "--no-progress",
        ]
    )
    assert rc == 0, err
    return root, root / "m" / "timeseries.csv", root / "m" / "frf.csv"


@pytest.fixture(scope="module")
def default_stepped(tmp_path_factory):
    """``samii measure --method stepped --noise --seed 3`` (the default 17 dwells), once for the tests that read it:
    its folder."""
    m = tmp_path_factory.mktemp("default_stepped") / "m"
    rc, _, err = run_cli(["measure", "--method", "stepped", "--noise", "--seed", "3", "--out", str(m), "--no-progress"])
    assert rc == 0, err
    return m


def test_frf_reads_samiis_stepped_time_series_as_the_measurement_did(stepped):
    root, ts, written = stepped
    rc, out, err = run_cli(["frf", str(ts), "--out", str(root / "frf"), "--json"])
    assert rc == 0, err
    info = json.loads(out)
    assert info["records"] is None and info["dwells"] == 5 and "stepped sine of 5 dwells" in info["noise"]
    again, measured = read_frf_csv(root / "frf" / "frf.csv"), read_frf_csv(written)
    assert np.allclose(again.freq_hz, measured.freq_hz)
    for ch in ("act", "base", "total"):
        assert np.allclose(getattr(again, ch), getattr(measured, ch), rtol=1e-8), ch  # (the CSV's 10 digits)
        assert np.allclose(again.coherence(ch), measured.coherence(ch), atol=1e-9), ch


@pytest.mark.slow
def test_diagnose_reads_a_stepped_time_series_as_its_frf_file(stepped):
    _, ts, written = stepped
    a, b = load(ts), load(written)
    assert a.layout is None and a.sample_rate_hz == 1000.0
    for ch in ("act", "base", "total"):
        assert np.allclose(a.var[ch], b.var[ch], rtol=1e-6), ch
    rc, out, err = run_cli(["diagnose", str(ts), "--no-progress"])
    assert rc == 0, err
    assert "stepped sine of 5 dwells" in out and "verdict:" in out


def test_a_stepped_sines_error_is_its_dwells_own_not_three_averages_pooled(stepped):
    """The relative error's variance of a point is (1 - g)/g of its own coherence (module docstring): not halved as
    3 averages, not pooled with dwells a decade away."""
    frf = read_frf_csv(stepped[2])
    m = from_frf(frf, source="s.csv")
    for ch in ("act", "base", "total"):
        g = frf.coherence(ch)
        assert np.allclose(m.var[ch], (1.0 - g) / g, rtol=1e-9), ch
    assert "each dwell's sine fit" in m.noise_source and "averages" not in m.noise_source


def test_a_stepped_time_series_without_its_schedule_or_cut_short_is_refused_naming_what(stepped, tmp_path):
    _, ts, _ = stepped
    lines = ts.read_text().splitlines()
    no_settle = tmp_path / "no_settle.csv"
    no_settle.write_text("\n".join(ln for ln in lines if not ln.startswith("# settle_s:")) + "\n")
    rc, _, err = run_cli(["frf", str(no_settle), "--out", str(tmp_path / "o1")])
    assert rc == 2 and "stepped sine but has no '# settle_s:' line" in err and str(no_settle) in err, err
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[: len(lines) - 20000]) + "\n")  # the last 20 s: the 35 Hz dwell's window
    rc, _, err = run_cli(["diagnose", str(short), "--no-progress"])
    assert rc == 2 and "before the measurement window of the dwell(s) at 35 Hz" in err and str(short) in err, err
    assert not (tmp_path / "o1").exists()


@pytest.mark.slow
def test_effects_found_with_the_residual_still_far_above_the_noise_are_not_called_the_whole_story(default_stepped, tmp_path):
    """The default stepped sine (17 dwells, 0.5-35 Hz, seed 3): one effect (the 32 Hz valve lag) and chi2 per residual
    33 after it, with no band of misfit on so few points; the verdict read "effects: 1 effect(s) the model lacks" as if
    it explained the data. The rule is even_misfit's, the one a verdict of none already obeyed. One run gives the words
    (stdout) and diagnosis.json (--out; what --json prints: test_diagnose_cli's test_diagnose_out_writes_the_report)."""
    rc, out, err = run_cli(["diagnose", str(default_stepped / "timeseries.csv"), "--no-progress", "--out", str(tmp_path / "d")])
    assert rc == 0, err
    d = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    real = [e for e in d["effects"] if not e.get("expected")]
    assert real and not d["unexplained"]
    note = [n for n in d["notes"] if n.startswith("after the effects found the residual stays above the noise")]
    assert len(note) == 1 and "not explained" in note[0]
    verdict = next(ln for ln in out.splitlines() if ln.startswith("verdict:"))
    assert verdict.endswith("but the residual stays above the noise after them (note below)"), verdict


@pytest.mark.slow
def test_the_default_stepped_sine_finds_the_pair_mode_3_makes_in_theta_v(default_stepped):
    """The default stepped sine (17 dwells, 3 Hz apart at 22-25 Hz) measures theta/v's pole and zero of the simulator's
    base mode 3 (pole 23.3 Hz with the loop closed, zero at the held-joint mode 24.90 Hz: samii modes), +3.9 dB at
    22 Hz and -6.4 dB at 25 Hz with errors of about 2 %. The pair was refused as closer than the dwells' spacing (a rule
    for a swept sine's noise wiggle) and the diagnosis ended on the valve alone at chi2 33 per residual. The points
    either side show it: it joins, at the simulator's frequencies, and the baseline's mode 3 stays the held joint's."""
    rc, out, err = run_cli(["diagnose", str(default_stepped / "frf.csv"), "--json", "--no-progress"])
    assert rc == 0, err
    d = json.loads(out)
    found = {e["kind"]: e["params"] for e in d["effects"]}
    assert {"valve", "act_mode"} <= set(found), found
    # samii modes on the embedded model: mode 3 at 23.32 Hz with the servo loop closed, 24.90 Hz with joint 2 held; the
    # oil column's pair at 31.74 Hz (what the valve kind reads)
    assert found["act_mode"]["freq_hz"] == pytest.approx(23.32, rel=0.03)
    assert found["act_mode"]["zero_freq_hz"] == pytest.approx(24.90, rel=0.03)
    assert found["valve"]["freq_hz"] == pytest.approx(31.74, rel=0.05)
    assert d["baseline_params"][0]["w3"] / (2 * np.pi) == pytest.approx(24.90, rel=0.03)
    # 29.3: this command's chi2 per degree of freedom after the valve alone, measured (stop 45) before the spacing rule
    # let the pair join; with the pair it was 8.8. (The docstring's 33 is per residual, on the time series.)
    assert d["chi2_per_dof"]["after"] < 0.5 * 29.3


def test_a_pair_closer_than_the_spacing_is_resolved_only_by_standard_errors_of_the_datas_own_noise():
    """The spacing rule (an actuator mode's pole and zero closer than the data's frequency spacing: a noise wiggle) gives
    way where the pair's separation stands 3 joint standard errors clear and the noise is the data's own (records or
    coherence); a mode narrower than half the spacing stays unresolved whatever its errors."""
    from samii.diagnose.effects import LIBRARY, Effect
    from samii.diagnose.model import Dataset
    from samii.diagnose.select import _unresolved_mode

    kind = next(k for k in LIBRARY if k.label == "extra_mode/act_mode")
    f = np.array([14.0, 18.0, 22.0, 25.0, 28.0, 35.0])  # the default stepped sine's dwells there: 3 Hz apart at 22-25 Hz

    def ds(known: bool) -> Dataset:
        keep = {"act": np.ones(f.size, bool)}
        return Dataset("st.csv", f, {"act": np.ones(f.size, complex)}, keep, {"act": np.ones(f.size)}, known, 1.0, 0.1)

    values = {"freq_hz": 23.52, "zeta": 0.038, "zero_freq_hz": 24.88, "zero_zeta": 0.026}
    pair = Effect(kind, values, {"freq_hz": 0.055, "zeta": 0.002, "zero_freq_hz": 0.16, "zero_zeta": 0.003})  # 8 joint SE apart
    loose = Effect(kind, values, {"freq_hz": 0.3, "zeta": 0.002, "zero_freq_hz": 0.4, "zero_zeta": 0.003})  # 2.7 joint SE
    assert not _unresolved_mode(pair, [ds(True)])
    assert _unresolved_mode(pair, [ds(False)])  # the noise read off the residual's roughness: its errors are not trusted
    assert _unresolved_mode(loose, [ds(True)])
    narrow = Effect(kind, dict(values, zeta=0.01), pair.stderr)  # 2 zeta f = 0.47 Hz under half the 3 Hz spacing
    assert _unresolved_mode(narrow, [ds(True)])
