"""Model structures: vectorised evaluation agrees with the notebook's seed TFs; analytic Jacobian is right."""

import numpy as np
import pytest

from samii import notebook as nb
from samii.identify.structures import ModelStructure

F_HZ = np.geomspace(0.1, 40.0, 120)  # the notebook's swept-sine span (chapter 9)
W = 2 * np.pi * F_HZ


def _eval_tf(tf, w):
    return np.asarray(tf(1j * w)).ravel()


def test_names_follow_the_notebook():
    assert ModelStructure.notebook_3mode().param_names == nb.NAMES_3MODE  # eq 9.3 order
    assert ModelStructure.notebook_2mode().param_names == nb.NAMES_2MODE  # eq 1.3 order
    st4 = ModelStructure(n_modes=4)
    assert st4.param_names[-6:] == ("w4", "z4", "B1", "B2", "B3", "B4")
    free = ModelStructure(n_modes=3, tie_mode2=False)
    assert free.param_names[6:12] == ("w1", "z1", "w2", "z2", "w3", "z3")


def test_w2_factor_convention_defaults_like_the_notebook():
    assert ModelStructure(n_modes=2).w2_factors is True  # eq 1.2
    assert ModelStructure(n_modes=3).w2_factors is False  # eq 9.2
    assert ModelStructure(n_modes=3, w2_factors=True).w2_factors is True


@pytest.mark.parametrize(
    "structure, params",
    [
        (ModelStructure.notebook_3mode(), nb.EQ9_4),
        (ModelStructure.notebook_3mode("s2"), nb.EQ9_4),
        (ModelStructure.notebook_2mode(), nb.EQ1_4_OPTIMIZED),
        (ModelStructure.notebook_2mode(), nb.EQ1_3_MANUAL),
        (ModelStructure(n_modes=3, w2_factors=True), nb.EQ9_FITS[0.3]),
    ],
)
def test_vectorised_responses_match_seed_transfer_functions(structure, params):
    kw = dict(numerator=structure.numerator, w2_factors=structure.w2_factors)
    ref = {"act": nb.actuator_tf(params), "base": nb.base_tf(params, **kw), "total": nb.total_tf(params, **kw)}
    for ch, tf in ref.items():
        h = structure.response(params, F_HZ, ch)
        np.testing.assert_allclose(h, _eval_tf(tf, W), rtol=1e-10)


def test_untied_mode2_equal_to_tie_when_w2_is_wz():
    tied = ModelStructure.notebook_3mode()
    free = ModelStructure(n_modes=3, tie_mode2=False)
    p = dict(nb.EQ9_4, w2=nb.EQ9_4["wz"], z2=nb.EQ9_4["zz"])
    np.testing.assert_allclose(free.response(p, F_HZ, "base"), tied.response(nb.EQ9_4, F_HZ, "base"), rtol=1e-12)
    p["w2"] *= 1.1  # and different otherwise
    assert not np.allclose(free.response(p, F_HZ, "base"), tied.response(nb.EQ9_4, F_HZ, "base"))


def test_four_modes_match_seed_base_tf():
    st = ModelStructure(n_modes=4)
    p = dict(nb.EQ9_4, w4=400.0, z4=0.02, B4=1e-5)  # an arbitrary fourth mode above w3
    np.testing.assert_allclose(st.response(p, F_HZ, "base"), _eval_tf(nb.base_tf(p), W), rtol=1e-10)


@pytest.mark.parametrize(
    "structure, params",
    [
        (ModelStructure.notebook_3mode(), dict(nb.EQ9_4)),
        (ModelStructure.notebook_2mode(), dict(nb.EQ1_4_OPTIMIZED)),
        (ModelStructure(n_modes=3, numerator="s2", tie_mode2=False, w2_factors=True), dict(nb.EQ9_4, w2=60.0, z2=0.05)),
    ],
)
def test_analytic_log_jacobian_matches_central_differences(structure, params):
    x = structure.vector(params)
    chans = ("act", "base", "total")
    resp = structure.log_responses(x, W, chans)
    for i, name in enumerate(structure.param_names):
        h = 1e-6 * abs(x[i])
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        for ch in chans:
            hp = structure.log_responses(xp, W, (ch,), derivatives=False)[ch][0]
            hm = structure.log_responses(xm, W, (ch,), derivatives=False)[ch][0]
            fd = (np.log(hp) - np.log(hm)) / (2 * h)
            an = resp[ch][1][:, i]
            scale = np.max(np.abs(an)) + 1e-30
            assert np.max(np.abs(fd - an)) / scale < 1e-6, (name, ch)


def test_state_space_of_total_is_minimal_and_matches():
    st = ModelStructure.notebook_3mode()
    ss = st.to_ss(nb.EQ9_4, "total")
    np.testing.assert_allclose(np.asarray(ss(1j * W)).ravel(), st.response(nb.EQ9_4, F_HZ, "total"), rtol=1e-8)
    poles = ss.poles()
    # the tied mode 2 cancels the actuator zero pair: no pole at |s| = wz (eq 8.1 remark); modes 1, 3 of eq 10.2 remain
    assert not np.any(np.abs(np.abs(poles) - nb.EQ9_4["wz"]) < 0.5)
    for p in nb.EQ10_2:
        assert np.min(np.abs(poles - p)) < 1e-3 * abs(p)


def test_improper_base_channel_has_no_state_space():
    with pytest.raises(ValueError, match="improper"):
        ModelStructure.notebook_3mode().to_ss(nb.EQ9_4, "base")
    ModelStructure.notebook_3mode("s2").to_ss(nb.EQ9_4, "base")  # s^2: proper, fine


def test_bad_parameters_are_named():
    st = ModelStructure.notebook_3mode()
    p = dict(nb.EQ9_4)
    del p["w3"]
    with pytest.raises(KeyError, match="w3"):
        st.vector(p)
    with pytest.raises(ValueError, match="zp"):
        st.vector(dict(nb.EQ9_4, zp=-0.1))
    with pytest.raises(ValueError, match="numerator"):
        ModelStructure(numerator="s3")


def test_one_mode_structure_describes_converts_and_refuses_a_tie():
    st = ModelStructure(n_modes=1)
    assert st.tie_mode2 is False and st.param_names == ("K1", "wp", "zp", "wz", "zz", "tau", "w1", "z1", "B1")
    assert st.describe() == "1 mode, s4 numerator, gains B_k (eq 9.2)"
    assert "modes" not in st.describe() and "mode 2" not in st.describe()
    p = {k: nb.EQ9_4[k] for k in st.param_names}
    for ch in ("act", "base", "total"):
        np.testing.assert_allclose(_eval_tf(st.to_tf(p, ch), W), st.response(p, F_HZ, ch), rtol=1e-10)
    with pytest.raises(ValueError, match="n_modes >= 2"):
        ModelStructure(n_modes=1, tie_mode2=True)
    assert ModelStructure.notebook_3mode().describe() == "3 modes, s4 numerator, w2=wz, z2=zz, gains B_k (eq 9.2)"


@pytest.mark.parametrize("structure", [ModelStructure.notebook_3mode(), ModelStructure.notebook_2mode(), ModelStructure(n_modes=4)])
def test_tf_matches_the_seed_transfer_functions(structure):
    # to_tf builds xdd/theta itself (any number of modes); it must agree with samii.notebook.base_tf
    p = dict(nb.EQ9_4, w4=400.0, z4=0.02, B4=1e-5) if structure.n_modes == 4 else dict(nb.EQ1_4_OPTIMIZED if structure.n_modes == 2 else nb.EQ9_4)
    kw = dict(numerator=structure.numerator, w2_factors=structure.w2_factors)
    np.testing.assert_allclose(_eval_tf(structure.to_tf(p, "base"), W), _eval_tf(nb.base_tf(p, **kw), W), rtol=1e-10)
    np.testing.assert_allclose(_eval_tf(structure.to_tf(p, "total"), W), _eval_tf(nb.total_tf(p, **kw), W), rtol=1e-10)


def test_channel_params_and_units():
    st = ModelStructure.notebook_3mode()
    assert st.channel_params(("act",)) == ("K1", "wp", "zp", "wz", "zz", "tau")
    assert st.channel_params(("base",)) == ("wz", "zz", "w1", "z1", "w3", "z3", "B1", "B2", "B3")  # mode 2 is (wz, zz), eq 9.2
    assert st.channel_params(("total",)) == st.param_names
    u = st.units()
    # theta/v ~ K1/s at low frequency (eq 9.1); xdd/theta = s^4 B/D (eq 9.2): B in (m/s^2)/rad * s^2
    assert (u["K1"], u["wp"], u["zp"], u["tau"], u["B1"]) == ("rad/(V·s)", "rad/s", "1", "rad/s", "(m/s²)/rad·s²")
    assert ModelStructure.notebook_3mode("s2").units()["B1"] == "(m/s²)/rad"  # s^2/D is dimensionless
    assert ModelStructure.notebook_2mode().units(theta="deg")["B1"] == "(m/s²)/deg·s⁴"  # eq 1.2: B w^2 s^4/D


def test_modal_columns_sum_to_the_base_response():
    st = ModelStructure.notebook_3mode()
    x = st.vector(nb.EQ9_4)
    cols = st.modal_columns(x, W)
    np.testing.assert_allclose(cols @ np.array([nb.EQ9_4[f"B{k}"] for k in (1, 2, 3)]), st.response(nb.EQ9_4, F_HZ, "base"), rtol=1e-12)
