"""The main job off the embedded model (issue 32 item 1): on rigs of the same class with other physical
parameters and other noise seeds, the summary is right: the fit finds the simulator's own modes and says
what its data do not determine, its verdict is a caveat and not a failure, and the damping controller
designed from the measurement still damps the base.

The truth of each rig is what `samii modes` gives for it (the linearised simulator with joint 2 held, and
the servo loop's lightly damped pair), which the main job's summary carries."""

from __future__ import annotations

import json
import math

import pytest

from samii.cli import main

RIGS = [
    # the README's --set example (clamp 2e5: base modes 1.94 / 9.91 / 25.6 Hz), on which the fit once laid the
    # hydraulic pair on base mode 1
    (1, ["beam.clamp_stiffness_Nm_rad=2e5"]),
    # more oil (a softer hydraulic pair) on a shorter beam (mode 3 at 29 Hz), another seed
    (2, ["hydraulic.total_volume=1.2e-5", "beam.length_m=3.9"]),
]


@pytest.mark.slow
@pytest.mark.parametrize("seed, sets", RIGS, ids=["clamp2e5-seed1", "volume-length-seed2"])
def test_main_job_holds_on_another_rig(tmp_path, capsys, seed, sets):
    argv = ["run", "--out", str(tmp_path / "r"), "--seed", str(seed), "--no-progress"] + [a for s in sets for a in ("--set", s)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    truth = [m["freq_hz"] for m in s["modes"]["base_modes"]]
    servo_hz = abs(s["modes"]["servo_pair_1_s"][1]) / (2 * math.pi)
    f = s["fit"]
    hz = {k: f["params"][k] / (2 * math.pi) for k in ("wp", "w1", "wz", "w3")}
    # modes 1 and 2 (wz, tied to base mode 2) where the simulator has them; the hydraulic pair beside the
    # servo loop's pair (the fit's wp is the open loop's, 2-5 % above the closed loop's on these rigs)
    assert hz["w1"] == pytest.approx(truth[0], rel=0.02)
    assert hz["wz"] == pytest.approx(truth[1], rel=0.03)
    assert 0.9 < hz["wp"] / servo_hz < 1.15
    # mode 3: right, or named as not determined by these data (a 0.1 V sweep's xdd/theta is noise above ~9 Hz)
    assert abs(hz["w3"] / truth[2] - 1) < 0.05 or "w3" in f["undetermined"]
    # a sound fit (with caveats), said so in the summary, never "NOT A SOUND FIT" on these healthy rigs
    assert f["sound"] and f["verdict"] in ("sound", "caveats")
    assert "fit of the notebook's 3-mode model beside eq 9.4: a sound fit" in printed and "NOT A SOUND FIT" not in printed
    # the damping controller designed from this rig's measurement damps it: >= 3x the free decay after switch-on
    cl = s["closed_loop"]
    assert cl["damping_step"]["stable"] and cl["damping_loper"]["stable"]
    assert cl["damping_loper"]["base"]["decay_rate_1_s"] > 3 * cl["damping_loper"]["base"]["free_decay_rate_1_s"]
    assert cl["servo_loop_alone_step"]["base"]["settle_s"] > 2 * cl["damping_step"]["base"]["settle_s"]
    # the summary names the rig
    assert all(x in printed.splitlines()[0] for x in sets)
