"""A found effect's evidence as data (issue 33, item 4): the sentence is rendered from the fields, never parsed.

The figures below are chosen to exercise each wording; the diagnoses' own figures are asserted on the fields in
tests/test_diagnose_core.py and tests/test_diagnose_cli.py.
"""

from __future__ import annotations

import json

import pytest

from samii.diagnose.diagnosis import FoundEffect
from samii.diagnose.evidence import Joined, Rival, evidence_text, joined_text, rival_text, sampling_text
from samii.json_output import dumps


def test_an_f_test_is_worded_from_its_figures():
    j = Joined("f_test", 812.4, 700.2, (1, 480), 76.8, -16.23)
    assert joined_text(j) == "adding it lowers chi2 from 812.4 to 700.2 for 1 parameter(s): F = 76.8 on (1, 480) dof, p = 10^-16.2"
    broad = Joined("f_test", 812.4, 700.2, (3, 478), 25.6, -12.0, places=7.0)
    assert joined_text(broad).endswith("p = 10^-12.0 (the best of the 7 places a mode this broad has in the band)")
    assert joined_text(Joined("f_test", 1e5, 1e3, (1, 480), 1e6, -400.0)).endswith("p < 1e-300")


def test_a_swap_and_a_refit_are_worded_from_their_figures():
    same = Joined("swap", 744.0, 741.5, replaced="sensor/accel_delay", extra_params=0)
    assert joined_text(same) == "it replaced sensor/accel_delay, which had joined by F-test, with no more parameters: chi2 744 -> 741.5"
    more = Joined("swap", 749.0, 730.0, f_stat=12.3, log10_p=-3.2, replaced="delay/command", extra_params=1)
    assert joined_text(more).endswith("with 1 more parameter(s): chi2 749 -> 730, F = 12.3, p = 10^-3.2")
    assert joined_text(Joined("refit")) == "kept by the joint refit"


def test_rivals_are_worded_from_their_figures():
    near = Rival("in_its_place", "sensor/accel_lowpass", 0.41, values={"corner_hz": 29.6}, moved=(("delay/command", {"delay_s": 0.0041}),))
    assert rival_text("sensor/accel_lowpass2", near) == (
        "; but sensor/accel_lowpass in its place fits almost as well (chi2 differs by 0.41 noise variances; its corner_hz "
        "29.6 Hz; with it delay/command delay_s 4.1 ms): these data hardly tell the two apart"
    )
    richer = Rival("richer", "actuator/valve", -1.5, 1, {"freq_hz": 80.0, "zeta": 0.5}, without_hold=True)
    said = rival_text("delay/command", richer)
    assert "its chi2 is higher by 1.5 noise variances" in said and "in the model without the command's hold" in said
    moves = Rival("moves_it", "sensor/accel_lowpass", values={"delay_s": 0.0039}, in_place_of="sensor/accel_lowpass2")
    assert rival_text("delay/command", moves) == (
        "; with sensor/accel_lowpass in place of sensor/accel_lowpass2 (which fits almost as well) it is delay_s 3.9 ms"
    )
    with pytest.raises(ValueError, match="Rival.how must be one of"):
        Rival("better", "x/y")
    with pytest.raises(ValueError, match="Joined.how must be one of"):
        Joined("vote")


def test_a_found_effect_carries_its_figures_into_json():
    j = Joined("f_test", 812.4, 700.2, (1, 480), 76.8, -16.23)
    r = Rival("in_its_place", "sensor/accel_delay", 0.8, values={"delay_s": 0.004})
    text = evidence_text("delay/command", "command delay 0.5 ms", j, [r], 1e-3)
    assert text.startswith("command delay 0.5 ms; adding it lowers chi2") and text.endswith(sampling_text(1e-3))
    e = FoundEffect("delay", "command", "act", {"delay_s": 5e-4}, {"delay_s": 1e-5}, text, True, j, (r,), 1e-3)
    d = json.loads(dumps(e.to_dict()))
    assert d["joined"] == {
        "how": "f_test",
        "chi2_before": 812.4,
        "chi2_after": 700.2,
        "dof": [1, 480],
        "f_stat": 76.8,
        "log10_p": -16.23,
        "places": 1.0,
        "replaced": None,
        "extra_params": None,
    }
    assert d["rivals"][0]["effect"] == "sensor/accel_delay" and d["rivals"][0]["values"] == {"delay_s": 0.004}
    assert d["sample_s"] == 1e-3 and d["evidence"] == text and d["beside_nonlinearity"] is False


def test_a_refusal_is_a_code_with_its_figures_and_its_class_is_not_read_off_its_words():
    from samii.diagnose.evidence import REFUSALS, Refusal
    from samii.diagnose.select import REFUSAL_CLASSES

    # the thirteen classes the report and the batteries count (diagnosis.json's refused[].class), each with a code
    assert set(REFUSAL_CLASSES) == {
        "below the excited band",
        "above the excited band",
        "not determined by the data",
        "not a resonance",
        "not placed by the data",
        "cancels within its uncertainty",
        "smaller than the measurement's floor",
        "indistinguishable from the sampling",
        "longer than a record",
        "a mode split in two",
        "a mode the data cannot resolve",
        "not told from an image",
        "cannot be placed",
    }
    r = Refusal("corner_within_sampling", {"corner_hz": 180.0, "lag_s": 8.8e-4, "sample_s": 1e-3, "band_hz": (0.1, 40.0), "margin": 2.0})
    assert r.cls == "indistinguishable from the sampling" and str(r) == r.text
    assert r.text == (
        "indistinguishable from the sampling: its corner (180 Hz) lies beyond a factor 2 of the excited band 0.1-40 Hz, "
        "where it is a group delay of 0.88 ms, at most one sample (1 ms)"
    )
    band = {"band_hz": (0.1, 40.0), "margin": 2.0}
    figures = {  # one refusal of each code (the figures chosen to fill each wording)
        "pair_below_band": {"zero_hz": 0.01, "pole_hz": 0.012, **band},
        "pair_above_band": {"zero_hz": 300.0, "pole_hz": 500.0, **band},
        "corners_undetermined": {"zero_hz": 3.0, "pole_hz": 5.0, "ln_se": 1.4},
        "damping_on_bound": {"zeta": 0.999, "bound": 1.0},
        "mode_on_range_end": {"param": "freq_hz", "value": 50.0, "range": (0.08, 50.0)},
        "frequency_undetermined": {"freq_hz": 0.08, "ln_se": 4.2},
        "cancels": {"freq_hz": 3.0, "zero_freq_hz": 3.01, "separation_se": 1.2},
        "longer_than_record": {"time_constant_s": 80.0, "record_s": 60.0},
        "corner_within_sampling": {"corner_hz": 180.0, "lag_s": 8.8e-4, "sample_s": 1e-3, **band},
        "corner_above_band": {"corner_hz": 180.0, "lag_s": 8.8e-4, **band},
        "on_range_end": {"param": "gain", "value": 100.0, "unit": "1", "range": (0.01, 100.0), "kind": "accel_gain"},
        "below_floor": {"factor": 3.0, "points": 1, "needed": 3, "largest_change": 0.02, "freq_hz": 12.0, "channel": "act", "largest_ratio": 1.3},
        "image": {
            **{"n_bands": 2, "channel": "base", "channel_name": "xdd/theta", "band_hz": (20.0, 35.0), "rms_db": 3.1, "rms_deg": 12.0},
            **{"takes_out_pct": 20.0, "needed_pct": 75.0},
        },
    }
    for code, (cls, _) in REFUSALS.items():  # each one's words hold its class's phrase, as the report reads them
        assert cls in Refusal(code, figures.get(code, {})).text, code
    with pytest.raises(ValueError, match="Refusal.code must be one of"):
        Refusal("too small")


# -- a nonlinearity's evidence (samii.diagnose.nonlinear.HarmonicEvidence, NonlinearEvidence) ------------------------


def _seen(harmonic: int, **kw):
    from samii.diagnose.nonlinear import HarmonicEvidence

    return HarmonicEvidence(source="rig.csv", harmonic=harmonic, n_records=3, n_significant=12, n_tested=18, band_hz=(1.46, 12.6),
                            peak_ratio=0.045, peak_hz=1.46, peak_command_v=0.0377, log10_p=-13.2, **kw)  # fmt: skip


_BASE3 = (
    "rig.csv: the 3rd harmonic of the sweep, referred to the valve command, repeats in all 3 records beyond their spread (p = "
    "10^-13 in the strongest segment) in 12 of 18 segments, 1.46-12.6 Hz, up to 4.5 % of the fundamental (-27 dB) at 1.46 Hz "
    "where the valve command is 37.7 mV; a linear system makes none"
)


def test_an_odd_law_is_worded_from_its_figures():
    chi2 = {"dead_band": 2.17, "saturation": 62.3, "hysteresis": 62.2}
    every = {"dead_band": 1.92, "saturation": 44.5, "hysteresis": 44.5}
    law = dict(phase_deg=-4.2, law="dead_band", level_v=0.00504, level_se_v=0.00019, law_chi2=chi2, phase_spread_deg=12.0)
    fits = _seen(3, **law, every_segments=18, every_chi2=every, trend=-0.84, law_fits=True)
    assert fits.text() == (
        _BASE3 + "; the 3rd harmonic (-4 deg from cos 3phi) says the centre of the wave is missing: a dead band (spool overlap; "
        "Coulomb friction that holds the joint at small commands looks alike): its describing function fits a level of 5.04 +- "
        "0.19 mV with chi2 2.17 per degree of freedom (the other laws: saturation 62.3, hysteresis 62.2; over all 18 tested "
        "segments, where it is absent too: dead_band 1.92, saturation 44.5, hysteresis 44.5); the distortion falls with the "
        "command's amplitude (correlation -0.84)"
    )
    # no law on the command alone: the kind and level indicative only
    loose = _seen(3, **law, law_fits=False, reference="the model's own")
    assert "that is in excess of the model's own, measured like the file;" in loose.text()
    assert loose.text().endswith("but no law on the command alone tells it apart (phase spread 12 deg over the segments): the nonlinearity "
                                 "depends on the loop's state too (the load pressure through the valve's orifice law, say), and the kind and "
                                 "level are indicative only")  # fmt: skip
    # a chi2 above MAX_DF_CHI2 (10) that is not far below the others' where the harmonic is (40 > 0.5 x 62.2, the
    # runner-up's): identified over every segment; 14.5 lies between the two cut-offs: far better where the harmonic is
    wide = _seen(3, **{**law, "law_chi2": {**chi2, "dead_band": 40.0}}, law_fits=True)
    assert wide.text().endswith("it fits far better than the others over every tested segment, where the harmonic is and where it is absent, "
                                "and its chi2 above 1 is the describing function's own approximation (a pure sine at the valve, where "
                                "the loop feeds the harmonics back)")  # fmt: skip
    narrow = _seen(3, **{**law, "law_chi2": {**chi2, "dead_band": 14.5}}, law_fits=True)
    assert "it fits far better than the others where the harmonic is, and" in narrow.text()


def test_a_gain_asymmetry_is_worded_from_its_figures():
    from dataclasses import replace

    from samii.diagnose.nonlinear import AlsoIn

    even = (
        _BASE3.replace("3rd", "2nd")
        + "; even harmonics dominate: the valve's two directions differ (its orifice law under load, unequal piston areas)"
    )
    few = _seen(2)
    assert few.text() == even  # fewer than 2 segments tested: no ratio
    assert _seen(2, mean_ratio=0.5, ratio_segments=27).text() == even + "; their mean ratio +50 % is beyond any gain asymmetry's"
    gain = _seen(2, mean_ratio=0.022, ratio_segments=27, asymmetry=0.097, asymmetry_se=0.002, ratio_chi2=1.16)
    assert gain.text() == even + (
        "; their mean ratio +2.2 % over 27 segments is a gain 9.7 +- 0.2 % lower in the negative direction (c2/c1 = 2 d / (3 pi "
        "(1 - d/2)), real and the same at every amplitude; that constant fits with chi2 1.16 per degree of freedom)"
    )
    orifice = replace(gain, asymmetry=-0.097, ratio_chi2=25.0)
    assert "lower in the positive direction" in orifice.text()
    assert orifice.text().endswith("chi2 25 per degree of freedom: far from constant, so the two directions differ by more than a gain (the "
                                   "orifice law's share grows with the command))")  # fmt: skip
    also = replace(gain, also=(AlsoIn("b.csv", 4), AlsoIn("c.csv", 2, 0.00496)))
    assert also.text().endswith("; also in b.csv (4 segments); also in c.csv (2 segments, level 4.96 mV)")


def test_an_amplitude_dependence_is_worded_from_its_test_and_joined_to_the_harmonics():
    from samii.diagnose.nonlinear import AmplitudeTest, NonlinearEvidence, NonlinearFinding, amplitude_kind

    grows = AmplitudeTest(("a.csv", "b.csv"), (0.05, 0.3), 4004.2, 38.0, -400.0, 6.66, 179)
    said = (
        "theta/v at 0.3 V differs from that at 0.05 V by chi2 4004 on 38 dof (p < 1e-300; 179 points), +6.66 dB on average "
        "(inverse-variance weighted) at the larger amplitude: the response grows with amplitude, as a dead band's or friction's "
        "(small commands lose more)"
    )
    assert amplitude_kind(grows) == "dead_band" and NonlinearFinding("dead_band", {}, {}, NonlinearEvidence(across_files=grows)).evidence == said
    seen = _seen(3, phase_deg=-4.2, law="saturation", level_v=0.08, level_se_v=0.001, law_chi2={"dead_band": 9.0, "saturation": 2.0, "hysteresis": 9.0},
                 phase_spread_deg=5.0, law_fits=True)  # fmt: skip
    both = NonlinearFinding("saturation", {}, {}, NonlinearEvidence(seen, grows))
    assert both.evidence == seen.text() + "; across files: " + said + " (the harmonics say saturation)"  # they disagree: said
    shrinks = AmplitudeTest(("a.csv", "b.csv"), (0.1, 0.3), 1210.0, 40.0, -227.0, -0.05, 183, channel="total")
    agreed = NonlinearFinding("saturation", {}, {}, NonlinearEvidence(seen, shrinks)).evidence
    assert agreed.endswith("; across files: xdd/v at 0.3 V differs from that at 0.1 V by chi2 1210 on 40 dof (p = 10^-227; 183 points), "
                           "-0.05 dB on average (inverse-variance weighted) at the larger amplitude: the response shrinks with amplitude, "
                           "as a saturation's")  # fmt: skip
    # the figures, not the words, in diagnosis.json
    doc = json.loads(dumps(FoundEffect("nonlinear", "saturation", "act", {}, {}, agreed, nonlinear=NonlinearEvidence(seen, shrinks)).to_dict()))
    assert doc["nonlinear"]["harmonics"]["level_v"] == 0.08 and doc["nonlinear"]["across_files"]["gain_change_db"] == -0.05
