"""``samii fit``: reads a DATA_FORMATS FRF CSV, fits, prints JSON, writes its folder."""

import json

import numpy as np
import pytest

from samii import notebook as nb
from samii.cli import main
from samii.formats import write_frf_csv
from samii.identify import ModelStructure, synthesize
from samii.identify.studies import from_notebook_units

F_HZ = np.geomspace(0.1, 40.0, 300)
SI_EQ9_4 = from_notebook_units(nb.EQ9_4)  # the data are SI (theta in rad)


@pytest.fixture(scope="module")
def frf_csv(tmp_path_factory):
    st = ModelStructure.notebook_3mode()
    data = synthesize(F_HZ, {c: st.response(SI_EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=None)
    return write_frf_csv(data, tmp_path_factory.mktemp("frf") / "eq9_4.csv")


def test_json_recovers_the_notebook_parameters(frf_csv, capsys):
    assert main(["fit", str(frf_csv), "--json", "--start", "notebook"]) == 0
    d = json.loads(capsys.readouterr().out)
    for key in ("params", "stderr", "cost", "rms_mag_db", "rms_phase_deg", "converged", "message"):
        assert key in d
    assert list(d["params"]) == list(nb.NAMES_3MODE)
    for k, v in SI_EQ9_4.items():
        assert d["params"][k] == pytest.approx(v, rel=1e-6), k  # CSV rounds to 10 digits
    assert set(d["rms_mag_db"]) == {"act", "base"} and d["rms_mag_db"]["act"] < 1e-6
    assert d["converged"] is True


def test_two_mode_band_fit_and_sweep_folder(frf_csv, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["fit", str(frf_csv), "--modes", "2", "--band-hz", "1", "12", "--phase-weights", "0,0.1", "--out", str(out), "--json"]) == 0
    fits = json.loads(capsys.readouterr().out)
    assert [f["phase_weight"] for f in fits] == [0.0, 0.1]
    assert list(fits[0]["params"]) == list(nb.NAMES_2MODE)
    assert any(w.startswith("tau") and "outside" in w for w in fits[0]["warnings"])  # the valve lag is beyond 12 Hz
    names = sorted(p.name for p in out.iterdir())
    assert names == ["bode_fit.png", "fit_pw0.1.json", "fit_pw0.json", "parameters.png"]
    saved = json.loads((out / "fit_pw0.json").read_text())
    assert saved["band_hz"][0] >= 1.0 and saved["band_hz"][1] <= 12.0
    assert saved["structure"]["w2_factors"] is True  # eq 1.2 convention for 2 modes
    # a second run does not overwrite the folder
    assert main(["fit", str(frf_csv), "--modes", "2", "--phase-weights", "0,0.1", "--out", str(out)]) == 2
    assert "overwrite" in capsys.readouterr().err


def test_bad_input_gives_one_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("freq_hz,act_mag,act_phase_deg\n1,1,0\n0.5,1,0\n")
    assert main(["fit", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and "samii fit: error" in err
    assert main(["fit", str(tmp_path / "missing.csv")]) == 2
    assert main(["fit", str(bad), "--phase-weights", "a,b"]) == 2  # argparse: rejected before anything runs
    assert "--phase-weights" in capsys.readouterr().err


@pytest.fixture(scope="module")
def noisy_csv(tmp_path_factory):
    from samii.identify import SweptSineNoise

    st = ModelStructure.notebook_3mode()
    data = synthesize(F_HZ, {c: st.response(SI_EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(3))
    return write_frf_csv(data, tmp_path_factory.mktemp("frf") / "eq9_4_noisy.csv")


def test_json_reports_weighting_and_lack_of_fit(noisy_csv, capsys):
    assert main(["fit", str(noisy_csv), "--json", "--weighting", "coherence", "--start", "auto"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["weighting"] == "coherence"
    assert d["lack_of_fit"]["found"] is False and d["lack_of_fit"]["n_averages"] == 3  # synthesize writes frf_records
    assert main(["fit", str(noisy_csv), "--modes", "2", "--start", "auto"]) == 0  # mode 3 (25 Hz) missing
    out = capsys.readouterr().out
    assert "weighting coherence (points weighted by their predicted random error), chosen by --weighting auto" in out
    assert "lack of fit: FOUND" in out and "warning: lack of fit in xdd/theta (base)" in out


def test_coherence_weighting_needs_coherence(tmp_path, capsys):
    st = ModelStructure.notebook_3mode()
    from samii import FrequencyResponse

    data = FrequencyResponse(F_HZ, act=st.response(SI_EQ9_4, F_HZ, "act"), base=st.response(SI_EQ9_4, F_HZ, "base"))
    path = write_frf_csv(data, tmp_path / "nocoh.csv")
    assert main(["fit", str(path), "--weighting", "coherence"]) == 2
    err = capsys.readouterr().err
    assert "nocoh.csv" in err and "coherence" in err


def test_actuator_only_file_fits_the_actuator(tmp_path, capsys):
    from samii import FrequencyResponse

    st = ModelStructure.notebook_3mode()
    path = write_frf_csv(FrequencyResponse(F_HZ, act=st.response(SI_EQ9_4, F_HZ, "act")), tmp_path / "act_only.csv")
    assert main(["fit", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["not_fitted"] == ["w1", "z1", "w3", "z3", "B1", "B2", "B3"]
    assert all(d["params"][k] is None and d["stderr"][k] is None for k in d["not_fitted"])
    assert d["params"]["wp"] == pytest.approx(SI_EQ9_4["wp"], rel=1e-6)
    assert main(["fit", str(path)]) == 0
    out = capsys.readouterr().out
    assert "act_only.csv has no base channel" in out and "not fitted" in out


@pytest.mark.slow
def test_more_modes_than_the_notebook_has(frf_csv, capsys):
    assert main(["fit", str(frf_csv), "--modes", "4", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert "notebook start skipped" in d["message"] and list(d["params"])[-1] == "B4"
