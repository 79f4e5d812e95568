"""The notebook's studies (chapters 1, 4, 9) on the stand-in data show what the notebook describes."""

import numpy as np
import pytest

from samii import notebook as nb
from samii.identify import FitProblem, ModelStructure
from samii.identify.studies import (
    RIG_ACCEL_FILTER_HZ,
    from_notebook_units,
    manual_vs_optimized,
    phase_weight_sweep,
    s2_vs_s4,
    synthetic_rig_frf,
    to_notebook_units,
)

F_HZ = np.geomspace(0.1, 40.0, 300)


@pytest.fixture(scope="module")
def rig():
    return synthetic_rig_frf(F_HZ, rng=np.random.default_rng(2003))


@pytest.fixture(scope="module")
def clean():
    return synthetic_rig_frf(F_HZ, rng=None, noise=None)


def test_units_round_trip_and_degree_assumption():
    si = from_notebook_units(nb.EQ9_4)
    assert si["K1"] == pytest.approx(nb.EQ9_4["K1"] * np.pi / 180)
    assert si["B2"] == pytest.approx(nb.EQ9_4["B2"] * 180 / np.pi)
    assert si["wp"] == nb.EQ9_4["wp"]
    back = to_notebook_units(si)
    for k, v in nb.EQ9_4.items():
        assert back[k] == pytest.approx(v, rel=1e-14)


def test_stand_in_is_eq9_4_plus_stated_effects(clean, rig):
    st = ModelStructure.notebook_3mode()
    si = from_notebook_units(nb.EQ9_4)
    wf = 2 * np.pi * RIG_ACCEL_FILTER_HZ
    s = 2j * np.pi * F_HZ
    np.testing.assert_allclose(clean.base, st.response(si, F_HZ, "base") * wf**2 / (s**2 + np.sqrt(2) * wf * s + wf**2), rtol=1e-12)
    lag = np.degrees(np.angle(clean.act / st.response(si, F_HZ, "act")))
    i = np.argmin(np.abs(F_HZ - 5.0))  # far from the coupling pairs: the 2 ms delay alone, 3.6 deg at 5 Hz
    assert lag[i] == pytest.approx(-360 * F_HZ[i] * 2e-3, abs=0.2)
    assert "synthetic" in rig.metadata["source"]
    np.testing.assert_allclose(clean.total, clean.act * clean.base, rtol=1e-12)
    assert rig.act_coh.min() < 0.9 and rig.base_coh.min() == pytest.approx(0.5)


def test_phase_weight_trades_magnitude_for_phase(rig, clean):
    lo, hi = phase_weight_sweep(rig, weights=(0.0, 0.3), rng=np.random.default_rng(0))
    st = lo.structure
    err = {r.phase_weight: FitProblem(clean, st, phase_weight=0.0).errors(st.vector(r.params))["act"] for r in (lo, hi)}
    rms = {w: (np.sqrt(np.mean(e[0] ** 2)), np.sqrt(np.mean(e[1] ** 2))) for w, e in err.items()}
    assert rms[0.3][0] > rms[0.0][0]  # more magnitude error ...
    assert rms[0.3][1] < 0.8 * rms[0.0][1]  # ... for much less phase error
    assert hi.params["tau"] < lo.params["tau"]  # the lag grows, as eq 9.3 -> 9.8 in the notebook
    assert lo.converged and hi.converged


def test_optimised_two_mode_fit_beats_both_notebook_sets(rig):
    study = manual_vs_optimized(rig, rng=np.random.default_rng(0))
    assert study.samii.converged
    assert study.samii.cost <= study.cost_notebook_optimized < study.cost_manual
    assert study.samii.band_hz[0] >= 1.0 and study.samii.band_hz[1] <= 12.0
    assert any(w.startswith("tau") for w in study.samii.warnings)  # the valve lag is not seen in 1-12 Hz


def test_s4_beats_s2_on_the_s4_stand_in(rig):
    # the stand-in is s^4 by construction (eq 9.4), so s^4 must fit it better; the notebook's own
    # verdict on its measured data ("somewhat inconclusive", chapter 4) cannot be tested on it
    fits = s2_vs_s4(rig, rng=np.random.default_rng(0))
    assert fits["s4"].cost < fits["s2"].cost
    assert fits["s4"].rms_mag_db["base"] < fits["s2"].rms_mag_db["base"]
