"""An effect found against a model that still misses the data (samii.diagnose.attribution): attributed when it
explains most of the misfit where it acts, not when it takes a little out of a misfit of another shape. The rule
on a model and data written here in closed form (the model's response patched in), so each case's numbers are
known: an accelerometer gain error of 1.3 is a change of 2.28 dB on xdd/theta and xdd/v at every frequency."""

from __future__ import annotations

import numpy as np
import pytest

from samii.diagnose import attribution
from samii.diagnose.attribution import unattributed
from samii.diagnose.effects import LIBRARY, Effect
from samii.diagnose.model import Baseline, Dataset, Fit, _apply
from samii.diagnose.simulator import Misfit

KIND = {k.label: k for k in LIBRARY}
F = np.geomspace(0.1, 40.0, 400)


def _base(f):
    s = 2j * np.pi * f
    w1 = 2 * np.pi * 1.7
    return {"act": 10.0 / (s * (1 + s / (2 * np.pi * 60))), "base": -(s**2) / (s**2 + 2 * 0.02 * w1 * s + w1**2)}


def _response(fit, i, f, sampled=True):
    out = _apply([(e.kind, np.array([e.values[p.name] for p in e.kind.params])) for e in fit.effects], _base(f), 2j * np.pi * f)
    out["total"] = out["act"] * out["base"]
    return out


def _bump(f, center_hz, db, deg, decades=0.15):
    g = np.exp(-0.5 * (np.log10(f / center_hz) / decades) ** 2)
    return np.exp(g * (db * np.log(10) / 20 + 1j * np.radians(deg)))


@pytest.fixture(autouse=True)
def closed_form(monkeypatch):
    monkeypatch.setattr(attribution, "model_response", _response)


def _case(true_gain, model_gain, misfit, channel):
    """The data: the model with a true accelerometer gain and ``misfit`` on ``channel``; the fit: the model with the
    gain ``model_gain`` found (None: none found). Returns (fit, datasets)."""
    effects = () if model_gain is None else (Effect(KIND["sensor/accel_gain"], {"gain": model_gain}, {}),)
    truth = _response(Fit(Baseline(), (), (), (Effect(KIND["sensor/accel_gain"], {"gain": true_gain}, {}),), 0.0, 1, 0, ()), 0, F)
    truth[channel] = truth[channel] * misfit
    if channel != "total":
        truth["total"] = truth["act"] * truth["base"]
    model = _response(Fit(Baseline(), (), (), effects, 0.0, 1, 0, ()), 0, F)
    keep = {ch: np.ones(F.size, bool) for ch in ("act", "total")}
    ds = Dataset("rig.csv", F, {ch: truth[ch] for ch in keep}, keep, {ch: np.full(F.size, 1e3) for ch in keep}, True, 1.0, 0.1)
    res = {ch: np.log(truth[ch] / model[ch]) for ch in keep}
    return Fit(Baseline(), (), (), effects, 0.0, 1, 0, (res,)), [ds]


def _band(channel, lo, hi, db=4.0, deg=30.0):
    return Misfit("rig.csv", channel, lo, hi, db, deg, 5.0, 40)


def test_a_gain_error_beside_a_misfit_elsewhere_is_attributed():
    # the misfit (4 dB on theta/v at 0.2-0.5 Hz) is where the gain does not act: not its business
    fit, ds = _case(1.3, 1.3, _bump(F, 0.3, 4.0, 30.0), "act")
    assert unattributed(fit, ds, [_band("act", 0.2, 0.5)], "sensor/accel_gain", {"gain": 1.3}) is None


def test_a_gain_error_that_explains_most_of_a_misfit_band_is_attributed():
    # xdd/v 5-15 Hz: without the gain 2.28 dB plus a 1 dB bump, with it the bump alone: 90 % of the power taken out
    fit, ds = _case(1.3, 1.3, _bump(F, 8.0, 1.0, 5.0), "total")
    assert unattributed(fit, ds, [_band("total", 5.0, 15.0, 1.0, 5.0)], "sensor/accel_gain", {"gain": 1.3}) is None


def test_a_small_gain_fitted_into_a_misfit_of_another_shape_is_not_attributed():
    # no gain error: a 4 dB, 30 deg bump on xdd/v at 8 Hz, and a gain of 1.1 (0.83 dB) fitted into it
    fit, ds = _case(1.0, 1.1, _bump(F, 8.0, 4.0, 30.0), "total")
    why = unattributed(fit, ds, [_band("total", 5.0, 15.0)], "sensor/accel_gain", {"gain": 1.1})
    assert why is not None and (why.code, why.cls, why.values["channel"], why.values["band_hz"]) == (
        "image",
        "not told from an image",
        "total",
        (5.0, 15.0),
    )
    assert why.values["takes_out_pct"] < why.values["needed_pct"] and "xdd/v 5-15 Hz" in why.text
    # the same change, held in the baseline (carried into the simulator), is judged the same way
    held, _ = _case(1.0, None, _bump(F, 8.0, 4.0, 30.0) / 1.1, "total")
    assert unattributed(held, ds, [_band("total", 5.0, 15.0)], "sensor/accel_gain", {"gain": 1.1}) is not None


def test_no_misfit_left_asks_nothing():
    fit, ds = _case(1.0, 1.1, _bump(F, 8.0, 4.0, 30.0), "total")
    assert unattributed(fit, ds, [], "sensor/accel_gain", {"gain": 1.1}) is None


# --- what the model places where only xdd/v is usable (samii.diagnose.attribution.product_only) ---


def _dataset(act_to_hz: float | None):
    """One file on F: xdd/v usable everywhere, theta/v up to ``act_to_hz`` (None: everywhere)."""
    keep = {"act": F <= (act_to_hz if act_to_hz is not None else np.inf), "total": np.ones(F.size, bool)}
    data = {ch: np.ones(int(k.sum()), complex) for ch, k in keep.items()}
    return Dataset("rig.csv", F, data, keep, {ch: np.ones(int(k.sum())) for ch, k in keep.items()}, True, 1.0, 0.1)


def _notebook_fit(effects, w3_hz: float):
    from samii.diagnose.model import notebook_reference
    from samii.identify.structures import ModelStructure

    st = ModelStructure.notebook_3mode()
    p = {k: v for k, v in notebook_reference().items() if k in st.param_names}
    p["w3"] = 2 * np.pi * w3_hz
    return Fit(Baseline(structure=st, params=(p,)), (p,), ({},), tuple(effects), 0.0, 1, 0, ({},))


def test_what_only_xdd_v_sees_is_said_to_be_placed_by_it_alone():
    from samii.diagnose.attribution import product_only

    valve = Effect(KIND["actuator/valve"], {"freq_hz": 32.3, "zeta": 0.1}, {})
    # theta/v usable to 9 Hz (battery C's rig.csv): the valve at 32.3 Hz and the baseline's mode 3 at 23.6 Hz lie where
    # only xdd/v sees them (the baseline's wp, 8.80 Hz in eq 9.4, lies below the band)
    found = product_only([_dataset(9.0)], _notebook_fit([valve], 23.6))
    assert len(found) == 1, found
    band = found[0]
    assert band.source == "rig.csv" and 9.0 < band.lo_hz < 9.2 and band.hi_hz == pytest.approx(40.0)
    assert [(p.what, p.channel, p.baseline) for p in band.placed] == [("base mode 3", "base", True), ("valve", "act", False)]
    assert band.placed[0].freqs_hz == pytest.approx((23.6,)) and band.placed[1].freqs_hz == (32.3,)
    n = band.text()
    assert "only xdd/v is usable" in n and "valve (32.3 Hz; theta/v)" in n and "the baseline's base mode 3 (23.6 Hz; xdd/theta)" in n
    assert "not measured" in n and "measure theta/v in that band" in n
    # theta/v usable everywhere: nothing is placed by xdd/v alone
    assert product_only([_dataset(None)], _notebook_fit([valve], 23.6)) == []
    # theta/v usable to 30 Hz: the valve at 32.3 Hz is within 1.25x of its edge (its flank is theta/v's), the mode too
    assert product_only([_dataset(30.0)], _notebook_fit([valve], 23.6)) == []
    # an effect of no frequency (a delay) is not placed in a band
    delay = Effect(KIND["delay/command"], {"delay_s": 0.002}, {})
    assert product_only([_dataset(9.0)], _notebook_fit([delay], 5.0)) == []


def test_a_band_of_one_or_two_points_is_not_named(monkeypatch):
    from samii.diagnose import attribution
    from samii.diagnose.attribution import PRODUCT_ONLY_POINTS, product_only

    # the count alone decides here: without the edge margin (which would shrink a hole of a few points to nothing)
    monkeypatch.setattr(attribution, "PRODUCT_ONLY_MARGIN", 1.0)

    def holed(n):
        ds = _dataset(None)
        hole = np.flatnonzero(F > 30.0)[:n]  # theta/v's variance crossing its limit at n points
        keep = dict(ds.keep, act=ds.keep["act"].copy())
        keep["act"][hole] = False
        valve = Effect(KIND["actuator/valve"], {"freq_hz": float(F[hole[0]]), "zeta": 0.1}, {})
        return Dataset(ds.source, F, ds.data, keep, ds.inv_sigma, True, 1.0, 0.1), valve

    ds, valve = holed(PRODUCT_ONLY_POINTS - 1)
    assert product_only([ds], _notebook_fit([valve], 23.6)) == []
    ds, valve = holed(PRODUCT_ONLY_POINTS)  # one point more: the band is named, with the valve in it
    found = product_only([ds], _notebook_fit([valve], 23.6))
    assert len(found) == 1 and [p.what for p in found[0].placed] == ["valve"]
