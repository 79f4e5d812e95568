"""``samii fit``: reads a DATA_FORMATS FRF CSV, fits, prints JSON, writes its folder."""

import json

import numpy as np
import pytest

from samii import notebook as nb
from samii.cli import main
from samii.identify import ModelStructure, synthesize
from samii.identify.studies import from_notebook_units
from samii.measure.io import write_frf_csv

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
    with pytest.raises(SystemExit):
        main(["fit", str(bad), "--phase-weights", "a,b"])
