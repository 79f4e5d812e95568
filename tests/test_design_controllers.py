"""Placement, pole cancellation and the runnable controllers: poles where asked, loops match the linear prediction."""

import control
import numpy as np
import pytest

from samii import controller as ctl
from samii import notebook as nb
from samii.design import cancel as cn
from samii.design import canonical as cc
from samii.design import placement as pl
from samii.design import rootlocus as rl

T = 1e-3  # the later closed-loop issue runs controllers at 1 kHz


@pytest.fixture(scope="module")
def eq14():
    return cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)


@pytest.fixture(scope="module")
def eq94():
    return cc.numeric_statespace(cc.derive_canonical_form(3, "accel"), nb.EQ9_4)


def _nearest(values, targets):
    values = np.asarray(values)
    return max(np.min(np.abs(values - t)) for t in targets)


def _sampled_plant(model):
    """ZOH plant read at t_k before v[k] is applied: y[k] = C x[k] + D v[k-1] (state [x; v_prev])."""
    d = control.sample_system(model, T, method="zoh")
    A, B, C, D = (np.asarray(m) for m in (d.A, d.B, d.C, d.D))
    n = A.shape[0]
    Aa = np.block([[A, np.zeros((n, 1))], [np.zeros((1, n + 1))]])
    Ba = np.vstack([B, [[1.0]]])
    Ca = np.hstack([C, D])
    return control.ss(Aa, Ba, Ca, np.zeros((C.shape[0], 1)), T, inputs=["v"], outputs=["theta", "accel"])


def _loop(plant, controller):
    """Linear prediction: python-control interconnection of the plant and the controller (theta_ref -> theta, accel)."""
    c = controller.statespace()
    return control.interconnect([plant, c], inplist=["theta_ref"], outlist=["theta", "accel"])


def _run(plant, controller, n, *, ref=1.0, scale=1.0):
    """Step the controller object against the plant, measure-then-act; returns theta, accel."""
    A, B, C = (np.asarray(m) for m in (plant.A, plant.B, plant.C))
    x = np.zeros(A.shape[0])
    controller.reset()
    out = np.zeros((n, 2))
    for k in range(n):
        y = C @ x
        out[k] = y
        v = controller.step({"theta_ref": ref / scale, "theta": y[0] / scale, "accel": y[1]})
        x = A @ x + B[:, 0] * v
    return out


def _check_matches_prediction(plant, controller, n=3000):
    loop = _loop(plant, controller)
    resp = control.forced_response(loop, T=np.arange(n) * T, U=np.ones(n))
    pred = np.asarray(resp.outputs).T
    run = _run(plant, controller, n)
    # per channel, relative to its peak: the canonical-form plants are badly scaled, so python-control's
    # simulation and the sample-by-sample loop round differently at the 1e-8 level
    scale = np.max(np.abs(pred), axis=0)
    assert np.all(np.abs(run - pred) <= 1e-5 * scale), np.max(np.abs(run - pred) / scale, axis=0)
    return loop, run


# ---- placement (chapter 8) ----


def test_desired_pole_rule_gives_eq8_3(eq14):
    des = pl.desired_poles(eq14, 1 / np.sqrt(2))
    for got, printed in ((des, nb.EQ8_3), (pl.unity_feedback_poles(eq14), nb.EQ8_2)):
        for p in printed:  # 4 significant digits
            assert np.min(np.abs(got - p)) < 3e-4 * abs(p)
    # real poles are kept, complex ones keep their magnitude at the new damping
    ufb = pl.unity_feedback_poles(eq14)
    for p, q in zip(ufb, des):
        assert abs(q) == pytest.approx(abs(p), rel=1e-12)
        if abs(p.imag) > 0:
            assert -q.real / abs(q) == pytest.approx(1 / np.sqrt(2), rel=1e-12)
        else:
            assert q == p


def test_continuous_placement_puts_poles_where_asked(eq14):
    des = pl.desired_poles(eq14, 0.6)
    K = pl.place_continuous(eq14, des)
    eig = np.linalg.eigvals(np.asarray(eq14.A) - np.asarray(eq14.B) @ K)
    assert _nearest(eig, des) < 1e-6 * np.max(np.abs(des))


@pytest.mark.parametrize("observer", ["placement", "kalman"])
def test_discrete_design_and_observer_poles_where_asked(eq14, observer):
    d = pl.design_placement(eq14, sample_time_s=T, zeta=1 / np.sqrt(2), observer=observer, input_noise_std=0.05, measurement_noise_std=(0.01, 0.5))
    Ad, Bd, C = (np.asarray(m) for m in (d.discrete.A, d.discrete.B, d.discrete.C))
    assert _nearest(np.linalg.eigvals(Ad - Bd @ d.K), d.poles_z) < 1e-8
    assert _nearest(np.linalg.eigvals(Ad - d.L @ C), d.observer_poles_z) < 1e-8
    if observer == "placement":
        np.testing.assert_allclose(d.observer_poles_z, np.exp(2 * d.poles_s * T))
    # the whole sampled loop (plant read before acting, observer, feedback) has exactly these eigenvalues and z = 0
    plant = _sampled_plant(d.model)
    loop, run = _check_matches_prediction(plant, d.controller(), n=2000)
    eig = np.linalg.eigvals(np.asarray(loop.A))
    expected = np.concatenate([d.poles_z, d.observer_poles_z, [0.0]])
    assert _nearest(eig, expected) < 1e-6 and _nearest(expected, eig) < 1e-6
    # and theta follows a unit step with unit DC gain
    assert run[-1, 0] == pytest.approx(1.0, abs=0.02)


def test_kalman_needs_its_covariances(eq14):
    with pytest.raises(ValueError, match="Kalman"):
        pl.design_placement(eq14, sample_time_s=T, observer="kalman")


# ---- pole cancellation (chapter 10) ----


def test_compensator_zeros_and_poles_are_eq10():
    d = cn.design_pole_cancel(nb.EQ9_4)
    zeros = d.Gc.zeros()
    for z in nb.EQ10_1 + nb.EQ10_2:
        assert np.min(np.abs(zeros - z)) < 2e-3 * abs(z)  # printed to 4 digits
    poles = np.sort(d.Gc.poles().real)
    np.testing.assert_allclose(poles, np.sort(nb.EQ10_8), rtol=2e-4)
    assert np.allclose(d.Gc.poles().imag, 0, atol=1e-3)  # double real poles at zeta = 1
    # the cancelled poles stay closed-loop poles: the compensator hides them, it does not move them
    cl = d.closed_loop
    for z in nb.EQ10_1:
        assert np.min(np.abs(cl - z)) < 2e-3 * abs(z)


def _theta_loop_pair_zetas(num_c, den_c, K):
    """Damping ratios of the moving closed-loop pairs of 1 + K Gc G_cl = 0, slowest first.

    Independent of samii.design.cancel: roots of the characteristic polynomial
    den_c den_cl + K num_c num_cl, G_cl = eq 9.4 actuator under unity feedback;
    poles within 1 % of a cancelled pole (eq 10.1, 10.2) are left out.
    """
    g_cl = control.feedback(nb.actuator_tf(nb.EQ9_4), 1)
    char = np.polyadd(np.polymul(den_c, g_cl.den[0][0]), K * np.polymul(num_c, g_cl.num[0][0]))
    r = np.roots(char)
    cancelled = np.array(nb.EQ10_1 + nb.EQ10_2)
    pairs = sorted((x for x in r if x.imag > 1e-6 and np.min(np.abs(cancelled - x)) > 1e-2 * abs(x)), key=abs)
    return np.array([-x.real / abs(x) for x in pairs])


def test_gain_rule_pins_our_value():
    d = cn.design_pole_cancel(nb.EQ9_4, loop="theta")
    # the rule: smallest K at which the slowest moving pair of 1 + K Gc G_cl = 0 has zeta 0.7. By the
    # characteristic polynomial (not cancel.py) on a 1e-5 grid from 0.06 to 0.08 the slowest pair's zeta
    # crosses 0.7 once, between K = 0.07211 and 0.07212 (it falls monotonically with K): K = 0.07212
    num, den = d.Gc.num[0][0], d.Gc.den[0][0]
    ks = np.arange(0.06, 0.08, 1e-5)
    z1 = np.array([_theta_loop_pair_zetas(num, den, k)[0] for k in ks])
    assert np.all(np.diff(z1) < 0)
    crossing = ks[np.flatnonzero(z1 <= 0.7)[0]]
    assert d.gain == pytest.approx(crossing, abs=1e-5)
    assert d.gain == pytest.approx(0.07212, abs=1e-4)
    assert _theta_loop_pair_zetas(num, den, d.gain)[0] == pytest.approx(0.7, abs=1e-9)
    # 8.3 % above the notebook's 0.0666: beyond its printed precision, explained by the seed report
    assert (d.gain - nb.EQ10_GAIN) / nb.EQ10_GAIN == pytest.approx(0.083, abs=1e-3)


def _pairs_realised_anew(L, k: float, cancel_tol: float = 1e-6) -> np.ndarray:
    """The moving pairs as samii.design.cancel computed them before issue 34: L realised and its poles found again at
    every gain (python-control's tf2ss and poles, rootlocus.feedback_poles with gain -k)."""
    ss = control.tf2ss(L)
    ol = L.poles()
    cl = rl.feedback_poles(ss.A, ss.B, ss.C, ss.D, -k)
    cl = cl[cl.imag > 1e-9 * np.abs(cl)]
    moving = np.array([x for x in cl if np.min(np.abs(ol - x)) > cancel_tol * abs(x)], complex)
    return moving[np.argsort(np.abs(moving))]


def test_a_gain_scan_gives_what_the_loop_realised_at_each_gain_gives():
    """gain_at_zeta realises the open loop once for its ~400 gains (issue 34: python-control's tf2ss and poles were
    90 % of each evaluation); the moving pairs it scans, and so the gain it returns, are the same bits as with L
    realised anew at each K, as it did before (_pairs_realised_anew)."""
    from scipy import optimize

    L = cn.design_pole_cancel(nb.EQ9_4, loop="theta").open_loop

    def zeta(k, pair):  # (gain_at_zeta's arithmetic: numpy's complex abs and mean, which builtin abs differs from in the last bit)
        p = _pairs_realised_anew(L, k)
        return float(np.mean((-p.real / np.abs(p))[[pair]])) - 0.7

    for pair, bracket in ((0, (0.01, 0.5)), (2, (0.01, 0.5)), (0, (1e-6, 10.0))):
        ks = np.geomspace(*bracket, 400)
        vals = np.array([zeta(k, pair) for k in ks])
        i = int(np.flatnonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))[0])
        anew = optimize.brentq(zeta, ks[i], ks[i + 1], args=(pair,), xtol=1e-12, rtol=1e-12)
        assert cn.gain_at_zeta(L, 0.7, pair=pair, bracket=bracket) == anew
    for k in (1e-4, nb.EQ10_GAIN, 0.3):
        assert np.array_equal(cn.moving_pairs(L, k), _pairs_realised_anew(L, k))


def test_zetas_at_the_notebooks_gain():
    # the notebook's K = 0.0666 (chapter 10) on its own printed eq 10.9 polynomials: four moving pairs,
    # slowest first: 0.711, 0.51345, 0.698, 0.954 (the seed report quotes 0.513 for the printed polynomials and
    # 0.514 for the unrounded compensator; 0.514 +- 1e-3 covers both). Two are "approximately 0.7", pair 2 is not
    z = _theta_loop_pair_zetas(np.array(nb.EQ10_9_NUM), np.array(nb.EQ10_9_DEN), nb.EQ10_GAIN)
    np.testing.assert_allclose(z, [0.711, 0.514, 0.698, 0.954], atol=1e-3)
    # and through samii.design.cancel with the unrounded compensator, within the printed-coefficient effect
    zc = cn.pair_zetas(cn.design_pole_cancel(nb.EQ9_4, loop="theta").open_loop, nb.EQ10_GAIN)
    np.testing.assert_allclose(zc, z, atol=3e-4)


def test_cancel_controller_tracks_theta_ref_with_unit_dc_gain_by_default(eq94):
    d = cn.design_pole_cancel(nb.EQ9_4, loop="theta")
    plant = _sampled_plant(eq94)
    dc = control.dcgain(_loop(plant, d.controller(sample_time_s=T)))
    assert dc[0] == pytest.approx(1.0, abs=1e-6)
    # without the prefilter the loop as drawn settles at K Gc(0) / (1 + K Gc(0)) = 1 / reference_gain (0.143)
    dc_raw = control.dcgain(_loop(plant, d.controller(sample_time_s=T, scale_reference=False)))
    assert dc_raw[0] == pytest.approx(1 / d.reference_gain, rel=1e-5)
    assert dc_raw[0] == pytest.approx(0.143, abs=5e-4)


@pytest.mark.parametrize("loop", ["theta", "accel"])
def test_cancel_controller_matches_prediction_and_keeps_cancellation(eq94, loop):
    d = cn.design_pole_cancel(nb.EQ9_4, loop=loop)
    c = d.controller(sample_time_s=T)  # default: theta_ref scaled for unit DC gain
    plant = _sampled_plant(eq94)
    lp, run = _check_matches_prediction(plant, c, n=4000)
    # matched discretisation: the compensator zeros sit exactly on the sampled plant's poles
    zc = np.linalg.eigvals(np.asarray(c.A))
    assert zc.size == 6
    if loop == "theta":
        assert run[-1, 0] == pytest.approx(1.0, abs=1e-3)  # the default reference prefilter
        # theta_ref -> accel has no lightly damped mode left: the response has decayed by 4 s
        assert np.max(np.abs(run[-500:, 1])) < 1e-3 * np.max(np.abs(run[:, 1]))


# ---- mass damping and the interface ----


def test_mass_damping_controller_reproduces_the_continuous_design(eq14):
    # eq 1.4, 2 Hz low-pass, K_a at the study's 6 dB optimum: the sampled loop has (nearly) the continuous poles
    loop = rl.mass_damping_loop(nb.EQ1_4_OPTIMIZED, variant=rl.NOTEBOOK_VARIANTS[4])
    k = rl.summarize(loop, n_gains=400).robust_negative.best_gain
    c = ctl.mass_damping_controller(k, rl.AccelFilter("lowpass", (2.0,)).tf(), sample_time_s=T, method="tustin")
    plant = _sampled_plant(eq14)
    lp, _ = _check_matches_prediction(plant, c)
    s_cont = rl.closed_loop_poles(loop, [k])[0]
    s_disc = np.log(np.linalg.eigvals(np.asarray(lp.A)).astype(complex) + 0j) / T
    # mode 2 cancels against the actuator zeros: it is a pole of the loop but not of the canonical form
    m2 = np.roots([1, 2 * nb.EQ1_4_OPTIMIZED["zz"] * nb.EQ1_4_OPTIMIZED["wz"], nb.EQ1_4_OPTIMIZED["wz"] ** 2])
    slow = np.array([p for p in s_cont if abs(p) < 80 and np.min(np.abs(m2 - p)) > 1e-6 * abs(p)])
    # a 1 kHz sampled loop with one sample of measurement delay moves these poles by well under 1 %
    assert _nearest(s_disc, slow) < 0.01 * np.max(np.abs(slow))


def test_unity_controller_and_interface(eq94):
    c = ctl.unity_theta_controller(sample_time_s=T)
    assert isinstance(c, ctl.Controller)
    _check_matches_prediction(_sampled_plant(eq94), c, n=1500)
    assert c.step({"theta_ref": 0.3, "theta": 0.1}) == pytest.approx(0.2)


def test_input_scale_converts_units():
    c = ctl.unity_theta_controller(sample_time_s=T, input_scale={"theta": 180 / np.pi, "theta_ref": 180 / np.pi}, model_units="deg")
    assert c.step({"theta_ref": np.pi / 180, "theta": 0.0}) == pytest.approx(1.0)


def test_bad_measurements_are_named():
    c = ctl.mass_damping_controller(0.5, sample_time_s=T)
    with pytest.raises(KeyError, match="accel"):
        c.step({"theta_ref": 0.0, "theta": 0.0})
    with pytest.raises(ValueError, match="theta"):
        c.step({"theta_ref": 0.0, "theta": float("nan"), "accel": 0.0})
    with pytest.raises(ValueError, match="not measurements"):
        ctl.LinearController([[0.0]], [[1.0]], [[1.0]], [[0.0]], sample_time_s=T, inputs=("torque",))
