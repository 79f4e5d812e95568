"""The cost is the notebook's samiierr.m, term for term."""

import control
import numpy as np
import pytest

from samii import notebook as nb
from samii.identify.cost import DB_PER_NEPER, DEG_PER_RAD, POOL_HALFWIDTH, FitProblem, notebook_cost, pooled_coherence
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


def test_pooled_coherence_is_the_mean_over_neighbours_within_the_window():
    f = np.geomspace(1.0, 100.0, 201)  # 100 per decade: ln spacing 0.023, so +-0.05 holds two neighbours a side
    rng = np.random.default_rng(0)
    g = rng.uniform(0.2, 1.0, f.size)
    pooled = pooled_coherence(f, g)
    np.testing.assert_allclose(pooled[2:-2], np.convolve(g, np.ones(5) / 5, mode="valid"), rtol=1e-12)
    assert pooled[0] == pytest.approx(np.mean(g[:3]))  # an end pools what it has
    # a point with no neighbour within the window keeps its own estimate (10 per decade: ln spacing 0.23)
    coarse = np.geomspace(1.0, 100.0, 21)
    np.testing.assert_allclose(pooled_coherence(coarse, g[:21]), g[:21], rtol=1e-12)
    # noise-free data stay noise-free
    np.testing.assert_array_equal(pooled_coherence(f, np.ones(f.size)), np.ones(f.size))
    assert POOL_HALFWIDTH == 0.05


def test_a_point_whose_three_records_agreed_by_chance_does_not_outweigh_its_neighbours():
    """At a notch a 3-record coherence estimate scatters (0.18, 0.89, 0.99, 0.80 on neighbouring points of a
    simulator rig's theta/v): one point at 0.99 weighed sqrt(0.99/0.01) = 10 against 2 for a coherence of 0.8.
    Its weight comes from its neighbourhood: here the mean of five points (0.698), weight 1.5."""
    f = np.geomspace(5.0, 20.0, 61)
    g = np.full(f.size, 0.7)
    i = 30
    g[i - 2 : i + 3] = [0.18, 0.89, 0.99, 0.80, 0.63]
    data = synthesize(f, {c: ST.response(nb.EQ9_4, f, c) for c in ("act", "base")}, noise=None)
    data = type(data)(f, act=data.act, base=data.base, act_coh=g, base_coh=g)
    pr = FitProblem(data, ST, phase_weight=0.1, weighting="coherence")
    w = pr._weights["act"] / pr._weights["act"][0]  # relative to a point of 0.7 all round
    gp = np.mean(g[i - 2 : i + 3])  # 0.698
    assert w[i] == pytest.approx(np.sqrt(gp / (1 - gp) / (0.7 / 0.3)), rel=1e-9)
    assert w[i] < 1.1  # per point it would be sqrt(0.99 / 0.01) / sqrt(0.7 / 0.3) = 6.5
    # unweighted (the notebook's cost), the noise profile behind the standard errors is the pooled one
    prof = FitProblem(data, ST, phase_weight=0.1).noise_profile()[: f.size]
    assert prof[i] / prof[0] == pytest.approx((1 - gp) / gp / (0.3 / 0.7), rel=1e-9)


def test_a_thinned_problem_keeps_the_weights_pooled_on_all_points():
    f = np.geomspace(0.1, 40.0, 2500)
    g = np.random.default_rng(1).uniform(0.3, 1.0, f.size)
    data = synthesize(f, {c: ST.response(nb.EQ9_4, f, c) for c in ("act", "base")}, noise=None)
    data = type(data)(f, act=data.act, base=data.base, act_coh=g, base_coh=g)
    pr = FitProblem(data, ST, phase_weight=0.1, weighting="coherence")
    th = pr.thinned(1000)
    k = 3
    assert th.n_points == len(f[::k])
    np.testing.assert_allclose(th._weights["act"], pr._weights["act"][::k])
    np.testing.assert_allclose(th.noise_profile(), np.concatenate([v[::k] for v in np.split(pr.noise_profile(), 4)]))


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
