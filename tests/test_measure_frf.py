"""The measurement chain on a linear closed loop whose FRF is known exactly.

Rig: the notebook's eq 9.4 transfer functions under unity position feedback
(samii.measure.linear_rig). Excitation -> physics-rate response -> DAQ (1 kHz,
anti-alias) -> estimator, compared with the exact open-loop FRF. Issue 3's
acceptance: within 1 dB and 5 deg wherever coherence > 0.95 between 0.5 and 35 Hz;
these tests demand 20x less.
"""

import numpy as np
import pytest

from samii.measure.daq import SensorNoise, acquire
from samii.measure.excitation import SteppedSine, SweptSine
from samii.measure.frf import estimate_frf, fourier_at, split_records
from samii.measure.linear_rig import LinearRig
from samii.measure.stepped import estimate_stepped

PHYS_HZ = 2000.0  # physics rate of the linear rig (first-order hold: exact to O((w dt)^2) = 2e-4 at 40 Hz)
DAQ_HZ = 1000.0
BAND = (0.5, 35.0)  # issue 3
TOL_DB, TOL_DEG = 1.0 / 20, 5.0 / 20  # the bounds with a factor-20 margin
#: Stepped sine on a base resonance (the default grid holds mode 1 at 1.75 Hz): the test's 5-time-constant
#: settle leaves e^-5 = 0.67 % of the transient, up to atan(0.0067) = 0.39 deg of phase in the window.
TOL_DEG_STEPPED = 0.4


@pytest.fixture(scope="module")
def rig():
    return LinearRig()


@pytest.fixture(scope="module")
def sweep():
    # The notebook's slowest mode (base mode 1, 1/(z1 w1) = 3.1 s, eq 9.4) needs a 15 s (5 time constants;
    # with sign-alternating records what rings on from the previous record lowers coherence)
    # rest, not the 45 s the default simulator's lighter mode needs. 2 V: the linear rig
    # has no pressure limit, and the noise test wants the rig's signal levels.
    return SweptSine(amplitude_v=2.0, tail_s=15.0)


@pytest.fixture(scope="module")
def swept_physics(rig, sweep):
    t = np.arange(int(round(sweep.duration_s * PHYS_HZ))) / PHYS_HZ
    return rig.simulate(sweep.signal(t), sample_rate_hz=PHYS_HZ)


@pytest.fixture(scope="module")
def swept(swept_physics):
    return acquire(swept_physics, sample_rate_hz=DAQ_HZ)


@pytest.fixture(scope="module")
def swept_frf(swept, sweep):
    return estimate_frf(swept, record_s=sweep.record_s, baseline_s=sweep.lead_s)


@pytest.fixture(scope="module")
def stepped_design():
    # settle 5 time constants of the notebook's base mode 1 (3.1 s, eq 9.4)
    return SteppedSine(amplitude_v=2.0, settle_s=15.4, ramp_s=1.0)


@pytest.fixture(scope="module")
def stepped_frf(rig, stepped_design):
    t = np.arange(int(round(stepped_design.duration_s * PHYS_HZ))) / PHYS_HZ
    ts = acquire(rig.simulate(stepped_design.signal(t), sample_rate_hz=PHYS_HZ), sample_rate_hz=DAQ_HZ)
    return estimate_stepped(ts, freqs_hz=stepped_design.freqs_hz, windows_s=stepped_design.windows_s)


def _errors(measured, exact, channel, keep):
    db = measured.magnitude_db(channel)[keep] - exact.magnitude_db(channel)[keep]
    deg = np.angle(measured.response(channel)[keep] / exact.response(channel)[keep], deg=True)
    return np.max(np.abs(db)), np.max(np.abs(deg))


def test_swept_sine_matches_exact_frf(swept_frf, rig):
    exact = rig.exact_frf(swept_frf.freq_hz)
    band = (swept_frf.freq_hz >= BAND[0]) & (swept_frf.freq_hz <= BAND[1])
    assert np.count_nonzero(band) > 150  # 100 points per decade over 1.85 decades
    for ch in ("act", "base", "total"):
        keep = band & (swept_frf.coherence(ch) > 0.95)
        assert np.all(keep[band]), ch  # noise-free: coherent everywhere in the band
        err_db, err_deg = _errors(swept_frf, exact, ch, keep)
        assert err_db < TOL_DB and err_deg < TOL_DEG, (ch, err_db, err_deg)


def test_actuator_channel_exact_over_the_whole_sweep(swept_frf, rig):
    # theta and v are strong at every frequency of the 0.1-40 Hz sweep; what is left is the
    # rig's first-order-hold discretisation, (w dt)^2 / 12 = 1.3e-3 (0.011 dB) at 40 Hz and 2 kHz
    err_db, err_deg = _errors(swept_frf, rig.exact_frf(swept_frf.freq_hz), "act", slice(None))
    assert err_db < 0.02 and err_deg < 0.02


def test_stepped_sine_matches_exact_frf(stepped_frf, rig, stepped_design):
    np.testing.assert_allclose(stepped_frf.freq_hz, sorted(stepped_design.freqs_hz))
    exact = rig.exact_frf(stepped_frf.freq_hz)
    for ch in ("act", "base", "total"):
        assert np.all(stepped_frf.coherence(ch) > 0.99)
        err_db, err_deg = _errors(stepped_frf, exact, ch, slice(None))
        assert err_db < TOL_DB and err_deg < TOL_DEG_STEPPED, (ch, err_db, err_deg)


def test_swept_and_stepped_agree(swept, sweep, stepped_frf):
    at_steps = estimate_frf(swept, record_s=sweep.record_s, baseline_s=sweep.lead_s, freqs_hz=stepped_frf.freq_hz)
    np.testing.assert_array_equal(at_steps.freq_hz, stepped_frf.freq_hz)
    for ch in ("act", "base", "total"):
        err_db, err_deg = _errors(at_steps, stepped_frf, ch, slice(None))
        assert err_db < TOL_DB and err_deg < TOL_DEG_STEPPED, (ch, err_db, err_deg)


def test_fft_grid_equals_direct_fourier_sums(swept, sweep, swept_frf):
    pick = swept_frf.freq_hz[::37]
    direct = estimate_frf(swept, record_s=sweep.record_s, baseline_s=sweep.lead_s, freqs_hz=pick)
    for ch in ("act", "base", "total"):
        np.testing.assert_allclose(direct.response(ch), swept_frf.response(ch)[::37], rtol=1e-9)


def test_metadata_states_estimator_records_window_and_coherence(swept_frf):
    meta = swept_frf.metadata
    assert "instrument variable" in meta["frf_estimator"]
    assert meta["frf_records"].startswith("3 records")
    assert "rectangular" in meta["frf_window"]
    assert "channel = g_r,num * g_r,den" in meta["frf_coherence"]
    assert meta["sample_rate_hz"] == "1000"


def test_noise_lowers_coherence_where_the_signal_is_weak_and_nowhere_else(swept_physics, sweep, swept_frf, rig):
    noise = SensorNoise()
    noisy = acquire(swept_physics, sample_rate_hz=DAQ_HZ, noise=noise, rng=np.random.default_rng(3))
    frf = estimate_frf(noisy, record_s=sweep.record_s, baseline_s=sweep.lead_s)
    f = frf.freq_hz
    # predicted coherence of each signal: SNR / (1 + SNR), SNR = |H_ry R|^2 / (noise std^2 * samples per record)
    records, _ = split_records(noisy, record_s=sweep.record_s, baseline_s=sweep.lead_s)
    r_power = np.mean(np.abs(fourier_at(records["r"], f, DAQ_HZ)) ** 2, axis=0)
    n_rec = records["r"].shape[1]
    exact = rig.exact_frf(f)
    g = exact.act
    loop = 1.0 + rig.position_gain_v_per_rad * g
    closed = {"v": 1.0 / loop, "theta": g / loop, "accel": exact.total / loop}
    std = noise.std()
    pred = {k: 1.0 / (1.0 + std[k] ** 2 * n_rec / (np.abs(h) ** 2 * r_power)) for k, h in closed.items()}
    pairs = {"act": ("theta", "v"), "base": ("accel", "theta"), "total": ("accel", "v")}
    weak_total = strong_total = 0
    for ch, (num, den) in pairs.items():
        predicted = pred[num] * pred[den]
        measured = frf.coherence(ch)
        strong, weak = predicted > 0.99, predicted < 0.2
        weak_total += np.count_nonzero(weak)
        strong_total += np.count_nonzero(strong)
        assert np.all(measured[strong] > 0.95), ch  # nowhere else
        if np.any(weak):
            assert np.median(measured[weak]) < 0.6, ch  # 3 averages: an incoherent estimate has mean 1/3
            assert np.all(swept_frf.coherence(ch)[weak] > 0.95)  # ... and it was the noise
    assert weak_total > 20 and strong_total > 300
    # where it is weak: the acceleration below 0.5 Hz (xdd ~ s^4 theta)
    assert np.median(frf.base_coh[f < 0.3]) < 0.6 and np.median(frf.base_coh[(f > 2) & (f < 8)]) > 0.99


def test_one_record_gives_no_coherence(swept, sweep):
    one = estimate_frf(swept, record_s=sweep.duration_s, baseline_s=sweep.lead_s)
    assert one.act_coh is None and "not estimated" in one.metadata["frf_coherence"]


def test_bad_inputs(swept, sweep):
    from samii.timeseries import TimeSeries

    no_r = TimeSeries(t=swept.t, v=swept.v, theta=swept.theta, accel=swept.accel)
    with pytest.raises(ValueError, match="excitation signal r"):
        estimate_frf(no_r, record_s=sweep.record_s, baseline_s=sweep.lead_s)
    with pytest.raises(ValueError, match="shorter than one record"):
        estimate_frf(swept, record_s=2 * sweep.duration_s, baseline_s=1.0)
    with pytest.raises(ValueError, match="no energy"):
        estimate_frf(swept, record_s=sweep.record_s, baseline_s=sweep.lead_s, band_hz=(50.0, 200.0))
    with pytest.raises(ValueError, match="Nyquist"):
        estimate_frf(swept, record_s=sweep.record_s, baseline_s=sweep.lead_s, band_hz=(1.0, 600.0))
    with pytest.raises(ValueError, match="windows"):
        estimate_stepped(swept, freqs_hz=[1.0, 2.0], windows_s=[[1.0, 2.0]])
    with pytest.raises(ValueError, match="outside the data"):
        estimate_stepped(swept, freqs_hz=[1.0], windows_s=[[swept.t[-1] + 1, swept.t[-1] + 2]])


def test_alternating_signs_cancel_even_order_distortion(rig, sweep):
    """An even-order term in the acceleration (k theta^2, as link 2's CG height l cos(theta)
    gives) biases identical repeated sweeps with coherence ~1; sign-alternating records
    cancel it from the estimate, and their coherence shows where it was."""
    from dataclasses import replace

    exact = None
    out = {}
    for alternate in (True, False):
        sw = replace(sweep, alternate_sign=alternate)
        t = np.arange(int(round(sw.duration_s * PHYS_HZ))) / PHYS_HZ
        phys = rig.simulate(sw.signal(t), sample_rate_hz=PHYS_HZ)
        k = 0.3 * np.max(np.abs(phys.accel)) / np.max(phys.theta**2)  # distortion peaks at 30 % of the signal
        distorted = replace(phys, accel=phys.accel + k * phys.theta**2)
        frf = estimate_frf(acquire(distorted, sample_rate_hz=DAQ_HZ), record_s=sw.record_s, baseline_s=sw.lead_s)
        exact = rig.exact_frf(frf.freq_hz) if exact is None else exact
        band = (frf.freq_hz >= BAND[0]) & (frf.freq_hz <= BAND[1])
        err_db = np.abs(20 * np.log10(np.abs(frf.base / exact.base)))[band]
        out[alternate] = (err_db, frf.base_coh[band], frf.metadata["frf_record_weights"])
    err_alt, coh_alt, how = out[True]
    err_same, coh_same, _ = out[False]
    assert "+-+" in how and "cancels" in how
    assert np.max(err_alt) < TOL_DB  # as clean as without distortion
    assert np.max(err_same) > 1.0 and np.min(coh_same) > 0.99  # biased, and coherence does not tell
    assert np.min(coh_alt) < 0.9  # the alternating records' coherence does


def test_stepped_coherence_is_the_spectral_coherence_of_the_estimate():
    """A sine of amplitude A in white noise s over N samples: the least-squares amplitude has
    error power 4 s^2/N, so coherence = A^2/(A^2 + 4 s^2/N); checked against the spread of
    the estimate over seeded trials, and a harmonic barely lowers it."""
    from samii.measure.stepped import sine_amplitude

    fs, f, n, amp, s = 1000.0, 5.0, 2000, 0.01, 0.2  # 10 periods; SNR per sample -29 dB
    t = np.arange(n) / fs
    rng = np.random.default_rng(7)
    est, coh = zip(*(sine_amplitude(amp * np.sin(2 * np.pi * f * t) + rng.normal(0, s, n), t, f) for _ in range(400)))
    expected = amp**2 / (amp**2 + 4 * s**2 / n)  # 0.56
    assert np.mean(coh) == pytest.approx(expected, rel=0.1)
    err_power = np.mean(np.abs(np.asarray(est) - (-1j * amp)) ** 2)  # sin = Re(-j e^{jwt})
    assert err_power == pytest.approx(4 * s**2 / n, rel=0.15)
    clean = amp * np.sin(2 * np.pi * f * t) + 0.1 * amp * np.sin(2 * np.pi * 2 * f * t)
    assert sine_amplitude(clean, t, f)[1] > 0.999


def test_record_signs_are_read_off_a_fast_sweep_or_stated():
    """Records are cut at whole samples: a repeat is shifted by up to half a sample, which
    a sweep to 100 Hz at 1 kHz turns into |rho| = 0.99; the signs must still be found."""
    from samii.measure.frf import record_weights

    sw = SweptSine(stop_hz=100.0, start_hz=1.0, tail_s=2.0, lead_s=0.5)
    fs = 1000.0
    r = sw.signal(np.arange(int(sw.duration_s * fs)) / fs)
    n = int(np.floor(sw.record_s * fs))
    starts = np.round(np.arange(sw.repetitions) * sw.record_s * fs).astype(int)
    recs = np.stack([r[s : s + n] for s in starts])
    w, how = record_weights(recs)
    np.testing.assert_allclose(w, [0.25, 0.5, 0.25])
    assert "+-+" in how and "read off" in how
    w, how = record_weights(recs, sw.record_signs)
    assert "stated" in how and sw.record_signs == (1, -1, 1)
    with pytest.raises(ValueError, match="record signs"):
        record_weights(recs, (1, 0, 1))
    rng = np.random.default_rng(0)
    w, how = record_weights(rng.normal(size=(3, 1000)))  # not one excitation repeated
    assert "uniform" in how


def test_stepped_coherence_reads_the_noise_at_the_dwell_not_a_hum_far_from_it():
    """Mains hum at 50 Hz, 30x the white noise, beside a 5 Hz dwell: the estimate's error is the white noise's alone
    (the fit over whole periods of 5 Hz is blind to 50 Hz), and so is the stated error power (read next to the dwell);
    the residual's whole variance stated it 900x too large."""
    from samii.measure.stepped import sine_amplitude

    fs, f, n, amp, s = 1000.0, 5.0, 2000, 0.01, 0.02
    t = np.arange(n) / fs
    rng = np.random.default_rng(8)
    runs = [
        sine_amplitude(amp * np.sin(2 * np.pi * f * t) + 0.6 * np.sin(2 * np.pi * 50.0 * t + rng.uniform(0, 6.3)) + rng.normal(0, s, n), t, f)
        for _ in range(300)
    ]
    est, coh = np.array([r[0] for r in runs]), np.array([r[1] for r in runs])
    observed = np.mean(np.abs(est - (-1j * amp)) ** 2)
    stated = np.mean(amp**2 * (1.0 - coh) / coh)  # 4 s^2/N from g = A^2/(A^2 + 4 s^2/N)
    assert observed == pytest.approx(4 * s**2 / n, rel=0.2)
    assert stated == pytest.approx(observed, rel=0.25)
