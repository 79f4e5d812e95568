"""Bad inputs and misuses of the commands built on the simulator (issue 9).

Every case runs in-process through ``samii.cli.main`` and must: return the stated exit
code (2 bad input, 3 unstable simulation), print exactly one line on stderr that names the
option or file, print no traceback, and leave an existing output folder exactly as it was.
The design and fit commands have their own batteries (test_design_hardening.py,
test_fit_hardening.py), the file readers theirs (test_io_hardening.py).
"""

from __future__ import annotations

import os
import sys

import pytest

from samii.cli import main

# ---------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    f = {
        "malformed_xml": "<mujoco><worldbody><body><geom size='1'/>",
        "empty": "",
        "no_plugin_xml": "<mujoco><worldbody><body><joint/><geom size='1'/></body></worldbody></mujoco>",
        "binary": b"\x00\xff\xfe\x00garbage\x89PNG",
        "bad_json": "{not json",
        "params_wrong_shape": '{"beam": {}}',
        "params_bad_value": '{"params": {"beam": {"length_m": -3}}}',
        "params_unknown": '{"params": {"beam": {"nonsense": 1}}}',
        "frf_text": "freq_hz,act_mag\n1,1\n2,1\n",
        "params_null": '{"params": {"hydraulic": {"bulk_modulus": null}}}',
        "params_string": '{"params": {"beam": {"length_m": "4.3"}}}',
        "params_deep": "[" * 100000 + "]" * 100000,
        "params_section_list": '{"params": {"beam": [1, 2]}}',
        "params_partial": '{"params": {"beam": {"length_m": 4.3}, "arm": {}, "timestep_s": 0.001}}',
        "params_negative_bulk": None,
    }
    import json as _json

    from samii.sim.model import default_params

    full = default_params().as_dict()
    full["hydraulic"]["bulk_modulus"] = -7e8
    f["params_negative_bulk"] = _json.dumps({"params": full})
    out = {}
    for name, text in f.items():
        suffix = (
            ".xml" if name.endswith("xml") or name in ("empty", "binary") else (".json" if "json" in name or name.startswith("params") else ".csv")
        )
        p = d / f"{name}{suffix}"
        p.write_bytes(text if isinstance(text, bytes) else text.encode())
        out[name] = str(p)
    out["dir"] = str(d)
    out["missing"] = str(d / "missing.xml")
    out["missing_json"] = str(d / "missing.json")
    a_file = d / "a_file.txt"
    a_file.write_text("x")
    out["a_file"] = str(a_file)
    return out


def _snapshot(folder) -> dict:
    return {p: (os.path.getsize(os.path.join(folder, p)), os.path.getmtime(os.path.join(folder, p))) for p in sorted(os.listdir(folder))}


def _run_bad(argv, capsys, code, needle, out_dir=None):
    before = _snapshot(out_dir) if out_dir is not None else None
    rc = main(argv)
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert rc == code, (argv, rc, cap.err)
    assert "Traceback" not in cap.err, cap.err
    assert len(lines) == 1, (argv, cap.err)
    assert needle.lower() in lines[0].lower(), (argv, needle, lines[0])
    assert "np.float64" not in lines[0]
    if out_dir is not None:
        assert _snapshot(out_dir) == before, (argv, os.listdir(out_dir))
    return lines[0]


# ---------------------------------------------------------------------------- the command itself

TOP = [
    (["nonsense"], "invalid choice"),
    (["--bogus"], "unrecognized option --bogus"),
    (["modes", "--bogus"], "unrecognized option --bogus"),
    # a misspelling is named with the closest option, before the required option it displaced
    (["closedloop", "--controller", "unity", "--scenerio", "step"], "unrecognized option --scenerio: did you mean --scenario?"),
    # no abbreviations: --amplitude is not silently --amplitude-v
    (["measure", "--amplitude", "0.5"], "unrecognized option --amplitude: did you mean --amplitude-v?"),
    (["run", "--sed=1"], "did you mean --seed?"),
    (["mesure"], "did you mean 'measure'?"),
    (["design", "rootlocus"], "did you mean 'rlocus'?"),
]


@pytest.mark.parametrize("argv, needle", TOP, ids=[" ".join(a) for a, _ in TOP])
def test_top_level(argv, needle, capsys):
    _run_bad(argv, capsys, 2, needle)


def test_version_and_help_exit_zero(capsys):
    from importlib import metadata

    import samii

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"samii {samii.__version__}"
    # the package's version is the installed distribution's (pyproject.toml's): the two cannot drift apart
    assert samii.__version__ == metadata.version("samii")
    assert main(["measure", "--help"]) == 0


# ---------------------------------------------------------------------------- overrides and models (shared by modes, measure)

BAD_SETS = [
    ("hydraulic.nonsense=1", "has no parameter"),
    ("hydraulic.bulk_modulus=-7e8", "bulk_modulus"),
    ("hydraulic.bulk_modulus=0", "bulk_modulus"),
    ("hydraulic.bulk_modulus=nan", "finite"),
    ("hydraulic.supply_pressure=inf", "finite"),
    ("beam.length_m=-1", "length_m"),
    ("beam.n_segments=0", "n_segments"),
    ("beam.n_segments=2.5", "whole number"),
    ("timestep_s=-0.001", "timestep_s"),
    ("timestep_s=0.5", "timestep_s"),
    ("beam.pitch_deg=120", "pitch_deg"),
    ("beam.accel_body_fixed=0.5", "accel_body_fixed"),
    ("nonsense.x=1", "expected 'beam.<name>'"),
    ("justaname", "NAME=VALUE"),
    ("=3", "NAME=VALUE"),
    ("beam.length_m=abc", "not a number"),
    ("hydraulic.valve_time_constant=-1", "valve_time_constant"),
    ("beam.n_segments=100000", "n_segments"),
    ("hydraulic.position_gain=1e9", "too stiff for the step"),
    ("hydraulic.reference_angle=100", "does not come to rest"),
    ("arm.held_armature_kgm2=-1", "held_armature_kgm2"),
    ("arm.joint1_stiffness_Nm_rad=0", "joint1_stiffness"),
    ("arm.heading_deg=1000", "heading_deg"),
]

BAD_MODELS = [
    ("malformed_xml", "not a valid MJCF"),
    ("empty", "not a valid MJCF"),
    ("no_plugin_xml", "no actuator named"),
    ("binary", "not a valid MJCF"),
    ("dir", "not a regular file"),
    ("missing", "does not exist"),
    ("missing_json", "does not exist"),
    ("bad_json", "not valid JSON"),
    ("params_wrong_shape", "'params' object"),
    ("params_bad_value", "length_m"),
    ("params_unknown", "nonsense"),
    ("params_null", "finite number"),
    ("params_string", "finite number"),
    ("params_deep", "nested too deeply"),
    ("params_section_list", "must be an object"),
    ("params_partial", "missing"),
    ("params_negative_bulk", "bulk_modulus"),
]


@pytest.mark.parametrize("item, needle", BAD_SETS, ids=[s for s, _ in BAD_SETS])
def test_modes_bad_set(item, needle, capsys):
    _run_bad(["modes", "--set", item], capsys, 2, needle)


@pytest.mark.parametrize("key, needle", BAD_MODELS, ids=[k for k, _ in BAD_MODELS])
def test_modes_bad_model(files, key, needle, capsys):
    line = _run_bad(["modes", "--model", files[key]], capsys, 2, needle)
    if key not in ("dir",):
        assert os.path.basename(files[key]) in line  # names the file


@pytest.mark.parametrize("value", ["-1", "0", "nan", "inf", "abc"])
def test_modes_bad_max_freq(value, capsys):
    _run_bad(["modes", "--max-freq-hz", value], capsys, 2, "--max-freq-hz")


def test_modes_set_given_twice(capsys):
    _run_bad(["modes", "--set", "beam.length_m=4", "--set", "beam.length_m=5"], capsys, 2, "given twice")


# ---------------------------------------------------------------------------- params


@pytest.mark.parametrize(
    "key, needle",
    [
        ("malformed_xml", "parameter file"),
        ("missing_json", "does not exist"),
        ("bad_json", "not valid JSON"),
        ("params_null", "finite number"),
        ("params_deep", "nested too deeply"),
        ("params_partial", "missing"),
        ("params_negative_bulk", "bulk_modulus"),
    ],
)
def test_params_bad_model(files, key, needle, capsys):
    _run_bad(["params", "--model", files[key]], capsys, 2, needle)


def test_params_empty_model_path(capsys):
    _run_bad(["params", "--model", ""], capsys, 2, "--model")


def test_modes_marks_an_unstable_loop(capsys):
    """A servo gain of 300 V/rad destabilises two coupled pairs: listed, marked, and stable = false in JSON."""
    import json

    assert main(["modes", "--set", "hydraulic.position_gain=300"]) == 0
    text = capsys.readouterr().out
    assert text.count("UNSTABLE") >= 3  # two marked poles and the verdict
    assert main(["modes", "--json", "--set", "hydraulic.position_gain=300"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["stable"] is False and all(p[0] > 0 for p in rep["unstable_poles"])
    assert main(["modes", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stable"] is True


def test_params_lists_every_set_name(capsys):
    assert main(["params", "--json"]) == 0
    import json

    rows = json.loads(capsys.readouterr().out)
    names = {r["name"] for r in rows}
    assert {"beam.length_m", "hydraulic.bulk_modulus", "timestep_s", "arm.joint1_stiffness_Nm_rad"} <= names
    assert all(r["unit"] for r in rows)  # every parameter has a unit
    # every listed name is accepted by --set with its own value
    from samii.sim.model import default_params, params_with_overrides

    params_with_overrides(default_params(), {r["name"]: r["value"] for r in rows})


# ---------------------------------------------------------------------------- measure

MEASURE = [
    (["--amplitude-v", "20"], "--amplitude-v"),
    (["--amplitude-v", "1e6"], "--amplitude-v"),
    (["--amplitude-v", "0"], "--amplitude-v"),
    (["--amplitude-v", "1e-300"], "--amplitude-v"),
    (["--amplitude-v", "-1"], "--amplitude-v"),
    (["--amplitude-v", "nan"], "--amplitude-v"),
    (["--seed", "-1"], "--seed"),
    (["--seed", "1.5"], "--seed"),
    (["--seed", "abc"], "--seed"),
    (["--tail-s", "1e9"], "3600 s"),
    (["--tail-s", "0"], "--tail-s"),
    (["--tail-s", "-1"], "--tail-s"),
    (["--tail-s", "nan"], "--tail-s"),
    (["--method", "stepped", "--freqs-hz", "1e-7"], "3600 s"),
    (["--method", "stepped", "--freqs-hz", "600"], "anti-alias"),
    (["--method", "stepped", "--freqs-hz", "5", "5"], "more than once"),
    (["--method", "stepped", "--freqs-hz", "0"], "--freqs-hz"),
    (["--method", "stepped", "--freqs-hz", "-3"], "--freqs-hz"),
    (["--method", "stepped", "--freqs-hz", "nan"], "--freqs-hz"),
    (["--method", "both", "--freqs-hz", "300"], "anti-alias"),
    (["--band-hz", "5", "1"], "LO < HI"),
    (["--band-hz", "0.1", "2000"], "anti-alias"),
    (["--band-hz", "0", "40"], "--band-hz"),
    (["--band-hz", "nan", "40"], "--band-hz"),
    (["--band-hz", "1"], "--band-hz"),
    (["--sample-rate-hz", "50"], "anti-alias"),
    (["--sample-rate-hz", "300"], "physics rate"),
    (["--sample-rate-hz", "3000"], "physics rate"),
    (["--sample-rate-hz", "0"], "--sample-rate-hz"),
    (["--sample-rate-hz", "-1"], "--sample-rate-hz"),
    (["--sample-rate-hz", "nan"], "--sample-rate-hz"),
    (["--averages", "0"], "--averages"),
    (["--averages", "-1"], "--averages"),
    (["--averages", "2.5"], "--averages"),
    (["--averages", "1000"], "--averages"),
    (["--method", "bogus"], "--method"),
    (["--freqs-hz", "5"], "--method stepped or both"),
    (["--set", "hydraulic.nonsense=1"], "has no parameter"),
    (["--set", "beam.n_segments=2.5"], "whole number"),
    (["--set", "timestep_s=-0.001"], "timestep_s"),
    (["--set", "hydraulic.bulk_modulus=nan"], "finite"),
]


@pytest.mark.parametrize("extra, needle", MEASURE, ids=[" ".join(a) for a, _ in MEASURE])
def test_measure_bad_option(extra, needle, out_dir, capsys):
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", *extra], capsys, 2, needle, out_dir)


@pytest.mark.parametrize("key, needle", BAD_MODELS[:6], ids=[k for k, _ in BAD_MODELS[:6]])
def test_measure_bad_model(files, key, needle, out_dir, capsys):
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--model", files[key]], capsys, 2, needle, out_dir)


def test_measure_out_paths(files, tmp_path, capsys):
    _run_bad(["measure", "--out", "", "--no-progress"], capsys, 2, "--out")
    _run_bad(["measure", "--out", "   ", "--no-progress"], capsys, 2, "--out")
    _run_bad(["measure", "--out", files["a_file"], "--no-progress"], capsys, 2, "not a folder")
    _run_bad(["measure", "--out", os.path.join(files["a_file"], "sub"), "--no-progress"], capsys, 2, "which is a file")
    assert not (tmp_path / "never").exists()


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root may write into a read-only folder")
def test_measure_out_read_only(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        _run_bad(["measure", "--out", str(ro / "sub"), "--no-progress"], capsys, 2, "not writable")
    finally:
        ro.chmod(0o700)


def test_measure_rerun_paths(files, out_dir, capsys):
    # a missing folder is created (test_closedloop_rerun_into_a_new_folder_creates_it); a file in its way is refused
    _run_bad(
        ["measure", "--out", str(out_dir), "--no-progress", "--rerun", os.path.join(files["a_file"], "nope", "x.rrd")],
        capsys,
        2,
        "which is a file",
        out_dir,
    )
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--rerun", files["dir"]], capsys, 2, "is a folder", out_dir)
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--rerun", ""], capsys, 2, "--rerun", out_dir)
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--rerun", files["a_file"]], capsys, 2, "--overwrite", out_dir)


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs /proc")
def test_measure_unwritable_pseudo_filesystem(out_dir, capsys):
    """/proc passes a permission check for root but refuses new files: the check creates a probe file."""
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--rerun", "/proc/x.rrd"], capsys, 2, "not writable", out_dir)
    _run_bad(["measure", "--out", "/proc/samii_out", "--no-progress"], capsys, 2, "not writable")


def test_measure_rerun_into_its_own_outputs(out_dir, capsys):
    """--rerun D/frf.csv with --out D would put the recording where the FRF goes: refused before any work."""
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--rerun", str(out_dir / "frf.csv")], capsys, 2, "own output", out_dir)
    _run_bad(
        ["measure", "--out", str(out_dir), "--no-progress", "--overwrite", "--rerun", str(out_dir / "run.json")], capsys, 2, "own output", out_dir
    )


def test_measure_out_dangling_link_and_folder_named_like_an_output(tmp_path, out_dir, capsys):
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "nowhere")
    _run_bad(["measure", "--out", str(link), "--no-progress"], capsys, 2, "symbolic link")
    (out_dir / "frf.csv").mkdir()
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--overwrite"], capsys, 2, "is a folder", out_dir)


def test_measure_existing_outputs_need_overwrite(out_dir, capsys):
    (out_dir / "frf.csv").write_text("the user's earlier result")
    line = _run_bad(["measure", "--out", str(out_dir), "--no-progress"], capsys, 2, "--overwrite", out_dir)
    assert "frf.csv" in line


def test_measure_unstable_servo_loop_is_exit_3(out_dir, capsys):
    """A servo gain of 1e5 V/rad: the loop oscillates on its own at the valve rails; not data."""
    line = _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--set", "hydraulic.position_gain=1e5"], capsys, 3, "unstable", out_dir)
    assert "Hz" in line


def test_measure_failure_while_writing_leaves_nothing(out_dir, capsys, monkeypatch):
    """A full disk (or any failure) after the simulation: no partial folder, the user's file untouched."""
    import errno

    import samii.formats as formats

    def full_disk(*_a, **_k):
        raise OSError(errno.ENOSPC, "No space left on device", "frf.csv")

    monkeypatch.setattr(formats, "write_frf_csv", full_disk)
    _run_bad(["measure", "--out", str(out_dir), "--no-progress", "--method", "stepped", "--freqs-hz", "20"], capsys, 2, "space", out_dir)
    assert not [p for p in os.listdir(out_dir) if p.startswith(".samii-stage")]


def test_measure_failure_in_a_new_folder_removes_it(tmp_path, capsys, monkeypatch):
    import samii.formats as formats

    monkeypatch.setattr(formats, "write_frf_csv", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt()))
    target = tmp_path / "new" / "deeper"
    assert main(["measure", "--out", str(target), "--no-progress", "--method", "stepped", "--freqs-hz", "20"]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


# ---------------------------------------------------------------------------- calibrate

CALIBRATE = [
    (["--param", "beam.nonsense"], "has no parameter"),
    (["--param", "hydraulic.total_volume", "--phase-weight", "nan"], "--phase-weight"),
    (["--param", "hydraulic.total_volume", "--phase-weight", "-1"], "--phase-weight"),
    (["--param", "hydraulic.total_volume", "--phase-weight", "1e300"], "--phase-weight"),
    (["--param", "hydraulic.total_volume", "--band-hz", "5", "1"], "LO < HI"),
    (["--param", "hydraulic.total_volume", "--band-hz", "nan", "1"], "--band-hz"),
    (["--param", "hydraulic.total_volume", "--max-iterations", "0"], "--max-iterations"),
    (["--param", "hydraulic.total_volume", "--max-iterations", "1.5"], "--max-iterations"),
    (["--param", "hydraulic.total_volume", "--bound", "hydraulic.total_volume=5:1"], "LO < HI"),
    (["--param", "hydraulic.total_volume", "--bound", "hydraulic.total_volume=a:b"], "numbers"),
    (["--param", "hydraulic.total_volume", "--bound", "hydraulic.total_volume=nan:1"], "LO < HI"),
    (["--param", "hydraulic.total_volume", "--start", "hydraulic.total_volume=nan"], "finite"),
    (["--param", "hydraulic.total_volume", "--start", "novalue"], "NAME=VALUE"),
    (["--param", "hydraulic.total_volume", "--weighting", "bogus"], "--weighting"),
    (["--param", "hydraulic.total_volume", "--set", "beam.length_m=-1"], "length_m"),
    (["--param", "hydraulic.total_volume", "--out", ""], "--out"),
    (["--param", "hydraulic.total_volume", "--channels", "bogus"], "--channels"),
    (["--param", "hydraulic.total_volume", "--channels", ","], "--channels"),
    (["--param", "hydraulic.total_volume", "--channels", "act,act"], "--channels"),
    (["--param", "hydraulic.total_volume", "--channels", "total"], "no total channel"),
]


@pytest.fixture(scope="module")
def frf_csv(tmp_path_factory):
    from samii.calibrate.calibrate_file import load_target
    from samii.formats import write_frf_csv

    return str(write_frf_csv(load_target("eq9.4"), tmp_path_factory.mktemp("frf") / "frf.csv"))


@pytest.mark.parametrize("extra, needle", CALIBRATE, ids=[" ".join(a) for a, _ in CALIBRATE])
def test_calibrate_bad_option(frf_csv, extra, needle, out_dir, capsys):
    _run_bad(["calibrate", frf_csv, *extra], capsys, 2, needle)


@pytest.mark.parametrize(
    "key, needle", [("missing", "no such file"), ("dir", "no such file"), ("malformed_xml", "expected an FRF CSV"), ("frf_text", "frf_text.csv")]
)
def test_calibrate_bad_data(files, key, needle, capsys):
    _run_bad(["calibrate", files[key], "--param", "hydraulic.total_volume"], capsys, 2, needle)


def test_calibrate_out_is_a_file(frf_csv, files, capsys):
    _run_bad(["calibrate", frf_csv, "--param", "hydraulic.total_volume", "--out", files["a_file"]], capsys, 2, "not a folder")


def test_calibrate_mjcf_model_refused(frf_csv, files, capsys):
    _run_bad(["calibrate", frf_csv, "--param", "hydraulic.total_volume", "--model", files["malformed_xml"]], capsys, 2, "parameter file")


# ---------------------------------------------------------------------------- signals (a real process)


def _spawn_measure(out, *extra):
    import subprocess

    code = "import sys; from samii.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.Popen(
        [sys.executable, "-c", code, "measure", "--out", str(out), "--no-progress", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


@pytest.mark.slow
@pytest.mark.parametrize("signame, code", [("SIGTERM", 143), ("SIGINT", 130), ("SIGHUP", 129)])
def test_signal_mid_run_leaves_nothing(tmp_path, signame, code):
    """Killed while simulating: one line, exit 128 + N (130 for Ctrl-C), no folder, no temp file."""
    import signal
    import time

    out = tmp_path / "m"
    proc = _spawn_measure(out, "--averages", "6")
    deadline = time.time() + 60
    while not out.exists() and time.time() < deadline:  # the folder appears when the simulation starts
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(getattr(signal, signame))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert not out.exists(), list(out.iterdir())
    assert not list(tmp_path.glob("**/*.tmp"))


def test_ctrl_c_during_start_up(tmp_path):
    """Ctrl-C while the command is still importing its stage (mujoco, scipy): one line, 130, nothing made."""
    import signal
    import time

    out = tmp_path / "m"
    proc = _spawn_measure(out)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert "Traceback" not in err, err
    assert proc.returncode == 130, err  # the run lasts about 4 s: 0.3 s in, it is still starting
    assert len([ln for ln in err.splitlines() if ln.strip()]) == 1, err
    assert not out.exists()


def test_frf_records_metadata_is_checked(tmp_path, capsys):
    """'# frf_records:' sets the random error every residual is judged against: an absurd count is refused."""
    import dataclasses

    import numpy as np

    from samii.formats import write_frf_csv
    from samii.identify.studies import synthetic_rig_frf

    data = synthetic_rig_frf(np.geomspace(0.1, 40.0, 200), rng=np.random.default_rng(0))  # with coherence
    for bad in ("1000000000000", "nan", "0"):
        damaged = dataclasses.replace(data, metadata={**data.metadata, "frf_records": bad})
        path = write_frf_csv(damaged, tmp_path / f"frf_{bad}.csv")
        _run_bad(["fit", str(path), "--no-progress"], capsys, 2, "frf_records")


def test_stale_stage_of_a_killed_run_is_removed(tmp_path, capsys):
    """SIGKILL cannot be handled: its staging folder stays until the next run into the same folder removes it."""
    from samii.outputs import OutputFolder

    out = tmp_path / "o"
    out.mkdir()
    stale = out / ".samii-stage-999999999-dead"  # no such process
    stale.mkdir()
    (stale / ".timeseries.csv.999999999.abc.tmp").write_bytes(b"x" * 1000)
    live = out / f".samii-stage-{os.getpid()}-live"  # this process: kept
    live.mkdir()
    with OutputFolder(out, ["a.txt"], overwrite=False) as folder:
        folder.path("a.txt").write_text("ok")
    assert not stale.exists() and live.exists()
    assert sorted(p.name for p in out.iterdir()) == sorted(["a.txt", live.name])


def test_concurrent_runs_never_mix(tmp_path):
    """Two runs into one folder: the folder ends with the whole set of one of them."""
    from samii.errors import InputError
    from samii.outputs import OutputFolder

    out = tmp_path / "o"
    names = ["a.txt", "b.txt"]
    first = OutputFolder(out, names, overwrite=True)
    second = OutputFolder(out, names, overwrite=True)
    with first as f1:
        with second as f2:
            for n in names:
                f2.path(n).write_text("second")
        for n in names:
            f1.path(n).write_text("first")
    assert {(out / n).read_text() for n in names} == {"first"}
    # without --overwrite the later run finds the names taken at commit and writes nothing
    a = OutputFolder(tmp_path / "p", names, overwrite=False)
    b = OutputFolder(tmp_path / "p", names, overwrite=False)
    with a as fa:
        for n in names:
            fa.path(n).write_text("a")
    with pytest.raises(InputError, match="--overwrite"):
        with b as fb:
            for n in names:
                fb.path(n).write_text("b")
    assert {(tmp_path / "p" / n).read_text() for n in names} == {"a"}
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == names


def test_broken_pipe_is_quiet(capsys, monkeypatch):
    """`samii params | head -1`: the reader leaves, stdout raises BrokenPipeError; exit 0, nothing on stderr."""
    import io

    class ClosedPipe(io.StringIO):
        def write(self, _text):
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert main(["params"]) == 0
    assert capsys.readouterr().err == ""


def test_ctrl_c_swallowed_by_a_library_still_stops_the_run(tmp_path, capsys, monkeypatch):
    """A Ctrl-C whose KeyboardInterrupt library code swallowed (an optional import in a bare ``except``) still
    counts: the run's outputs are not committed, exit 130 (CI once saw a start-up Ctrl-C lost this way)."""
    import samii.closedloop.scenario as scenario_module
    from samii.cli import main
    from samii.errors import SIGNALS_RECEIVED

    original = scenario_module.run_closed_loop

    def interrupted_run(*args, **kwargs):
        result = original(*args, **kwargs)
        SIGNALS_RECEIVED.append(2)  # the handler ran; its exception never reached samii
        return result

    monkeypatch.setattr(scenario_module, "run_closed_loop", interrupted_run)
    out = tmp_path / "cl"
    rc = main(["closedloop", "--controller", "unity", "--scenario", "step", "--duration-s", "3", "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err
    assert rc == 130, err
    assert "interrupted" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    assert not SIGNALS_RECEIVED  # (the command's own: the caller's next library call is not stopped by it)
