"""The augmented model exported to python-control equals the responses the diagnosis fitted.

Every effect kind of the library, at parameters a rig could have, is applied to
eq 9.4 (in SI) through the fit's own code (samii.diagnose.model._apply) and
through the exported transfer function; they must agree to round-off, a delay
to its Pade approximant's accuracy (order 3 at 4 ms: the phase error of e^-sT
is below 0.1 % up to wT = 1.5, i.e. 60 Hz).
"""

from __future__ import annotations

import numpy as np
import pytest

from samii.diagnose.effects import LIBRARY, Effect
from samii.diagnose.export import augmented_frd, augmented_tf
from samii.diagnose.model import Baseline, Fit, notebook_reference
from samii.identify.structures import ModelStructure

VALUES = {
    "delay/command": {"delay_s": 0.004},
    "delay/theta_sensor": {"delay_s": 0.002},
    "delay/accel_sensor": {"delay_s": 0.003},
    "extra_mode/base_mode": {"freq_hz": 15.0, "zeta": 0.02, "residue": 0.02},
    "extra_mode/act_mode": {"freq_hz": 15.0, "zeta": 0.02, "zero_freq_hz": 14.0, "zero_zeta": 0.03},
    "sensor/accel_lowpass": {"corner_hz": 30.0},
    "sensor/accel_lowpass2": {"corner_hz": 60.0},
    "sensor/accel_highpass": {"corner_hz": 0.3},
    "sensor/accel_gain": {"gain": 1.1},
    "actuator/pole_zero": {"zero_hz": 5.0, "pole_hz": 8.0},
    "actuator/valve": {"freq_hz": 50.0, "zeta": 0.7},
    "actuator/leak": {"pole_per_s": 0.2},
}


def _fit(kind):
    st = ModelStructure.notebook_3mode()
    p = {k: v for k, v in notebook_reference().items() if k in st.param_names}
    eff = Effect(kind, VALUES[kind.label], {})
    return Fit(Baseline(structure=st, params=(p,)), (p,), ({},), (eff,), 0.0, 0, 0, ())


def test_every_kind_has_values():
    assert set(VALUES) == {k.label for k in LIBRARY}


@pytest.mark.parametrize("kind", LIBRARY, ids=lambda k: k.label)
@pytest.mark.parametrize("channel", ["act", "base", "total"])
def test_tf_matches_the_fitted_response(kind, channel):
    fit = _fit(kind)
    f = np.geomspace(0.1, 40.0, 200)
    if kind.label == "delay/theta_sensor" and channel == "base":
        with pytest.raises(ValueError, match="augmented_frd"):
            augmented_tf(fit, channel=channel)
        return
    exact = augmented_frd(fit, f, channel=channel)
    h_exact = exact.frdata[0, 0] if hasattr(exact, "frdata") else exact.fresp[0, 0]
    tf = augmented_tf(fit, channel=channel, pade_order=5)
    h_tf = tf(2j * np.pi * f)
    tol = 2e-3 if kind.category == "delay" else 1e-9
    np.testing.assert_allclose(h_tf, h_exact, rtol=tol)
    if kind.kind == "leak" and channel != "base":  # the integrator moved, not cancelled by a zero at 0
        assert np.min(np.abs(tf.poles())) == pytest.approx(0.2, rel=1e-9)
        if channel == "act":
            assert np.all(np.abs(tf.zeros()) > 1e-3)


@pytest.mark.parametrize("label", [k.label for k in LIBRARY])
def test_exported_total_is_stable(label):
    """The effects add no unstable pole to xdd/v (the Pade inverse of a theta delay would), but the one a leaky
    integrator found in the right half plane has (gravity's pull against the leakage: the physics found)."""
    fit = _fit(next(k for k in LIBRARY if k.label == label))
    poles = augmented_tf(fit, channel="total", pade_order=3).poles()
    unstable = poles[np.real(poles) >= 1e-9]
    if label == "actuator/leak":
        np.testing.assert_allclose(unstable, [VALUES[label]["pole_per_s"]], rtol=1e-9)
    else:
        assert unstable.size == 0


def test_total_is_proper_and_delay_needs_an_order():
    fit = _fit(next(k for k in LIBRARY if k.label == "delay/command"))
    tf = augmented_tf(fit, channel="total", pade_order=3)
    num, den = np.trim_zeros(tf.num[0][0], "f"), np.trim_zeros(tf.den[0][0], "f")
    assert num.size <= den.size
    with pytest.raises(ValueError, match="Pade order"):
        augmented_tf(fit, pade_order=None)
