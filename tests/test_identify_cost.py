"""The cost is the notebook's samiierr.m, term for term."""

import control
import numpy as np
import pytest

from samii import notebook as nb
from samii.identify.cost import DB_PER_NEPER, DEG_PER_RAD, FitProblem, notebook_cost
from samii.identify.structures import ModelStructure
from samii.identify.synthetic import SweptSineNoise, synthesize

F_HZ = np.geomspace(0.1, 40.0, 200)
ST = ModelStructure.notebook_3mode()


def _data(params=nb.EQ9_4, noise=None, seed=0):
    resp = {c: ST.response(params, F_HZ, c) for c in ("act", "base")}
    return synthesize(F_HZ, resp, noise=noise, rng=np.random.default_rng(seed))


def _samiierr(params, data, pw):
    """Literal transcription of chapter 9's samiierr.m with python-control's bode (unwrapped phase in degrees)."""
    w = data.w
    act = control.frequency_response(nb.actuator_tf(params), w)
    base = control.frequency_response(nb.base_tf(params), w)
    act_fit_mag, act_fit_ph = np.abs(act.complex.ravel()), np.degrees(np.unwrap(np.angle(act.complex.ravel())))
    base_fit_mag, base_fit_ph = np.abs(base.complex.ravel()), np.degrees(np.unwrap(np.angle(base.complex.ravel())))
    ev1 = 20 * np.log10(np.abs(data.act)) - 20 * np.log10(act_fit_mag)
    ev2 = 20 * np.log10(np.abs(data.base)) - 20 * np.log10(base_fit_mag)
    phe1 = data.phase_deg("act") - act_fit_ph
    phe2 = data.phase_deg("base") - base_fit_ph
    evt = np.concatenate([ev1, ev2, pw * phe1, pw * phe2])
    return float(np.sum(evt**2))


@pytest.mark.parametrize("pw", [0.0, 0.1, 0.5])
def test_cost_equals_notebook_code(pw):
    data = _data()  # eq 9.4 curves as data, eq 9.3 (the pw=0 fit) as model: a cost well away from 0
    ours = notebook_cost(nb.EQ9_FITS[0.0], data, ST, phase_weight=pw)
    assert ours == pytest.approx(_samiierr(nb.EQ9_FITS[0.0], data, pw), rel=1e-9)
    assert ours > 1.0


def test_phase_weight_multiplies_before_squaring():
    data = _data()
    c = {pw: notebook_cost(nb.EQ9_FITS[0.0], data, ST, phase_weight=pw) for pw in (0.0, 0.1, 0.2)}
    assert c[0.2] - c[0.0] == pytest.approx(4 * (c[0.1] - c[0.0]), rel=1e-12)


def test_cost_zero_at_truth_and_band_restricts_points():
    data = _data()
    assert notebook_cost(nb.EQ9_4, data, ST, phase_weight=0.1) < 1e-20
    full = FitProblem(data, ST, phase_weight=0.0)
    band = FitProblem(data, ST, phase_weight=0.0, band_hz=(1.0, 12.0))
    assert band.data.freq_hz.min() >= 1.0 and band.data.freq_hz.max() <= 12.0
    assert band.n_residuals < full.n_residuals
    assert band.cost(ST.vector(nb.EQ9_FITS[0.0])) < full.cost(ST.vector(nb.EQ9_FITS[0.0]))


def test_errors_are_db_and_degrees():
    data = _data()
    p = dict(nb.EQ9_4, K1=nb.EQ9_4["K1"] * 10 ** (1.5 / 20))  # +1.5 dB on theta/v, no phase change
    e = FitProblem(data, ST, phase_weight=0.1).errors(ST.vector(p))
    np.testing.assert_allclose(e["act"][0], 1.5, atol=1e-12)
    np.testing.assert_allclose(e["act"][1], 0.0, atol=1e-12)
    np.testing.assert_allclose(e["base"][0], 0.0, atol=1e-12)
    assert DB_PER_NEPER == pytest.approx(8.685889638)
    assert DEG_PER_RAD == pytest.approx(57.29577951)


def test_coherence_weighting_downweights_bad_points():
    data = _data(noise=SweptSineNoise(), seed=1)
    pr = FitProblem(data, ST, phase_weight=0.1, weighting="coherence")
    x = ST.vector(nb.EQ9_FITS[0.0])
    r_w = pr.residuals(x)
    r_u = FitProblem(data, ST, phase_weight=0.1).residuals(x)
    m = F_HZ.size
    base_mag = slice(m, 2 * m)
    low = data.base_coh < 0.6  # the s^4 base channel below ~1 Hz
    assert low.any()
    ratio = np.abs(r_w[base_mag] / r_u[base_mag])
    assert np.median(ratio[low]) < 0.2 * np.median(ratio[~low])


def test_bad_settings_are_refused():
    data = _data()
    with pytest.raises(ValueError, match="phase_weight"):
        FitProblem(data, ST, phase_weight=-0.1)
    with pytest.raises(ValueError, match="band"):
        FitProblem(data, ST, band_hz=(50.0, 60.0))
    with pytest.raises(ValueError, match="total"):
        FitProblem(data, ST, channels=("total",))
    nocoh = synthesize(F_HZ, {"act": data.act, "base": data.base}, noise=None)
    nocoh = type(nocoh)(F_HZ, act=nocoh.act, base=nocoh.base)
    with pytest.raises(ValueError, match="coherence"):
        FitProblem(nocoh, ST, weighting="coherence")
