"""The diagnosis fit's analytic Jacobian (issue 11, item 7: speed).

Every effect kind's derivatives (``EffectKind.derivatives``) and the fit's whole
Jacobian (``samii.diagnose.model._Problem.jacobian``) are checked against central
differences of the same residuals: a free notebook baseline over two files, an
additive extra mode beside factors on both channels, a per-file correction, a
fixed baseline, and the simulator's local structure. The agreement expected is
that of a central difference with a relative step of 1e-6 (truncation ~1e-12,
round-off ~1e-10 of the column's scale): 1e-6 relative leaves room for both.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative

from samii.diagnose.effects import LIBRARY
from samii.diagnose.model import Baseline, Dataset, _Layout, _Problem, fit_model, notebook_reference
from samii.frequency_response import FrequencyResponse
from samii.identify.structures import ModelStructure

KINDS = {k.label: k for k in LIBRARY}
#: a value inside every parameter's range, away from its bounds (Hz, s, 1, residue)
VALUES = {
    "delay_s": 0.003,
    "freq_hz": 12.0,
    "zeta": 0.05,
    "residue": 0.02,
    "zero_freq_hz": 10.0,
    "zero_zeta": 0.03,
    "gain": 1.1,
    "zero_hz": 5.0,
    "pole_hz": 9.0,
    "pole_per_s": 0.3,
}


def _values(kind):
    corner = 0.5 if kind.kind == "accel_highpass" else 20.0
    return np.array([VALUES.get(p.name, corner) for p in kind.params])


@pytest.mark.parametrize("kind", LIBRARY, ids=lambda k: k.label)
def test_effect_derivatives_match_central_differences(kind):
    s = 2j * np.pi * np.geomspace(0.1, 40.0, 60)
    p = _values(kind)
    resp, deriv = kind.response(p, s), kind.derivatives(p, s)
    assert any(r is not None for r in resp)
    for j, (r, d) in enumerate(zip(resp, deriv)):
        assert (r is None) == (d is None), f"{kind.label}: output {j} has a response but no derivative, or the reverse"
        if r is None:
            continue
        assert d.shape == (s.size, p.size)

        def f(q):  # the log of a factor, the added term itself
            out = kind.response(q, s)[j]  # noqa: B023 - called within this iteration
            return np.log(out) if j < 2 else out  # noqa: B023 - called within this iteration

        num = np.empty_like(d)
        for c in range(p.size):
            h = 1e-6 * abs(p[c])
            up, dn = p.copy(), p.copy()
            up[c] += h
            dn[c] -= h
            num[:, c] = (f(up) - f(dn)) / (2 * h)
        assert np.max(np.abs(num - d)) <= 1e-6 * np.max(np.abs(d))


def _dataset(freq_hz, rng, source):
    """Eq 9.4 (SI) with 3 % log noise on theta/v and xdd/v, the usable points everywhere."""
    st = ModelStructure.notebook_3mode()
    ref = notebook_reference()
    data, keep, inv = {}, {}, {}
    for ch in ("act", "total"):
        h = st.response(ref, freq_hz, ch) * np.exp(0.03 * (rng.standard_normal(freq_hz.size) + 1j * rng.standard_normal(freq_hz.size)))
        data[ch], keep[ch], inv[ch] = h, np.ones(freq_hz.size, bool), np.full(freq_hz.size, 1 / 0.03)
    return Dataset(source, freq_hz, data, keep, inv, True, 1.0, 0.1)


def _effects():
    return [
        (KINDS["extra_mode/base_mode"], np.array([15.0, 0.03, 0.01])),
        (KINDS["delay/theta_sensor"], np.array([0.002])),
        (KINDS["sensor/accel_lowpass"], np.array([30.0])),
        (KINDS["extra_mode/act_mode"], np.array([20.0, 0.05, 18.0, 0.04])),
        (KINDS["actuator/valve"], np.array([60.0, 0.7])),
    ]


def _kept_is_fresh(problem, z, analytic):
    """The Jacobian the residuals keep for the optimiser's next call (``_Problem.residuals``) is the one computed afresh
    at that point, bit for bit; it is given (not computed again) once, and not for another point."""
    problem.residuals(z)
    kept = problem._last[1]
    assert problem.jacobian(z) is kept and np.array_equal(kept, analytic)  # given, not computed again
    assert problem._last is None  # given once
    problem.residuals(z + 0.01)
    assert np.array_equal(problem.jacobian(z), analytic)


def _check(datasets, baseline, effects, free, xb, every_column=True):
    kinds = [k for k, _ in effects]
    xe = [v for _, v in effects]
    layout = _Layout(baseline, len(datasets), kinds, xb, xe, free)
    problem = _Problem(datasets, baseline, layout, xb)
    z = layout.to_z(xb, xe) + 0.01 * np.random.default_rng(1).standard_normal(layout.to_z(xb, xe).size)
    analytic = problem.jacobian(z)
    _kept_is_fresh(problem, z, analytic)
    numeric = approx_derivative(problem.residuals, z, method="3-point", rel_step=1e-6)
    assert analytic.shape == numeric.shape == (problem.residuals(z).size, z.size)
    scale = np.max(np.abs(numeric), axis=0)
    if every_column:
        assert np.all(scale > 0)
    # a column the data do not depend on (the actuator's parameters for xdd/theta alone, a theta delay in xdd/v,
    # where it cancels) is zero analytically and round-off numerically: judged against the largest column
    scale = np.maximum(scale, 1e-5 * scale.max())
    assert np.max(np.abs(analytic - numeric) / scale) < 1e-6


def test_fit_jacobian_free_baseline_two_files_with_correction():
    rng = np.random.default_rng(0)
    f1, f2 = np.geomspace(0.2, 40.0, 120), np.geomspace(0.3, 35.0, 90)
    ds = [_dataset(f1, rng, "a"), _dataset(f2, rng, "b")]
    st = ModelStructure.notebook_3mode()
    ref = notebook_reference()
    # a correction on its own grid (interpolated onto each file's): a smooth complex factor on each channel
    fc = np.geomspace(0.1, 50.0, 200)
    corr = FrequencyResponse(fc, metadata={}, act=1.02 * np.exp(-2j * np.pi * fc * 1e-4), base=0.98 * np.exp(1j * 0.01 * np.log(fc)))
    bl = Baseline(structure=st, params=(ref, ref), reference=ref, correction=(corr, corr))
    xb = [st.vector(ref) * 1.01, st.vector(ref) * 0.99]
    _check(ds, bl, _effects(), True, xb)
    _check(ds, bl, _effects(), False, xb)  # the baseline held: the effects' columns only


def test_fit_jacobian_fixed_baseline():
    rng = np.random.default_rng(2)
    f = np.geomspace(0.2, 40.0, 100)
    ds = _dataset(f, rng, "a")
    st = ModelStructure.notebook_3mode()
    ref = notebook_reference()
    fixed = {ch: {c: st.response(ref, f, c) for c in need} for ch, need in (("act", ("act",)), ("total", ("act", "base")))}
    bl = Baseline(fixed=(fixed,), label="a saved fit")
    effects = _effects()[:3] + [(KINDS["sensor/accel_gain"], np.array([1.05]))]
    _check([ds], bl, effects, False, [])


def test_fit_jacobian_simulator_structure():
    from samii.diagnose.simulator import LocalSimulator
    from samii.sim.model import default_params

    rng = np.random.default_rng(3)
    f = np.geomspace(0.3, 35.0, 60)
    ds = _dataset(f, rng, "a")
    st = LocalSimulator(default_params())
    x0 = st.params(st.x0)
    bl = Baseline(structure=st, params=(x0,), reference=None)
    _check([ds], bl, _effects()[:3], True, [st.x0 * 1.05])


def test_fit_recovers_effects_with_the_analytic_jacobian():
    """The fit with the analytic Jacobian reaches the values the data were made with: eq 9.4 times a 4 ms
    command delay and a 30 Hz roll-off, no noise, from starts 25-50 % off."""
    f = np.geomspace(0.2, 40.0, 150)
    st = ModelStructure.notebook_3mode()
    ref = notebook_reference()
    s = 2j * np.pi * f
    act = st.response(ref, f, "act") * np.exp(-s * 0.004)
    total = act * st.response(ref, f, "base") / (1 + s / (2 * np.pi * 30.0))
    ones = np.ones(f.size, bool)
    ds = Dataset(
        "exact",
        f,
        {"act": act, "total": total},
        {"act": ones, "total": ones},
        {"act": np.full(f.size, 100.0), "total": np.full(f.size, 100.0)},
        True,
        1.0,
        0.1,
    )
    bl = Baseline(structure=st, params=(ref,), reference=ref)
    fit = fit_model([ds], bl, [(KINDS["delay/command"], np.array([0.002])), (KINDS["sensor/accel_lowpass"], np.array([45.0]))])
    assert fit.chi2 < 1e-12
    assert fit.effects[0].values["delay_s"] == pytest.approx(0.004, rel=1e-6)
    assert fit.effects[1].values["corner_hz"] == pytest.approx(30.0, rel=1e-6)


def _eq94_dataset(channels, f, rng, **kw) -> Dataset:
    """Eq 9.4 (SI) on ``channels`` with 3 % log noise, every point usable."""
    st, ref = ModelStructure.notebook_3mode(), notebook_reference()
    data, keep, inv = {}, {}, {}
    for ch in channels:
        h = st.response(ref, f, ch) * np.exp(0.03 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)))
        data[ch], keep[ch], inv[ch] = h, np.ones(f.size, bool), np.full(f.size, 1 / 0.03)
    return Dataset("one", f, data, keep, inv, True, 1.0, 0.1, **kw)


@pytest.mark.parametrize("channels", [("act",), ("base",), ("total",), ("act", "base"), ("base", "total")])
def test_fit_jacobian_every_channel_set_every_kind(channels):
    """One or two channels of a file, every kind of the library at once (two extra base modes among them), in a
    shuffled order, the baseline free: the Jacobian still equals central differences (each kind's derivative
    enters only the channels it affects)."""
    rng = np.random.default_rng(5)
    st, ref = ModelStructure.notebook_3mode(), notebook_reference()
    ds = _eq94_dataset(channels, np.geomspace(0.2, 40.0, 80), rng)
    effects = [(k, _values(k)) for k in LIBRARY if not k.needs_fixed_baseline]
    effects.append((KINDS["extra_mode/base_mode"], np.array([27.0, 0.04, -0.005])))
    effects = [effects[i] for i in rng.permutation(len(effects))]
    bl = Baseline(structure=st, params=(ref,), reference=ref)
    _check([ds], bl, effects, True, [st.vector(ref) * 1.02], every_column=False)


def _masked_dataset(rng):
    """Eq 9.4 on all three channels, each with its own usable points (theta/v below 20 Hz, xdd/theta from 0.5 Hz,
    xdd/v every other point), 3 % log noise."""
    f = np.geomspace(0.2, 40.0, 90)
    st = ModelStructure.notebook_3mode()
    ref = notebook_reference()
    keep = {"act": f < 20.0, "base": f > 0.5, "total": np.arange(f.size) % 2 == 0}
    data, inv = {}, {}
    for ch, k in keep.items():
        noise = np.exp(0.03 * (rng.standard_normal(k.sum()) + 1j * rng.standard_normal(k.sum())))
        data[ch], inv[ch] = st.response(ref, f[k], ch) * noise, np.full(k.sum(), 1 / 0.03)
    return Dataset("masked", f, data, keep, inv, True, 1.0, 0.1), st, ref


@pytest.mark.parametrize("free", [True, False])
def test_each_channel_is_judged_on_its_own_usable_points(free):
    """The baseline is evaluated once per file on its whole grid and each channel takes its usable points from it
    (the held baseline once per fit): the residual of every channel is ln(data / model) at that channel's own points,
    as the structure gives them there, and the Jacobian still equals central differences."""
    ds, st, ref = _masked_dataset(np.random.default_rng(7))
    xb = [st.vector(ref) * 1.01]
    effect = [(KINDS["delay/command"], np.array([0.003])), (KINDS["sensor/accel_lowpass"], np.array([25.0]))]
    layout = _Layout(Baseline(structure=st, params=(ref,), reference=ref), 1, [k for k, _ in effect], xb, [v for _, v in effect], free)
    problem = _Problem([ds], layout.baseline, layout, xb)
    res, _, _ = problem.evaluate(layout.to_z(xb, [v for _, v in effect]))
    p = st.params(xb[0])
    for ch, k in ds.keep.items():
        s = 2j * np.pi * ds.freq_hz[k]
        model = st.response(p, ds.freq_hz[k], ch)
        if ch in ("act", "total"):
            model = model * np.exp(-s * 0.003)
        if ch in ("base", "total"):
            model = model / (1 + s / (2 * np.pi * 25.0))
        assert res[0][ch].shape == (k.sum(),)
        assert np.allclose(res[0][ch], np.log(ds.data[ch] / model), rtol=0, atol=1e-12)
    _check([ds], layout.baseline, effect, free, xb)


@pytest.mark.parametrize("channels", [("act", "total"), ("act", "base"), ("base", "total")])
@pytest.mark.parametrize("free_lag, hold", [(True, False), (False, False), (True, True), (False, True), (None, True)])
def test_fit_jacobian_with_the_sampled_feedthrough(channels, free_lag, hold):
    """The sampled feedthrough's term (model.feedthrough_term) on xdd/v and xdd/theta, every kind of the library
    (delays delay the step; a low-pass, a valve or an extra mode change what reaches it), the baseline free and the
    lag free or held: the Jacobian equals central differences, the lag's column included. With the command's hold
    in the baseline (Baseline.hold_s) too: its sinc, the steps and the images of every channel (model.sampled_images),
    with the lag free, held, or not modelled (None: the steps read as the rest)."""
    rng = np.random.default_rng(11)
    st, ref = ModelStructure.notebook_3mode(), notebook_reference()
    ds = _eq94_dataset(channels, np.geomspace(0.2, 40.0, 70), rng, sample_rate_hz=500.0)
    effects = [(k, _values(k)) for k in LIBRARY if not k.needs_fixed_baseline and k.kind not in ("accel_lowpass", "accel_lowpass2", "valve")]
    effects.append((KINDS["sensor/accel_lowpass"], np.array([4000.0])))  # a corner near FEEDTHROUGH_AT_FS: D neither whole nor zero
    effects = [effects[i] for i in rng.permutation(len(effects))]
    bl = Baseline(
        structure=st,
        params=(ref,),
        reference=ref,
        feedthrough_lag=None if free_lag is None else 0.4,
        sample_rates_hz=(500.0,),
        hold_s=(0.001,) if hold else (),
    )
    xb = [st.vector(ref) * 1.02]
    xe = [v for _, v in effects]
    layout = _Layout(bl, 1, [k for k, _ in effects], xb, xe, True, 0.3 if free_lag else None)
    held_lag = None if free_lag in (True, None) else 0.4
    problem = _Problem([ds], bl, layout, xb, held_lag=held_lag)
    z = layout.to_z(xb, xe)
    if free_lag:
        z = np.append(z, 0.3)
    if hold:  # the data are the sampled model's (eq 9.4's continuous xdd at 0.2-0.3 Hz, where the images are as large as
        # it, is half a turn from it: a residual on the log's branch cut jumps under a central difference)
        e0 = problem.evaluate(z)[0][0]
        ds = replace(ds, data={ch: ds.data[ch] * np.exp(-e0[ch]) * np.exp(0.03 * rng.standard_normal(e0[ch].size)) for ch in ds.data})
        problem = _Problem([ds], bl, layout, xb, held_lag=held_lag)
    z = z + 0.01 * rng.standard_normal(z.size)
    analytic = problem.jacobian(z)
    _kept_is_fresh(problem, z, analytic)
    numeric = approx_derivative(problem.residuals, z, method="3-point", rel_step=1e-6)
    scale = np.max(np.abs(numeric), axis=0)
    if free_lag:
        assert scale[-1] > 1e-2 * scale.max()  # the lag moves the residual: at 500 Hz the feedthrough is material
    scale = np.maximum(scale, 1e-5 * scale.max())
    assert np.max(np.abs(analytic - numeric) / scale) < 1e-6
