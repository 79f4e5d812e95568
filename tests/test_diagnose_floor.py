"""The systematic floor (samii.measure.floor) and the identifiability and practical-significance refusals
(samii.diagnose.select): what repeats in every record is measured, and a candidate the data cannot identify
or that the floor could produce is refused with its reason."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from samii.diagnose.effects import LIBRARY, Effect
from samii.diagnose.rig import EffectRig
from samii.diagnose.select import _below_floor, _f_limit, _f_test, _refused, _unidentifiable, search_places, within_sampling
from samii.measure.excitation import SweptSine
from samii.measure.floor import PRACTICAL_FACTOR, REL_FLOOR, controller_fir, estimator_bias, quantisation_step, with_floor
from samii.measure.measured import from_timeseries

FS = 1000.0
KIND = {k.kind: k for k in LIBRARY}


def test_quantisation_step_finds_an_encoders_count_and_nothing_in_smooth_data():
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.standard_normal(20000)) * 1e-4
    q = 2 * np.pi / 2**16  # a 16-bit encoder over one revolution
    assert quantisation_step(np.round(x / q) * q + 0.3) == pytest.approx(q, rel=1e-6)
    assert quantisation_step(x) is None
    assert quantisation_step(np.array([float(f"{v:.6g}") for v in x])) is None  # a CSV's rounding is no lattice


def test_controller_fir_reads_an_analogue_and_a_digital_loop():
    rng = np.random.default_rng(1)
    n = 60000
    t = np.arange(n) / FS
    r = 0.1 * np.sin(2 * np.pi * (0.2 + 0.5 * t / t[-1] * 20) * t)
    theta = np.convolve(r, np.ones(200) / 200, mode="same")  # any smooth motion driven by r
    kp = 180 / np.pi
    noisy = theta + 5e-5 * rng.standard_normal(n)  # the recorded theta
    c, explained = controller_fir(noisy, r - kp * theta, r, FS)  # an analogue loop acts on the true theta
    assert c.size == 1 and c[0] == pytest.approx(kp, rel=2e-3) and explained > 0.99
    v = r.copy()
    v[1:] -= kp * noisy[:-1]  # a digital loop acting on the last reading
    c, explained = controller_fir(noisy, v, r, FS)
    assert c.size == 2 and c[0] == pytest.approx(0.0, abs=0.01 * kp) and c[1] == pytest.approx(kp, rel=2e-3)


def _sweep(**kw):
    sw = SweptSine(repetitions=3, amplitude_v=0.1, seconds_per_octave=4.0, **kw)
    return sw.signal(np.arange(int(round(sw.duration_s * FS))) / FS)


def test_estimator_bias_is_the_estimators_own_error_on_noise_free_data():
    """Sweeps up with no rest between them: base mode 1 rings into the next record, and the weak low-frequency
    xdd/v is biased by it (SweptSine's docstring). The bias measured through the rig's own model is the error
    the estimator makes on that rig's noise-free data, point by point; with rest between the sweeps it is nil."""
    rig = EffectRig.drawn(np.random.default_rng(5))
    truth = lambda f: {"act": rig.responses(f)["G"], "base": rig.responses(f)["B"]}  # noqa: E731
    worst = []
    for kw in ({"direction": "up", "tail_s": 0.0, "lead_s": 0.0}, {"tail_s": 20.0}):
        m = from_timeseries(rig.simulate(_sweep(**kw), sample_rate_hz=FS), source="rig.csv")
        bias, how = estimator_bias(m, truth)
        assert bias is not None, how
        f = m.frf.freq_hz
        t = truth(f)
        actual = m.frf.total / (t["act"] * t["base"]) - 1.0
        np.testing.assert_allclose(bias["total"], actual, rtol=1e-4, atol=1e-7)
        np.testing.assert_allclose(bias["act"], m.frf.act / t["act"] - 1.0, rtol=1e-4, atol=1e-6)
        worst.append(np.max(np.abs(actual[(f > 1.0) & (f < 3.0)])))
    print(worst)
    assert worst[0] > 1e-2 and worst[1] < 1e-3  # 5 % near base mode 1 without rest; 2e-5 with 20 s of it


def test_with_floor_adds_the_relative_floor_and_quantisation_to_every_point():
    rng = np.random.default_rng(2)
    rig = EffectRig.drawn(rng)
    ts = rig.simulate(_sweep(), sample_rate_hz=FS, rng=rng)
    q = 2 * np.pi / 2**14
    from dataclasses import replace

    coarse = replace(ts, theta=np.round(ts.theta / q) * q)
    for series, quantised in ((ts, False), (coarse, True)):
        m = from_timeseries(series, source="rig.csv")
        fl = with_floor(m)
        assert fl.floor is not None and ("theta" in fl.floor.quant_steps) is quantised
        for ch in m.frf.channels:
            added = fl.var[ch] - m.var[ch]
            assert np.all(added >= REL_FLOOR**2 * (1 - 1e-9))
            np.testing.assert_allclose(added, fl.floor.var[ch])
        if quantised:
            assert fl.floor.quant_steps["theta"] == pytest.approx(q, rel=1e-6)
            # theta's rounding error over theta's power: largest where theta is smallest (the band's top)
            assert fl.floor.var["act"][-1] > 10 * REL_FLOOR**2


def _effect(kind, se=None, **values):
    k = KIND[kind]
    return Effect(k, values, se or {p.name: 0.01 * abs(values[p.name]) for p in k.params})


def _datasets(lo=0.1, hi=40.0, record_s=120.0, fs=1000.0):
    f = np.geomspace(lo, hi, 300)
    return [SimpleNamespace(freq_hz=f, keep={"act": np.ones(f.size, bool)}, record_s=record_s, sample_rate_hz=fs)]


@pytest.mark.parametrize(
    "effect, reason",
    [
        (_effect("pole_zero", zero_hz=0.01, pole_hz=0.012), "below the excited band"),  # a constant gain in the band
        (_effect("pole_zero", zero_hz=23.0, pole_hz=62.7, se={"zero_hz": 80.0, "pole_hz": 300.0}), "not determined by the data"),
        (_effect("leak", pole_per_s=-0.0015), "longer than a record"),  # an 11-minute time constant from 2-minute records
        (_effect("accel_highpass", corner_hz=0.001), "longer than a record"),
        (_effect("accel_lowpass", corner_hz=327.0), "indistinguishable from the sampling"),  # 0.49 ms: under a sample
        (_effect("accel_lowpass", corner_hz=120.0), "above the excited band"),  # 1.3 ms: a delay, not a corner
        (_effect("base_mode", freq_hz=35.6, zeta=0.5, residue=-1e-3), "not a resonance"),  # a broad bump on the damping's bound
        # the held-out second rig's 1 Hz AC coupling (seed offset 300, N01): a base "mode" at 0.08 +- 5.9 Hz, damping 0.27
        (
            _effect("base_mode", freq_hz=0.08, zeta=0.2745, residue=-6.2e-4, se={"freq_hz": 5.9, "zeta": 21.0, "residue": 1e-4}),
            "not determined by the data: its frequency",
        ),
        (
            _effect(
                "act_mode",
                freq_hz=3.0,
                zeta=0.1,
                zero_freq_hz=1.0,
                zero_zeta=0.1,
                se={"freq_hz": 9.0, "zeta": 0.01, "zero_freq_hz": 0.01, "zero_zeta": 0.01},
            ),
            "not determined by the data: its frequency",
        ),
    ],
)
def test_what_the_data_cannot_identify_is_refused_with_its_reason(effect, reason):
    assert reason in _unidentifiable(effect, _datasets()).text


@pytest.mark.parametrize(
    "effect",
    [
        _effect("pole_zero", zero_hz=23.0, pole_hz=35.0),  # a spool's lag against the simulator's
        _effect("pole_zero", zero_hz=30.0, pole_hz=1e4),  # a lead: its pole beyond the band
        _effect("leak", pole_per_s=0.2),  # the simulator's own (5 s)
        _effect("leak", pole_per_s=-0.5),
        _effect("accel_highpass", corner_hz=0.3),
        _effect("accel_lowpass", corner_hz=30.0),
        _effect("accel_lowpass2", corner_hz=60.0),  # within an octave of the band's top
        _effect("valve", freq_hz=50.0, zeta=0.7),
        _effect("valve", freq_hz=25.0, zeta=3.0),  # a valve on its damping's bound is a first-order spool lag: kept
        _effect("base_mode", freq_hz=15.0, zeta=0.02, residue=6e-3),
        # a mode's frequency known to within a factor e either way is placed (0.9 in ln), and one whose error is not on
        # record is not refused for it
        _effect("base_mode", freq_hz=15.0, zeta=0.02, residue=6e-3, se={"freq_hz": 13.5, "zeta": 0.01, "residue": 1e-3}),
        Effect(KIND["base_mode"], {"freq_hz": 15.0, "zeta": 0.02, "residue": 6e-3}, {}),
    ],
)
def test_what_the_data_identify_is_not_refused(effect):
    assert _unidentifiable(effect, _datasets()) is None


def test_a_mode_on_an_end_of_the_range_searched_is_not_placed():
    """A mode's frequencies are searched over the measured band widened by diagnosis.BAND_MARGIN; one that ends on
    an end of that range is where the data want it further out (against a simulator that cannot represent the
    second rig's plants, base "modes" at exactly 50.0 Hz from 0.1-40 Hz data). Just inside, it is placed."""
    from samii.diagnose.diagnosis import BAND_MARGIN, _within_band

    ds = _datasets()
    base, act = _within_band(KIND["base_mode"], ds), _within_band(KIND["act_mode"], ds)
    top, bottom = 40.0 * BAND_MARGIN, 0.1 / BAND_MARGIN
    r = _unidentifiable(Effect(base, {"freq_hz": top, "zeta": 0.15, "residue": 0.035}, {}), ds)
    assert (r.code, r.cls, r.values["param"], r.values["value"]) == ("mode_on_range_end", "not placed by the data", "freq_hz", top)
    assert r.values["range"][1] == pytest.approx(top) and "not placed by the data: its freq_hz" in r.text
    assert _unidentifiable(Effect(base, {"freq_hz": 0.97 * top, "zeta": 0.15, "residue": 0.035}, {}), ds) is None
    low_zero = {"freq_hz": 0.0866, "zeta": 0.41, "zero_freq_hz": bottom, "zero_zeta": 0.36}
    assert _unidentifiable(Effect(act, low_zero, {}), ds).values["param"] == "zero_freq_hz"


def test_a_pair_below_the_band_is_a_gain_a_fixed_baseline_cannot_hold():
    pair = _effect("pole_zero", zero_hz=0.01, pole_hz=0.012)
    r = _unidentifiable(pair, _datasets(), free=True)
    assert (r.code, r.cls, r.values["zero_hz"], r.values["pole_hz"]) == ("pair_below_band", "below the excited band", 0.01, 0.012)
    assert r.values["pole_hz"] < r.values["band_hz"][0] / r.values["margin"] and "below the excited band" in r.text
    assert _unidentifiable(pair, _datasets(), free=False) is None
    # straddling the band: a tilt of +20 dB/decade the data show, whatever the corners
    assert _unidentifiable(_effect("pole_zero", zero_hz=0.01, pole_hz=500.0), _datasets()) is None


def test_a_change_under_the_floor_is_refused_and_one_over_it_is_not():
    f = np.geomspace(0.1, 40.0, 300)
    floor = np.full(f.size, REL_FLOOR**2)
    ds = [
        SimpleNamespace(
            freq_hz=f, keep={"act": np.ones(f.size, bool)}, floor_var={"act": floor}, corr_length=1.0, inv_sigma={"act": np.full(f.size, 1e3)}
        )
    ]
    before = SimpleNamespace(residuals=({"act": np.zeros(f.size, complex)},))
    small = SimpleNamespace(residuals=({"act": np.full(f.size, 2.0 * REL_FLOOR + 0j)},))  # 1 %: under 3 x 0.5 %
    r = _below_floor(before, small, ds)
    assert (r.code, r.cls, r.values["points"], r.values["channel"]) == ("below_floor", "smaller than the measurement's floor", 0, "act")
    # the change is 2 x REL_FLOOR everywhere, under PRACTICAL_FACTOR x the floor's REL_FLOOR
    assert r.values["largest_change"] == pytest.approx(2.0 * REL_FLOOR)
    assert r.values["largest_ratio"] == pytest.approx(2.0 / PRACTICAL_FACTOR) and "smaller than the measurement's floor" in r.text
    bump = np.zeros(f.size, complex)
    bump[100:104] = 4.0j * REL_FLOOR  # 2 % of phase at four points
    assert _below_floor(before, SimpleNamespace(residuals=({"act": bump},)), ds) is None


def test_the_f_tests_level_is_the_residuals_above_the_stated_noise_and_never_below_it():
    """The F-test counts a chi2 difference in the richer model's chi2 per degree of freedom where that is above 1 (an
    understated noise makes no effect), and in the stated noise where it is below (a floor that overstates one
    channel, theta/v's quantisation at chi2 0.47, does not lower the bar for a "mode" in xdd/v: the second rig's
    clean seed 5004 got one at p = 10^-4.9 that way). _f_limit stays the test's inverse on both sides."""

    def fit(chi2, n_params):
        return SimpleNamespace(chi2=chi2, n_residuals=1003, n_params=n_params, dof=1003 - n_params)

    for chi2_per_dof, level in ((0.5, 1.0), (1.0, 1.0), (2.0, 2.0)):
        after = fit(chi2_per_dof * 1000.0, 3)
        before = fit(after.chi2 + 30.0, 0)
        f, dof, logp = _f_test(before, after, corr=1.5)
        assert dof == (3, 1000)
        assert f == pytest.approx(30.0 / 3 / level / 1.5)
        # the chi2 without the 3 parameters that the test finds just needed at its p
        limit = _f_limit(after, 3, 1.5, logp)
        assert limit == pytest.approx(before.chi2, rel=1e-9)
        # a mode searched over 21 places: its p 21 times larger, and the inverse the same test's
        _, _, logp21 = _f_test(before, after, corr=1.5, places=21.0)
        assert logp21 == pytest.approx(min(logp + np.log10(21.0), 0.0))
        if logp21 < 0.0:
            assert _f_limit(after, 3, 1.5, logp21, 21.0) == pytest.approx(before.chi2, rel=1e-9)


def test_the_samplings_own_delay_is_not_held_to_the_floor_and_a_longer_one_is():
    """A delay of at most one sample is the sampling's own (the hold's half sample): there whatever the data say,
    reported as expected, so a change under the floor does not refuse it (at 500 Hz the hold's 1 ms, refused beside
    an accelerometer delay, left a 30 Hz roll-off read at 39 Hz); a longer delay is a finding and is held to it."""
    f = np.geomspace(0.1, 40.0, 300)
    ds = [
        SimpleNamespace(
            freq_hz=f,
            keep={"act": np.ones(f.size, bool)},
            floor_var={"act": np.full(f.size, REL_FLOOR**2)},
            corr_length=1.0,
            record_s=120.0,
            sample_rate_hz=500.0,
        )
    ]
    before = SimpleNamespace(residuals=({"act": np.zeros(f.size, complex)},))
    small = SimpleNamespace(
        residuals=({"act": np.full(f.size, 2.0 * REL_FLOOR + 0j)},), baseline=SimpleNamespace(free=True), effects=()
    )  # 1 %: under 3 x 0.5 % everywhere
    hold = _effect("command", delay_s=0.001)  # half a sample at 500 Hz
    late = _effect("command", delay_s=0.004, se={"delay_s": 1e-4})  # two samples
    edge = _effect("command", delay_s=0.0021, se={"delay_s": 1e-4})  # one sample within two standard errors
    assert within_sampling(hold, 0.002) and within_sampling(edge, 0.002) and not within_sampling(late, 0.002)
    assert not within_sampling(hold, None)  # a file that does not state its rate gets no allowance
    assert _refused(hold, small, ds, before=before) is None
    assert _refused(edge, small, ds, before=before) is None
    assert _refused(late, small, ds, before=before).cls == "smaller than the measurement's floor"


def test_a_modes_p_counts_the_places_its_frequency_was_searched_over():
    """An extra mode's frequency is the best of the band (Davies 1987: not identified under the null): its p is
    multiplied by the places a mode of its damping has in the band, ln(hi/lo) / (2 zeta), at most the usable points
    over the correlation length; a corner or a delay has no narrow shape to put anywhere: 1."""
    f = np.geomspace(0.1, 40.0, 300)
    ds = [SimpleNamespace(freq_hz=f, keep={"act": f < 20.0, "total": f > 1.0}, corr_length=1.5)]
    broad = _effect("base_mode", freq_hz=33.5, zeta=0.14, residue=-1.5e-4)
    assert search_places(broad, ds) == pytest.approx(np.log(400.0) / 0.28)  # 21
    sharp = _effect("base_mode", freq_hz=33.0, zeta=0.001, residue=-1e-5)
    assert search_places(sharp, ds) == pytest.approx(300 / 1.5)  # the points, not 2996 cells
    act = _effect("act_mode", freq_hz=15.0, zeta=0.2, zero_freq_hz=14.0, zero_zeta=0.02)
    assert search_places(act, ds) == pytest.approx(np.log(400.0) / 0.04)  # the narrower of its pole and zero
    assert search_places(_effect("accel_lowpass", corner_hz=30.0), ds) == 1.0
    assert search_places(_effect("command", delay_s=0.004), ds) == 1.0


def test_mains_lines_are_found_and_subtracted_and_a_sweep_is_left_alone():
    from samii.measure.lines import remove_lines

    fs = 1000.0
    t = np.arange(int(140 * fs)) / fs
    sweep = 0.1 * np.sin(2 * np.pi * (0.1 * t + 0.5 * (40.0 - 0.1) / t[-1] * t**2))
    hum = 0.01 * np.sin(2 * np.pi * 50.02 * t + 0.3) + 0.003 * np.sin(2 * np.pi * 150.06 * t)
    noise = 1e-3 * np.random.default_rng(0).standard_normal(t.size)
    cleaned, lines = remove_lines(sweep + hum + noise, fs)
    assert [round(x.freq_hz, 1) for x in lines] == [50.0, 150.1]
    assert lines[0].amplitude == pytest.approx(0.01, rel=0.02)
    assert np.std(cleaned - sweep - noise) < 0.05 * np.std(hum)
    same, none = remove_lines(sweep + noise, fs)
    assert none == [] and np.array_equal(same, sweep + noise)


def test_records_that_are_not_repeats_are_found_and_repeats_are_not():
    """A 10 % step of the accelerometer's gain after the second of three records: the records differ smoothly over
    frequency (samii.diagnose.stationarity); the same rig without it does not."""
    from dataclasses import replace

    from samii.diagnose.stationarity import record_changes

    rng = np.random.default_rng(4)
    rig = EffectRig.drawn(rng)
    sw = SweptSine(repetitions=3, amplitude_v=0.1, seconds_per_octave=4.0)
    ts = rig.simulate(sw.signal(np.arange(int(round(sw.duration_s * FS))) / FS), sample_rate_hz=FS, rng=rng)
    assert record_changes(from_timeseries(ts, source="repeats.csv")) == []
    step = np.where(ts.t > 2 * sw.record_s, 1.1, 1.0)
    changed = record_changes(from_timeseries(replace(ts, accel=ts.accel * step), source="step.csv"))
    assert changed and {c.channel for c in changed} == {"total"}
    # records of one sign are compared (+, -, +: the first and the third): 1.1 / 1.05 - 1 = 4.8 % against their mean;
    # the largest window of the band holds its noise too
    assert 100 * (1.1 / 1.05 - 1) * 0.8 < max(c.largest_pct for c in changed) < 100 * (1.1 / 1.05 - 1) * 1.5
    assert {c.record for c in changed} <= {0, 2}
    assert "the rig changed during the file" in changed[0].text()
