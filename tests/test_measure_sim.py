"""Issue 3, item 6: the measurement in the simulator is right.

- at small amplitude the swept-sine FRF agrees with the linearised simulator
  within 1 dB and 5 deg wherever coherence > 0.95 between 0.5 and 35 Hz;
- swept and stepped sine agree within the same bounds;
- with sensor noise, coherence drops where the signal is weak, not elsewhere;
- at larger amplitude the hydraulic nonlinearity shows.

The reference is the simulator's own linearisation (samii.sim.linearize) in
discrete time at the physics step, which is what sampled data obey.
"""

import numpy as np
import pytest

pytest.importorskip("mujoco")

from samii.measure.campaign import linearised_frf, measure_stepped, measure_swept  # noqa: E402
from samii.measure.daq import SensorNoise  # noqa: E402
from samii.measure.excitation import SteppedSine, SweptSine  # noqa: E402
from samii.measure.frf import estimate_frf  # noqa: E402

BAND = (0.5, 35.0)
TOL_DB, TOL_DEG = 1.0, 5.0  # issue 3
SMALL_V = 0.02  # peak load pressure ~0.3 MPa, 4 % of the 7 MPa supply
LARGE_V = 0.5  # ~3.9 MPa, 55 % of supply


@pytest.fixture(scope="module")
def model():
    from samii.sim.model import load_model

    return load_model()


@pytest.fixture(scope="module")
def small(model):
    return measure_swept(model, SweptSine(amplitude_v=SMALL_V))


def _errors(measured, reference, channel, keep):
    ratio = measured.response(channel)[keep] / reference.response(channel)[keep]
    return float(np.max(np.abs(20 * np.log10(np.abs(ratio))))), float(np.max(np.abs(np.angle(ratio, deg=True))))


def test_small_amplitude_swept_sine_matches_the_linearised_simulator(model, small):
    frf = small.frf
    ref = linearised_frf(model, frf.freq_hz)
    band = (frf.freq_hz >= BAND[0]) & (frf.freq_hz <= BAND[1])
    for ch in ("act", "base", "total"):
        keep = band & (frf.coherence(ch) > 0.95)
        assert keep.sum() > 0.9 * band.sum(), ch
        err_db, err_deg = _errors(frf, ref, ch, keep)
        # measured (sign-alternating records): 0.06/0.36, 0.11/0.69, 0.11/0.69 dB/deg (act, base, total),
        # every point of the band above coherence 0.95; demand half the bounds
        assert err_db < TOL_DB / 2 and err_deg < TOL_DEG / 2, (ch, err_db, err_deg)


def test_swept_and_stepped_sine_agree(model, small):
    design = SteppedSine(freqs_hz=(1.0, 4.0, 9.0, 14.0, 28.0), amplitude_v=SMALL_V)
    stepped = measure_stepped(model, design).frf
    sweep = SweptSine(amplitude_v=SMALL_V)
    swept_at = estimate_frf(small.timeseries, record_s=sweep.record_s, baseline_s=sweep.lead_s, freqs_hz=stepped.freq_hz)
    ref = linearised_frf(model, stepped.freq_hz)
    for ch in ("act", "base", "total"):
        err_db, err_deg = _errors(swept_at, stepped, ch, slice(None))
        assert err_db < TOL_DB / 2 and err_deg < TOL_DEG / 2, (ch, err_db, err_deg)
        err_db, err_deg = _errors(stepped, ref, ch, slice(None))  # and the stepped sine is itself right
        assert err_db < 0.1 and err_deg < 0.5, (ch, err_db, err_deg)


@pytest.mark.slow
def test_noise_lowers_coherence_only_where_the_signal_is_weak(model):
    from samii.sim.plugin import hydraulic_params

    sweep = SweptSine()  # the default 0.1 V
    noise = SensorNoise()
    meas = measure_swept(model, sweep, noise=noise, rng=np.random.default_rng(11))
    frf = meas.frf
    f = frf.freq_hz
    # predicted coherence of each signal from the linearised closed loop, as for the linear rig
    from samii.measure.frf import fourier_at, split_records

    records, _ = split_records(meas.timeseries, record_s=sweep.record_s, baseline_s=sweep.lead_s)
    r_power = np.mean(np.abs(fourier_at(records["r"], f, 1000.0)) ** 2, axis=0)
    n_rec = records["r"].shape[1]
    ref = linearised_frf(model, f)
    loop = 1.0 + hydraulic_params(model).position_gain * ref.act
    closed = {"v": 1.0 / loop, "theta": ref.act / loop, "accel": ref.total / loop}
    std = noise.std()
    pred = {k: 1.0 / (1.0 + std[k] ** 2 * n_rec / (np.abs(h) ** 2 * r_power)) for k, h in closed.items()}
    pairs = {"act": ("theta", "v"), "base": ("accel", "theta"), "total": ("accel", "v")}
    n_weak = n_strong = 0
    for ch, (num, den) in pairs.items():
        predicted = pred[num] * pred[den]
        measured = frf.coherence(ch)
        strong, weak = predicted > 0.99, predicted < 0.2
        n_strong += strong.sum()
        n_weak += weak.sum()
        assert np.all(measured[strong] > 0.95), ch
        if weak.any():
            assert np.median(measured[weak]) < 0.6, ch
    assert n_weak > 20 and n_strong > 100


def test_larger_amplitude_shows_the_hydraulic_nonlinearity(model, small):
    large = measure_swept(model, SweptSine(amplitude_v=LARGE_V))
    f = large.frf.freq_hz
    ref = linearised_frf(model, f)
    near_resonance = (f >= 6.0) & (f <= 12.0)  # closed-loop hydraulic pair at 8.4 Hz
    small_db, _ = _errors(small.frf, ref, "act", near_resonance)
    large_db, _ = _errors(large.frf, ref, "act", near_resonance)
    assert small_db < 0.2 and large_db > 1.0, (small_db, large_db)
    # the load pressure explains it: a large fraction of the supply
    from samii.sim.plugin import hydraulic_params

    supply = hydraulic_params(model).supply_pressure
    assert np.max(np.abs(large.timeseries.p_load)) > 0.4 * supply > 4 * np.max(np.abs(small.timeseries.p_load))
