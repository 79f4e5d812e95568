"""A fit's concerns and caveats as data (issue 33, item 4): codes with the figures they rest on, worded from them.

The truth is the notebook's eq 9.4 model (w1 1.73 Hz, w3 25.0 Hz: samii.notebook.EQ9_4), synthesised with the swept
sine's noise as tests/test_identify_profile.py does; a band that leaves a mode out must say so with the mode's place,
the band and what to try, in the command line's spelling and in Python's.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from samii import notebook as nb
from samii.identify import ModelStructure, SweptSineNoise, fit, synthesize
from samii.identify.concerns import _ADVICE, _FINDINGS, CODES, COMMAND_LINE, PYTHON, REMEDIES, Finding
from samii.json_output import dumps

ST3 = ModelStructure.notebook_3mode()
F_HZ = np.geomspace(0.1, 40.0, 400)


@pytest.fixture(scope="module")
def eq94():
    rng = np.random.default_rng(5)
    return synthesize(F_HZ, {c: ST3.response(nb.EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=rng)


def test_a_band_above_mode_1_says_where_mode_1_is_and_what_to_try(eq94):
    r = fit(eq94, ST3, band_hz=(2.0, 40.0), profile=False)
    out = [c for c in r.caveats if c.code == "outside_band"]
    assert [c.names for c in out] == [("w1", "z1")] and "w1" in r.undetermined
    v = out[0].values
    # mode 1 is eq 9.4's 1.73 Hz (within 2 %: 0.16-0.53 % on seeds 1, 2, 3, 5), below the band's first point (the
    # grid's first above 2 Hz)
    assert v["freq_hz"] == pytest.approx(nb.EQ9_4["w1"] / (2 * np.pi), rel=0.02)
    assert v["freq_hz"] < v["band_hz"][0] and v["band_hz"][0] >= 2.0 and v["band_hz"][1] == 40.0
    assert out[0].remedies == ("widen_band", "fewer_modes") and out[0].kind == "unmeasured"
    cli, py = out[0].text, out[0].words(PYTHON)
    assert cli.startswith(f"mode w1 = {v['freq_hz']:.3g} Hz lies outside the fitted band") and "widen --band-hz" in cli
    assert "--" not in py and "widen band_hz to include it" in py


def test_concerns_serialise_with_their_figures_and_words(eq94):
    r = fit(eq94, ST3, band_hz=(0.1, 15.0), profile=False)
    d = json.loads(dumps(r.to_dict()))
    said = d["findings"]["concerns"] + d["findings"]["caveats"]
    assert said and [f["text"] for f in said] == d["concerns"] + d["caveats"]
    w3 = next(f for f in said if f["code"] == "outside_band")
    # eq 9.4's mode 3 (25.0 Hz) lies above a band ending at 15 Hz: the fit puts w3 somewhere beyond it
    assert w3["names"] == ["w3", "z3"] and w3["values"]["freq_hz"] > w3["values"]["band_hz"][1]
    assert w3["values"]["band_hz"][1] <= 15.0


def test_one_mode_is_never_told_to_fit_fewer_modes(eq94):
    """Fitted above 12 Hz, where eq 9.4 has only mode 3 (25.0 Hz) and the actuator's pair (8.8 and 9.9 Hz) below the
    band, modes are put outside it (where only a tail is seen): three modes are told to try fewer, one mode never is (there are none
    fewer)."""
    said = {}
    for n in (3, 1):
        r = fit(eq94, ModelStructure(n_modes=n), band_hz=(12.0, 40.0), profile=False)
        said[n] = r.concerns + r.caveats
        out = [c for c in said[n] if c.code == "outside_band"]
        assert out and all(not c.values["band_hz"][0] <= c.values["freq_hz"] <= c.values["band_hz"][1] for c in out), said[n]
    assert any("fewer_modes" in c.remedies for c in said[3]) and any("fewer --modes" in c.text for c in said[3])
    assert not any("fewer_modes" in c.remedies or "try_fewer_modes" in c.remedies for c in said[1])
    assert not any("fewer --modes" in c.text for c in said[1])


def test_every_code_and_remedy_is_worded_and_unknown_ones_are_refused():
    assert set(_FINDINGS) == set(CODES) == set(_ADVICE)
    for r in REMEDIES.values():  # each names options only by the keys both spellings give
        r.format(**COMMAND_LINE), r.format(**PYTHON)
    with pytest.raises(ValueError, match="unknown code 'mode_lost'"):
        Finding("mode_lost", "misplaced")
    with pytest.raises(ValueError, match="unknown kind 'fatal'"):
        Finding("noise_only", "fatal")
    with pytest.raises(ValueError, match="unknown remedies"):
        Finding("noise_only", "noise", {"min_coherence": 0.5, "highest": 0.2}, (), ("pray",))
    f = Finding("noise_only", "noise", {"min_coherence": 0.5, "highest": 0.21}, (), ("more_excitation",))
    assert f.text == (
        "no point has coherence >= 0.5 in the fitted channels (the highest is 0.21): the data are noise, and no parameter "
        "is determined by them; measure with more excitation"
    )
