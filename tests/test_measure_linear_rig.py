"""The linear stand-in rig reproduces the notebook's closed-loop poles and its own transfer functions."""

import numpy as np
import pytest

from samii import notebook as nb
from samii.measure.linear_rig import DEG, LinearRig


def test_closed_loop_poles_are_eq10_1_and_the_base_modes():
    poles = LinearRig().closed_loop().poles()
    # eq 10.1: unity theta feedback around eq 9.4 puts the hydraulic pair at -4.214 +- 52.84j
    for p in nb.EQ10_1 + nb.EQ10_2:  # eq 10.2: base modes 1 and 3 are untouched by the theta loop
        assert np.min(np.abs(poles - p)) / abs(p) < 1e-3, p


def test_closed_loop_frequency_response_is_the_loop_algebra():
    rig = LinearRig()
    f = np.array([0.3, 2.0, 9.0, 30.0])
    resp = rig.closed_loop().frequency_response(2 * np.pi * f)
    h = np.asarray(resp.complex)[:, 0, :]  # outputs v, theta, accel
    exact = rig.exact_frf(f)
    loop = 1 + rig.position_gain_v_per_rad * exact.act
    np.testing.assert_allclose(h[0], 1 / loop, rtol=1e-9)
    np.testing.assert_allclose(h[1], exact.act / loop, rtol=1e-9)
    np.testing.assert_allclose(h[2], exact.total / loop, rtol=1e-7)


def test_units_follow_the_degree_reading_of_the_notebook():
    rig = LinearRig()
    # act ~ K1 / s at low frequency: K1 deg/(V s) = K1 * pi/180 rad/(V s)
    f = 1e-3
    assert abs(rig.exact_frf([f]).act[0]) * 2 * np.pi * f == pytest.approx(nb.EQ9_4["K1"] * DEG, rel=1e-4)
    assert rig.position_gain_v_per_rad == pytest.approx(180 / np.pi)


def test_simulation_reaches_the_sinusoidal_steady_state():
    rig = LinearRig()
    fs, f = 2000.0, 4.0
    t = np.arange(int(30 * fs)) / fs
    ts = rig.simulate(np.sin(2 * np.pi * f * t), sample_rate_hz=fs)
    last = t > 25  # 8 time constants of the slowest mode (3.1 s)
    basis = np.column_stack([np.cos(2 * np.pi * f * t[last]), np.sin(2 * np.pi * f * t[last])])
    (a, b), *_ = np.linalg.lstsq(basis, ts.theta[last], rcond=None)
    exact = rig.exact_frf([f])
    theta_r = exact.act[0] / (1 + rig.position_gain_v_per_rad * exact.act[0])
    assert complex(a, -b) == pytest.approx(theta_r * -1j, rel=1e-4)  # r = sin(wt) = Re(-j e^{jwt})
    assert ts.theta_ref is not None and np.all(ts.theta_ref == 0)
