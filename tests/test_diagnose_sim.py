"""``samii diagnose --baseline sim`` (issue 11, item 5): the calibrated simulator as the model under
test, the effects found carried into it as physics, and its own error before and after.

The data are the simulator's own swept-sine measurements (``samii measure --noise``: 0.1 V, three
sign-alternating sweeps, seeded sensor noise) with an effect option the diagnosis is not told about, so
what it should find is known exactly:

- clean data, swept over the main job's 0.1-40 Hz (253 s): nothing found, nothing carried, the
  simulator's error at the noise (chi2 ~ 1; the record-to-record spread of 3 records runs ~20 % hot:
  measured 1.25 and 0.97, bound 1.6);
- a 4 ms command delay: found within 0.5 ms (the issue's tolerance), carried as
  ``hydraulic.command_delay``, the simulator's xdd/v chi2 falling from far above the noise to
  near it (measured 86 -> 0.87 on this seed; bounds > 20 before, < 2 after, and the rms phase
  error at least halved: 17.2 -> 3.0 deg);
- a 20 Hz first-order accelerometer roll-off: found within 15 % (the issue's tolerance for sensor
  corners), carried as ``sensor.accel_lowpass_hz``;
- a 0.5 kg body on a 15 Hz mount at the beam's end (``beam.tip_body_*``): found as an extra base
  mode within 2 % of the mode it adds (15.13 Hz, joint 2 held), carried as a body on the tip in
  the second round, the simulator's xdd/v chi2 falling to the noise;
- the valve's spool twice as slow: found as a real pole/zero pair, carried as the spool's time constant.

The effects are swept over 0.3-40 Hz (SWEEP: 161 s, issue 34's shorter records where the physics allows): each acts
well inside that band (the delay's and the corners' phase grows with frequency, the body's mode is at 15 Hz), and the
one thing that shows mostly below 0.3 Hz, the leak (0.199 1/s: test_diagnose_units; its phase 18 deg at 0.1 Hz, 6 deg
at 0.3 Hz), is the simulator's own: the clean case keeps the main job's band. Measured on six seeds each (3, 4, 5, 6,
26, 31) at 0.3-40 Hz, every assert below holds on all six: the delay 3.95-4.02 ms alone, xdd/v chi2 85-89 ->
0.87-1.08; the roll-off 19.93-20.28 Hz; the spool 8.85-9.00 ms alone, xdd/v chi2 19-21 -> 0.88-1.08; the body's mode
alone at 15.10-15.19 Hz, 0.43-0.49 kg carried, xdd/v chi2 1.9-2.2 -> 0.87-1.06.
From 0.5 Hz (143 s) seed 4 found an accelerometer gain beside the delay (1.003 +- 0.002, F 15.8) and beside the body
(0.988, with a second, broad "mode" at 12 Hz): not traced (stop 73's note); a band that starts above 0.3 Hz is not
the same test. experiments/sim_baseline_band/run.py measures these cases from any start frequency.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_diagnose_cli import run_cli

from samii.cli import main
from samii.closedloop.card import build_card_model
from samii.closedloop.controllers import notebook_cancel
from samii.closedloop.damping import sensors_from_diagnosis
from samii.closedloop.scenario import default_spec_factory
from samii.diagnose.diagnosis import diagnose
from samii.diagnose.files import simulator_params_text
from samii.json_output import dumps
from samii.measure.campaign import measure_swept
from samii.measure.daq import SensorNoise
from samii.measure.excitation import SweptSine
from samii.measure.measured import load
from samii.schema import document
from samii.sim.model import dotted, load_model, params_from_dict

#: The effects' sweep: 0.3-40 Hz, the rest as the main job's (module docstring).
SWEEP = SweptSine(start_hz=0.3)


def _measured(tmp_path_factory, name: str, overrides: dict, seed: int, sweep: SweptSine = SWEEP):
    path = tmp_path_factory.mktemp(name) / "timeseries.csv"
    model = load_model(overrides=overrides) if overrides else load_model()
    measure_swept(model, sweep, noise=SensorNoise(), rng=np.random.default_rng(seed), timeseries_path=path)
    return path


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return _measured(tmp_path_factory, "clean", {}, 3, SweptSine())


@pytest.fixture(scope="module")
def delayed(tmp_path_factory):
    return _measured(tmp_path_factory, "delay", {"hydraulic.command_delay": 0.004}, 3)


@pytest.fixture(scope="module")
def lowpass(tmp_path_factory):
    return _measured(tmp_path_factory, "lowpass", {"sensor.accel_lowpass_hz": 20.0}, 4)


@pytest.fixture(scope="module")
def delayed_diagnosis(delayed):
    """``diagnose`` of the 4 ms delay record against the simulator, once for the two tests that read it (11 s with its
    measurement in stop 74's run of the suite, in one process; 33-36 s on an earlier, slower machine with the 0.1-40 Hz
    record)."""
    return diagnose([load(delayed)], baseline="sim")


@pytest.fixture(scope="module")
def clean_cli(tmp_path_factory, clean):
    """``samii diagnose CLEAN --baseline sim --out DIR --rerun RRD --rerun-fps 10`` (text), once for the tests that
    read its folder, its recording or its words: (stdout, DIR, RRD). On two forked workers whatever the tests run on
    (conftest.py): the simulator's re-measurements, the forward selection's fits and the figures shared out, as on a
    user's machine; test_a_diagnosis_forked_is_the_same_as_in_one_process compares it with the command in one process."""
    root = tmp_path_factory.mktemp("clean_cli")
    out, rrd = root / "out", root / "rec" / "clean.rrd"
    rrd.parent.mkdir()
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SAMII_WORKERS", "2")
        rc, text, err = run_cli(
            ["diagnose", str(clean), "--baseline", "sim", "--out", str(out), "--rerun", str(rrd), "--rerun-fps", "10", "--no-progress"]
        )
    assert rc == 0, err
    return text, out, rrd


@pytest.fixture(scope="module")
def tip_body(tmp_path_factory):
    return _measured(tmp_path_factory, "tip_body", TIP_BODY, 31)


TIP_BODY = {"beam.tip_body_mass_kg": 0.5, "beam.tip_body_freq_hz": 15.0, "beam.tip_body_damping_ratio": 0.02}


@pytest.mark.slow
def test_clean_simulator_data_need_nothing(clean_cli):
    """Read from the command's diagnosis.json (``clean_cli``: the same ``diagnose`` of the same record, done once)."""
    _, out, _ = clean_cli
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["verdict"] == "none" and d["effects"] == []
    s = d["simulator"]
    assert s["carried"] == [] and s["changes"] == {}
    assert set(s["error_before"]) == set(s["error_after"]) == {"act", "base", "total"}
    for ch, e in s["error_after"].items():
        assert e["chi2"] < 1.6, (ch, e)


@pytest.mark.slow
def test_command_delay_found_carried_and_the_simulator_error_drops(delayed_diagnosis):
    d = delayed_diagnosis
    real = [e for e in d.effects if not e.expected]
    assert [(e.category, e.kind) for e in real] == [("delay", "command")]
    assert abs(real[0].params["delay_s"] - 0.004) < 5e-4
    s = d.simulator
    assert s.carried == ("delay/command",)
    assert abs(s.changes["hydraulic.command_delay"] - 0.004) < 5e-4
    before, after = s.error_before["total"], s.error_after["total"]
    assert before.chi2 > 20 and after.chi2 < 2.0 and after.rms_deg < before.rms_deg / 2
    assert d.error_after["total"].chi2 < d.error_before["total"].chi2


@pytest.mark.slow
def test_accelerometer_roll_off_found_and_carried(lowpass, tmp_path):
    d = diagnose([load(lowpass)], baseline="sim")
    real = [e for e in d.effects if not e.expected]
    assert ("sensor", "accel_lowpass") in [(e.category, e.kind) for e in real]
    e = next(e for e in real if e.kind == "accel_lowpass")
    assert abs(e.params["corner_hz"] / 20.0 - 1) < 0.15
    s = d.simulator
    assert "sensor/accel_lowpass" in s.carried
    assert s.error_after["total"].chi2 < s.error_before["total"].chi2
    # the simulator as diagnosed, as a parameter file (simulator_params.json of --out): a closed loop on it reads its
    # accelerometer through the roll-off found
    path = tmp_path / "simulator_params.json"
    path.write_text(simulator_params_text(s))
    assert "sensor.accel_lowpass_hz" in json.loads(path.read_text())["note"]
    spec, qpos, act = default_spec_factory(path)()
    cm = build_card_model(spec, notebook_cancel().controller, replaces_servo=True, home_qpos=qpos, home_act=act)
    assert abs(cm.sensors.accel_lowpass_hz / 20.0 - 1) < 0.15 and cm.layout.n_sensor_state > 0
    # and a damping design told the sensors by the diagnosis (samii design damping --sensors-from diagnosis.json)
    diag = tmp_path / "diagnosis.json"
    diag.write_text(dumps(document(d.record())))
    found = sensors_from_diagnosis(diag)
    assert set(found) >= {"sensor.accel_lowpass_hz"} and found["sensor.accel_lowpass_hz"] == s.changes["sensor.accel_lowpass_hz"]


@pytest.mark.slow
def test_a_diagnosis_forked_is_the_same_as_in_one_process(clean_cli, clean, tmp_path, monkeypatch):
    """``clean_cli`` ran on two forked workers; the same command in one process writes the same diagnosis.json, byte for
    byte (the simulator's re-measurements kept from the workers, the fits' results read back by reference)."""
    monkeypatch.setenv("SAMII_WORKERS", "1")
    out = tmp_path / "serial"
    rc, _, err = run_cli(["diagnose", str(clean), "--baseline", "sim", "--out", str(out), "--no-progress"])
    assert rc == 0, err
    assert (out / "diagnosis.json").read_bytes() == (clean_cli[1] / "diagnosis.json").read_bytes()


@pytest.mark.slow
def test_cli_baseline_sim_writes_the_simulator_block(clean_cli):
    text, out, _ = clean_cli
    assert "simulator: carried nothing" in text
    for name in ("diagnosis.json", "simulator.png", "bode.png", "residuals.png", "simulator_params.json"):
        assert (out / name).is_file(), name
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["verdict"] == "none" and d["simulator"]["changes"] == {}
    # the calibrated simulator, which every --model takes: its knobs as diagnosis.json reports them
    params = dotted(params_from_dict(json.loads((out / "simulator_params.json").read_text())["params"]))
    for name, value in d["simulator"]["calibration"]["after"]["values"].items():
        if not name.startswith("gain."):
            assert params[name] == pytest.approx(value, rel=1e-12), name


def test_carry_rules():
    """What is carried into the simulator, and how: a delay adds to the simulator's own, a gain
    error multiplies its gain, a corner beyond what the physics rate represents and a valve law
    without a level are not carried, with the reason."""
    from samii.diagnose.diagnosis import FoundEffect
    from samii.diagnose.simulator import carry, found_value
    from samii.sim.model import default_params, params_with_overrides

    p = params_with_overrides(default_params(), {"hydraulic.command_delay": 0.001, "sensor.accel_gain": 2.0})
    effects = [
        FoundEffect("delay", "command", "act", {"delay_s": 0.003}, {}, ""),
        FoundEffect("sensor", "accel_gain", "base", {"gain": 1.1}, {}, ""),
        FoundEffect("sensor", "accel_lowpass", "base", {"corner_hz": 900.0}, {}, ""),
        FoundEffect("nonlinear", "dead_band", "act", {"gain_change_db": 2.0}, {}, ""),
        FoundEffect("extra_mode", "act_mode", "act", {"freq_hz": 15.0}, {}, ""),
        FoundEffect("delay", "command", "act", {"delay_s": 0.0005}, {}, "", expected=True),
    ]
    options, carried, not_carried = carry(effects, p)
    assert options == pytest.approx({"hydraulic.command_delay": 0.004, "sensor.accel_gain": 2.2})
    assert carried == ["delay/command", "sensor/accel_gain"]
    text = " | ".join(not_carried)
    assert "accel_lowpass: 900 Hz is beyond" in text and "dead_band: no level" in text and "act_mode" in text
    assert found_value("hydraulic.command_delay", p, 0.0041, 1e-4) == pytest.approx((0.0031, 1e-4))
    assert found_value("sensor.accel_gain", p, 2.2, 0.02) == pytest.approx((1.1, 0.01))
    options, carried, not_carried = carry(
        [FoundEffect("nonlinear", "saturation", "act", {"saturation_v": 0.05}, {}, "")], p, refuse={"nonlinear/saturation": "no level"}
    )
    assert not options and not_carried == ["nonlinear/saturation: no level"]
    # valve dynamics: the spool (a first-order lag) takes the found lag's low-frequency group delay 2 zeta / omega
    tau0 = p.hydraulic.valve_time_constant
    options, carried, _ = carry([FoundEffect("actuator", "valve", "act", {"freq_hz": 50.0, "zeta": 0.7}, {}, "")], p)
    assert carried == ["actuator/valve"]
    assert options == pytest.approx({"hydraulic.valve_time_constant": tau0 + 1.4 / (2 * np.pi * 50.0)})
    # a real pole/zero pair is the ratio of two first-order spools, (1 + s tau0)/(1 + s tau): with its zero at the
    # simulator's corner the spool becomes 1/w_p exactly; a lead gives up lag, but the spool stays within its physical
    # limits (0.2-50 ms), and so does a lag (a pair at 0.3/0.4 Hz would be a 130 ms spool)
    w0 = 1.0 / tau0
    options, carried, _ = carry([FoundEffect("actuator", "pole_zero", "act", {"zero_hz": w0 / (2 * np.pi), "pole_hz": 10.0}, {}, "")], p)
    assert carried == ["actuator/pole_zero"]
    assert options == pytest.approx({"hydraulic.valve_time_constant": 1.0 / (2 * np.pi * 10.0)})
    options, carried, not_carried = carry([FoundEffect("actuator", "pole_zero", "act", {"zero_hz": 5.0, "pole_hz": 500.0}, {}, "")], p)
    assert not options and not carried and "outside 0.2-50 ms" in not_carried[0]
    options, carried, not_carried = carry([FoundEffect("actuator", "pole_zero", "act", {"zero_hz": 0.4, "pole_hz": 0.3}, {}, "")], p)
    assert not options and not carried and "outside 0.2-50 ms" in not_carried[0]
    # a gain asymmetry, found in excess of the simulator's own 2nd harmonic: the ratios c2/c1 add
    from samii.diagnose.nonlinear import asymmetry_fraction, asymmetry_ratio

    asym = FoundEffect("nonlinear", "asymmetry", "act", {"asymmetry_fraction": 0.1}, {}, "")
    options, carried, _ = carry([asym], p)
    assert carried == ["nonlinear/asymmetry"] and options == pytest.approx({"hydraulic.valve_asymmetry": 0.1})
    options, carried, _ = carry([asym], params_with_overrides(p, {"hydraulic.valve_asymmetry": 0.2}))
    assert options == pytest.approx({"hydraulic.valve_asymmetry": asymmetry_fraction(asymmetry_ratio(0.2) + asymmetry_ratio(0.1))})
    assert options["hydraulic.valve_asymmetry"] == pytest.approx(0.2814, abs=1e-4)  # ratios 4.72 % + 2.23 % (gains: 0.280)
    stronger = FoundEffect("nonlinear", "asymmetry", "act", {"asymmetry_fraction": -2.0}, {}, "")
    options, carried, not_carried = carry([stronger], params_with_overrides(p, {"hydraulic.valve_asymmetry": -0.8}))
    assert not options and "beyond" in not_carried[0]


@pytest.mark.slow
def test_extra_base_mode_found_and_carried_as_a_body_on_the_tip(tip_body):
    from samii.diagnose.simulator import body_effect_values
    from samii.sim.model import default_params, params_with_overrides

    truth, _ = body_effect_values(params_with_overrides(default_params(), TIP_BODY), {})
    d = diagnose([load(tip_body)], baseline="sim")
    real = [e for e in d.effects if not e.expected]
    assert [(e.category, e.kind) for e in real] == [("extra_mode", "base_mode")]
    assert abs(real[0].params["freq_hz"] / truth["freq_hz"] - 1) < 0.02
    assert "body on the beam's end" in real[0].evidence
    s = d.simulator
    assert s.carried == ("extra_mode/base_mode",)
    # measured on this seed: 0.468 kg carried (the mass is the least pinned of the three: 0.43-0.49 kg over six
    # seeds); xdd/v chi2 2.07 -> 1.06 (clean data at 0.3-40 Hz: 0.88-1.09 over the six seeds, at the noise)
    assert abs(s.changes["beam.tip_body_mass_kg"] / 0.5 - 1) < 0.3
    before, after = s.error_before["total"], s.error_after["total"]
    assert after.chi2 < before.chi2 and after.chi2 < 1.3


@pytest.fixture(scope="module")
def slow_spool(tmp_path_factory):
    return _measured(tmp_path_factory, "slow_spool", {"hydraulic.valve_time_constant": SLOW_SPOOL_S}, 26)


#: The valve's spool twice as slow as the embedded model's (4.48 ms, a 35.5 Hz first-order lag).
SLOW_SPOOL_S = 0.00897


@pytest.mark.slow
def test_a_slower_spool_is_found_and_carried_as_the_spool_s_time_constant(slow_spool):
    """Against the simulator a spool twice as slow is (1 + s tau0)/(1 + s tau): a real pole/zero pair, 35.5 Hz zero
    and 17.7 Hz pole. The first selection (what carries directly) imitates it by a theta delay, an accelerometer
    roll-off and a gain error; the pair is found after that carry, carried alone as the spool's time constant, and
    the imitations are not needed against it (measured on this seed: 9.00 ms carried, nothing else found; the
    simulator's xdd/v chi2 20.6 -> 0.89)."""
    d = diagnose([load(slow_spool)], baseline="sim")
    real = [e for e in d.effects if not e.expected]
    assert [(e.category, e.kind) for e in real] == [("actuator", "pole_zero")]
    assert real[0].params["spool_time_constant_s"] == pytest.approx(SLOW_SPOOL_S, rel=0.15)
    s = d.simulator
    assert s.carried == ("actuator/pole_zero",)
    assert s.changes["hydraulic.valve_time_constant"] == pytest.approx(SLOW_SPOOL_S, rel=0.15)
    before, after = s.error_before["total"], s.error_after["total"]
    assert before.chi2 > 5 and after.chi2 < 1.3


def test_an_extra_mode_becomes_a_body_of_the_mass_its_residue_needs():
    """The mass from a residue: the mode a 0.5 kg body on a 15 Hz mount adds, carried back into
    the simulator without it, gives the body back to first order in the mass (measured 0.491 kg);
    a residue of the other sign, a second body, or one beyond the physics rate are not carried."""
    from samii.diagnose.diagnosis import FoundEffect
    from samii.diagnose.simulator import BODY, body_effect_values, carry, tip_body_options
    from samii.sim.model import default_params, params_with_overrides

    p = default_params()
    values, _ = body_effect_values(params_with_overrides(p, TIP_BODY), {})
    assert values["freq_hz"] == pytest.approx(15.13, rel=2e-3)  # the mode, a little above the mount's own 15 Hz
    e = FoundEffect("extra_mode", "base_mode", "base", values, {}, "")
    options = tip_body_options(e, p)
    mass, freq, zeta = BODY["extra_mode/base_mode"]
    assert options[mass] == pytest.approx(0.5, rel=0.05)
    assert options[freq] == values["freq_hz"] and options[zeta] == values["zeta"]
    flipped = FoundEffect("extra_mode", "base_mode", "base", {**values, "residue": -values["residue"]}, {}, "")
    assert "sign of no body" in tip_body_options(flipped, p)
    assert "already has a body" in tip_body_options(e, params_with_overrides(p, TIP_BODY))
    fast = FoundEffect("extra_mode", "base_mode", "base", {**values, "freq_hz": 400.0}, {}, "")
    assert "beyond what the simulator's physics rate" in tip_body_options(fast, p)
    options, carried, not_carried = carry([e, e], p)
    assert carried == ["extra_mode/base_mode"] and "a second extra mode" in not_carried[0]
    # a heavily damped "mode" (proposed from data the simulator cannot represent: the second rig's 8 ms delay file,
    # 4.86 Hz at damping 0.41) is fitted over positive frequencies (its band had reached -4.8 Hz: a ValueError)
    broad = {"freq_hz": 4.86, "zeta": 0.41, "residue": 0.0049}  # (that file's residue: no body on the tip makes its sign)
    assert "sign of no body" in tip_body_options(FoundEffect("extra_mode", "base_mode", "base", broad, {}, ""), p)
    options = tip_body_options(FoundEffect("extra_mode", "base_mode", "base", {**broad, "residue": -1e-5}, {}, ""), p)
    assert options[mass] > 0 and options[freq] == 4.86 and options[zeta] == 0.41


@pytest.mark.slow
def test_the_simulators_own_harmonics_are_not_a_missing_nonlinearity(tmp_path_factory):
    """The simulator's orifice law makes harmonics of the sweep: at 0.3 V a 3rd harmonic beyond
    1 % near the hydraulic resonance, which the harmonic test claims on its own. Against the
    simulator (``--baseline sim``) they are its own, not something it lacks: tested in excess of the
    simulator measured like the file, nothing is claimed and a note says whose they are. A 20 mV
    dead band on top is still claimed, as a dead band, within 15 % of its level."""
    from samii.diagnose.nonlinear import find_nonlinear
    from samii.diagnose.simulator import measured_like
    from samii.sim.model import default_params

    sweep = SweptSine(amplitude_v=0.3)
    clean = tmp_path_factory.mktemp("own") / "clean.csv"
    measure_swept(load_model(), sweep, noise=SensorNoise(), rng=np.random.default_rng(7), timeseries_path=clean)
    m = load(clean)
    alone, _, _, _ = find_nonlinear([m])
    assert alone, "the orifice's harmonics at 0.3 V should be claimed without a reference"
    ref = measured_like(default_params(), m)
    found, notes, _, _ = find_nonlinear([m], references=[ref], reference_label="the simulator's own harmonics")
    assert not found
    assert any("the simulator's own harmonics" in n for n in notes), notes

    band = tmp_path_factory.mktemp("own") / "dead_band.csv"
    measure_swept(
        load_model(overrides={"hydraulic.valve_dead_band": 0.02}), sweep, noise=SensorNoise(), rng=np.random.default_rng(8), timeseries_path=band
    )
    m = load(band)
    found, _, _, _ = find_nonlinear([m], references=[measured_like(default_params(), m)], reference_label="the simulator's own harmonics")
    assert [f.kind for f in found] == ["dead_band"]
    assert abs(found[0].params["dead_band_v"] / 0.02 - 1) < 0.15
    assert "in excess of the simulator's own harmonics" in found[0].evidence


def _recorded(path, runs, keys=("volts/r", "accel_m_s2/accel")):
    from samii.viz.recording import read_scalars

    got = read_scalars(path, [f"/{r}/{k}" for r in runs for k in keys])
    return {(r, k): got.get(f"/{r}/{k}") for r in runs for k in keys}


@pytest.mark.slow
def test_recording_of_the_simulator_against_the_data(delayed_diagnosis, tmp_path):
    """``--rerun``: the file's record beside the simulator measured like it, before and after the
    4 ms delay was carried; the same excitation at the same times (the file's sweep from its
    metadata), and the base acceleration's residual against the data falling with the delay
    carried (measured 0.038 -> 0.010 m/s^2 rms, the data's noise)."""
    from samii.diagnose.recording import write_diagnosis_recording

    d = delayed_diagnosis
    rrd = tmp_path / "d.rrd"
    info = write_diagnosis_recording(rrd, d, fps=10, thin=False)  # every sample, to compare them (thinned: samii.viz.thinning)
    assert info.runs == ("data", "simulator_after", "simulator_before")
    s = _recorded(rrd, info.runs)
    (td, rd), (ta, ra), (tb, rb) = (s[(r, "volts/r")] for r in info.runs)
    n = len(tb)
    assert len(ta) == n and n < len(td) and np.allclose(td[:n], tb) and np.allclose(ta, tb)  # 2 of the file's 3 sweeps
    assert np.max(np.abs(rd[:n] - rb)) < 1e-6 and np.max(np.abs(rd[:n] - ra)) < 1e-6
    data = s[("data", "accel_m_s2/accel")][1][:n]
    before = np.sqrt(np.mean((data - s[("simulator_before", "accel_m_s2/accel")][1]) ** 2))
    after = np.sqrt(np.mean((data - s[("simulator_after", "accel_m_s2/accel")][1]) ** 2))
    assert after < 0.6 * before, (before, after)
    import rerun.chunk as rc

    entities = {str(c.entity_path) for c in rc.RrdReader(str(rrd)).store().stream()}
    assert not any(e.startswith("/data/deformed") for e in entities)  # measured data: no joint positions, no 3D
    assert "/simulator_after/deformed/beam_4" in entities and "/simulator_before/true_scale/link2" in entities
    # the modal coordinates of the simulator after the carry (the first run with joint positions), only there
    assert "/simulator_after/displacement_mm/mode_1" in entities and "/simulator_before/displacement_mm/mode_1" not in entities


@pytest.mark.slow
def test_cli_records_the_simulator_against_clean_data(clean_cli):
    text, _, rrd = clean_cli
    assert f"wrote {rrd}" in text
    s = _recorded(rrd, ("data", "simulator_before", "simulator_after"), keys=("volts/r",))
    assert s[("data", "volts/r")] is not None and s[("simulator_before", "volts/r")] is not None
    assert s[("simulator_after", "volts/r")] is None  # nothing carried: no second simulator
    assert [p.name for p in rrd.parent.iterdir()] == [rrd.name]  # no temporary file left beside it


def test_cli_recording_needs_the_simulator(clean, tmp_path, capsys):
    rrd = tmp_path / "x.rrd"
    assert main(["diagnose", str(clean), "--rerun", str(rrd), "--no-progress"]) == 2
    assert "--baseline sim" in capsys.readouterr().err and not rrd.exists()
    assert main(["diagnose", str(clean), "--baseline", "sim", "--rerun-fps", "10", "--no-progress"]) == 2
    assert "--rerun" in capsys.readouterr().err


def test_the_data_sweep_frequency_from_the_file(delayed, tmp_path):
    """The data's sweep frequency in a recording is the one its header states, over all its sweeps,
    and a record whose time does not start at 0 is drawn from its first sample (as the simulator's)."""
    from dataclasses import replace

    from samii.diagnose.recording import _from_zero, _sweep_hz

    ts = load(delayed).timeseries
    f = _sweep_hz(ts)
    lead, record = float(ts.metadata["lead_s"]), float(ts.metadata["record_s"])
    assert int(float(ts.metadata["repetitions"])) == 3
    assert np.isnan(f[ts.t < lead - 0.01]).all() and np.isfinite(f[(ts.t > lead + 0.01) & (ts.t < lead + record - 25)]).all()
    assert np.isfinite(f[ts.t > lead + 2 * record + 1.0]).any()  # the third sweep too
    assert np.nanmax(f) == pytest.approx(float(ts.metadata["stop_hz"]), rel=0.01)
    assert float(ts.metadata["start_hz"]) == SWEEP.start_hz and np.nanmin(f) == pytest.approx(SWEEP.start_hz, rel=1e-9)  # (the fade's)
    later = replace(ts, t=ts.t + 100.0)
    assert np.allclose(_sweep_hz(later), f, rtol=1e-9, equal_nan=True)
    assert np.allclose(_from_zero(later).t, ts.t, atol=1e-9) and _from_zero(ts) is ts


def test_recalibration_bounds_stay_about_the_starting_simulator(delayed):
    """A recalibration's knob ranges are a factor 10 about the simulator the diagnosis started
    from (``anchor``), not about the previous calibration's result: chained, the spans compounded
    and took hydraulic.total_volume to 1/120 of nominal, where the simulator diverged."""
    from samii.calibrate.simulator import parameter_value
    from samii.diagnose.simulator import calibrate_simulator
    from samii.sim.model import default_params, params_with_overrides

    m = load(delayed)
    nominal = default_params()
    v0 = parameter_value(nominal, "hydraulic.total_volume")
    bent = params_with_overrides(nominal, {"hydraulic.total_volume": v0 / 8})
    free = calibrate_simulator(m, start=bent, max_nfev=1).result.bounds["hydraulic.total_volume"]
    anchored = calibrate_simulator(m, start=bent, max_nfev=1, anchor={"hydraulic.total_volume": v0}).result
    assert free == pytest.approx((v0 / 80, v0 * 10 / 8))
    assert anchored.bounds["hydraulic.total_volume"] == pytest.approx((v0 / 10, v0 * 10))
    assert anchored.values["hydraulic.total_volume"] >= v0 / 10 * (1 - 1e-9)


def test_misfits_say_where_and_by_how_much_the_simulator_misses():
    """Issue 31 item 4: before carrying anything, where the calibrated simulator misses the data beyond their noise and
    floor, band by band, with its size. Residuals drawn at each point's stated error find no band; 2 dB and 10 deg
    added to theta/v (and so xdd/v) over 2-5 Hz come back as that band, that size (above ~9 Hz theta is noisy at
    0.1 V: there 2 dB on theta/v is within its noise, and only xdd/v shows it)."""
    from samii.diagnose.model import Dataset
    from samii.diagnose.rig import EffectRig
    from samii.diagnose.simulator import misfits
    from samii.measure.measured import from_timeseries

    fs = 1000.0
    sw = SweptSine(start_hz=1.0, stop_hz=40.0, seconds_per_octave=2.0, repetitions=3)
    r = sw.signal(np.arange(int(round(sw.duration_s * fs))) / fs)
    ds = Dataset.from_measured(from_timeseries(EffectRig().simulate(r, sample_rate_hz=fs, rng=np.random.default_rng(5)), source="rig.csv"))
    rng = np.random.default_rng(6)
    noise = {
        ch: (rng.standard_normal(ds.data[ch].size) + 1j * rng.standard_normal(ds.data[ch].size)) / ds.inv_sigma[ch] / np.sqrt(2) for ch in ds.data
    }
    assert misfits([ds], [noise]) == ()
    miss = np.log(10 ** (2.0 / 20)) + 1j * np.radians(10.0)
    res = {
        ch: e + (miss * ((ds.freq_hz[ds.keep[ch]] >= 2) & (ds.freq_hz[ds.keep[ch]] <= 5)) if ch in ("act", "total") else 0) for ch, e in noise.items()
    }
    found = {m.channel: m for m in misfits([ds], [res])}
    assert set(found) <= {"act", "total"} and "act" in found
    for m in found.values():
        assert 1.5 <= m.lo_hz <= 2.3 and 4.5 <= m.hi_hz <= 6.5, m  # (the test's windows reach a few points past)
        assert 1.4 < m.rms_db < 2.4 and 7.0 < m.rms_deg < 12.0, m
        assert m.text().startswith(("theta/v", "xdd/v")) and "dB" in m.text()


def test_the_verdict_says_when_a_carry_makes_the_simulator_worse():
    """Issue 31 item 4: never report a carry that makes rms dB, rms deg or chi2 worse on a channel without saying so."""
    from samii.diagnose.diagnosis import ChannelError
    from samii.diagnose.simulator import Misfit, SimulatorReport

    before = {"act": ChannelError(2.36, 20.2, 262.0, 233), "total": ChannelError(5.08, 18.7, 1004.0, 168)}
    after = {"act": ChannelError(2.83, 20.1, 43.8, 233), "total": ChannelError(2.12, 12.1, 154.0, 168)}
    cannot = (Misfit("f.csv", "act", 10.0, 40.0, 7.8, 73.0, 900.0, 60),)
    s = SimulatorReport(before, after, {}, ("delay/theta_sensor",), (), None, None, (), (), misfit_after=cannot)
    assert s.worse == ["theta/v rms dB 2.36 -> 2.83 dB"]
    text = s.verdict_text()
    assert "cannot represent the data at theta/v 10-40 Hz" in text and "worse: theta/v rms dB 2.36 -> 2.83 dB" in text
    quiet = SimulatorReport(before, before, {}, (), (), None, None, (), ())
    assert quiet.worse == [] and quiet.verdict_text() == ""


def test_a_carry_the_simulator_cannot_run_is_not_carried_and_says_why(monkeypatch):
    """--baseline sim: when the simulator with an effect carried diverges as it is measured like the file (a tip body
    proposed from data the simulator cannot represent, on the second rig's 8 ms delay file), nothing is carried and the
    reason is given; the diagnosis goes on (it ended with SimulationUnstable, exit 3)."""
    from types import SimpleNamespace

    from samii.diagnose import simulator
    from samii.errors import SimulationUnstable

    def diverges(params, m):
        raise SimulationUnstable("simulation diverged before t = 20 s (mjWARN_BADQACC); no result written")

    monkeypatch.setattr(simulator, "carry", lambda effects, params, refuse=None: ({"beam.tip_body_mass_kg": 40.0}, ["extra_mode/base_mode"], []))
    monkeypatch.setattr(simulator, "params_with_overrides", lambda params, options: params)
    monkeypatch.setattr(simulator, "correction", diverges)
    before = SimpleNamespace(params="calibrated", result=SimpleNamespace(start={}))
    body = SimpleNamespace(category="extra_mode", kind="base_mode")
    out, options, carried, not_carried = simulator.carry_and_recalibrate([SimpleNamespace(source="rig.csv")], [None], before, [body])
    assert out is before and options == {} and carried == []
    assert not_carried == [
        "extra_mode/base_mode: the simulator with it carried diverges when measured like rig.csv "
        "(simulation diverged before t = 20 s (mjWARN_BADQACC); no result written)"
    ]


@pytest.mark.slow
def test_with_nothing_carried_the_second_selection_is_against_the_first_selections_simulator(monkeypatch):
    """Issue 31 item 4, on data the simulator cannot represent (the battery's second rig: eq 9.4 under a digital loop,
    a 2 ms command delay; three 20 s sweeps here). Nothing is carried, so the second selection must run against the
    simulator of the first, with the correction its knobs were calibrated with. With the correction recomputed at the
    calibrated knobs (bent far: the simulator misses these data by 4-9 dB) the baseline no longer matched them, and
    the error after came out 2-5x the error before on every channel (theta/v chi2 532 -> 2309), a 2 ms delay missed.
    Here with no kind in the library (the selections add nothing) the error after is the error before, exactly."""
    from test_diagnose_second_rig import _second_rig

    from samii.diagnose import diagnosis
    from samii.measure.measured import from_timeseries
    from samii.timeseries import TimeSeries

    sr = _second_rig()
    fs = 1000.0
    rng = np.random.default_rng(1100)
    r, _ = sr.swept_sine(fs, direction="up", n_records=3, sweep_s=20.0, rest_s=0.0, amplitude_v=0.1)
    d = sr.Rig.drawn(rng, spread=0.15, fs=fs, command_delay_s=0.002).simulate(r, fs, rng=rng)
    m = from_timeseries(TimeSeries(t=d["t"], v=d["v"], theta=d["theta"], accel=d["accel"], r=d["r"]), source="second rig")
    monkeypatch.setattr(diagnosis, "_kinds", lambda *a, **k: [])
    dg = diagnosis.diagnose([m], baseline="sim")
    assert dg.simulator.carried == () and dg.effects == ()
    assert dg.simulator.misfit_before  # (the simulator cannot represent these data, and says where)
    for ch, before in dg.error_before.items():
        assert dg.error_after[ch].chi2 == pytest.approx(before.chi2, rel=1e-9), ch
