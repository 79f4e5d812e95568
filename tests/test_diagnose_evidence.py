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
