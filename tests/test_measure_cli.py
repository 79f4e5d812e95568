"""``samii measure``: outputs, run.json, overwrite rules, Rerun recording."""

import json

import numpy as np
import pytest

from samii.sim.model import default_params

pytest.importorskip("mujoco")

from samii.cli import main  # noqa: E402
from samii.formats import read_frf_csv, read_timeseries_csv  # noqa: E402


@pytest.mark.slow
def test_default_run_writes_everything(tmp_path, capsys):
    out = tmp_path / "m"
    assert main(["measure", "--out", str(out), "--no-progress"]) == 0
    for name in ("timeseries.csv", "frf.csv", "bode.png", "run.json"):
        assert (out / name).is_file(), name
    frf = read_frf_csv(out / "frf.csv")
    assert frf.channels == ("act", "base", "total") and frf.act_coh is not None
    assert frf.freq_hz[0] == pytest.approx(0.1, rel=0.05) and frf.freq_hz[-1] == pytest.approx(40.0, rel=0.01)
    ts = read_timeseries_csv(out / "timeseries.csv")
    assert ts.sample_rate_hz == pytest.approx(1000.0) and ts.r is not None and ts.p_load is not None
    assert ts.metadata["amplitude_v"] == "0.1"
    run = json.loads((out / "run.json").read_text())
    assert run["excitation"]["swept"]["repetitions"] == 3
    assert run["daq"]["seed"] == 0 and run["daq"]["sensor_noise"] is None
    assert run["model"]["timestep_s"] == pytest.approx(0.001) and run["model"]["params"]["beam"] == default_params().as_dict()["beam"]
    assert "mujoco" in run["versions"] and run["timing"]["real_time_factor"] > 10
    for ch in ("act", "base", "total"):  # the bounds, at the default amplitude too
        assert run["vs_linearised_simulator_0.5_35_hz"][ch]["max_abs_db"] < 1.0
    text = capsys.readouterr().out
    assert "x real time" in text and "wrote" in text
    # a second run refuses to overwrite, before simulating anything
    assert main(["measure", "--out", str(out), "--no-progress"]) == 2
    assert "--overwrite" in capsys.readouterr().err


@pytest.mark.slow
def test_stepped_with_noise_rerun_and_overwrite(tmp_path, capsys):
    out = tmp_path / "s"
    rrd = tmp_path / "run.rrd"
    args = [
        "measure",
        "--out",
        str(out),
        "--method",
        "stepped",
        "--freqs-hz",
        "9",
        "3",
        "--noise",
        "--seed",
        "5",
        "--no-progress",
        "--rerun",
        str(rrd),
        "--json",
    ]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["excitation"]["stepped"]["freqs_hz"] == [9.0, 3.0]
    assert summary["daq"]["sensor_noise"]["theta_rad"] == pytest.approx(5e-4)
    frf = read_frf_csv(out / "frf.csv")
    np.testing.assert_allclose(frf.freq_hz, [3.0, 9.0])
    assert rrd.stat().st_size > 100_000
    first = (out / "frf.csv").read_text()
    assert main(args + ["--overwrite"]) == 0  # same seed: same numbers
    capsys.readouterr()
    assert (out / "frf.csv").read_text() == first


def test_bad_arguments(tmp_path, capsys):
    assert main(["measure", "--out", str(tmp_path / "x"), "--sample-rate-hz", "300", "--no-progress"]) == 2
    assert "physics rate" in capsys.readouterr().err
    assert main(["measure", "--out", str(tmp_path / "y"), "--band-hz", "40", "1", "--no-progress"]) == 2
    assert "--band-hz 40 1: expected LO < HI" in capsys.readouterr().err
    assert main(["measure", "--amplitude-v", "-1"]) == 2  # argparse: rejected before anything runs


@pytest.mark.slow
def test_load_pressure_above_supply_is_reported(tmp_path, capsys):
    """Issue 8: at 5 V and 5 Hz the motor pumps the load pressure past the 7 MPa supply (7.7 MPa);
    the run says so. At 3 Hz it stays below (3 MPa) and says nothing."""
    out = tmp_path / "m5"
    assert main(["measure", "--out", str(out), "--no-progress", "--amplitude-v", "5", "--freqs-hz", "5", "--method", "stepped"]) == 0
    text = capsys.readouterr().out
    run = json.loads((out / "run.json").read_text())
    assert run["peaks"]["load_pressure_pa"] > run["model"]["hydraulic"]["supply_pressure"]
    assert "warning: stepped run: the load pressure reached" in text and "lower --amplitude-v" in text
    assert run["warnings"]
    # bounded by the open valve's reverse flow: within 20 % of supply, not the 9 MPa of a cut-off law
    assert run["peaks"]["load_pressure_pa"] < 1.2 * run["model"]["hydraulic"]["supply_pressure"]
    low = tmp_path / "m3"
    assert main(["measure", "--out", str(low), "--no-progress", "--amplitude-v", "5", "--freqs-hz", "3", "--method", "stepped"]) == 0
    assert "warning" not in capsys.readouterr().out
    assert "warnings" not in json.loads((low / "run.json").read_text())
