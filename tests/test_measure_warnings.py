"""The Bode test's warnings as data (samii.measure.bode_test.MeasureWarning): a code, the run, the numbers behind it;
the sentence the command prints is rendered from them."""

from __future__ import annotations

import pytest

from samii.measure.bode_test import LINEARITY_WARN_DB, MeasureWarning, _warnings


def _check(sustained_db: float, max_db: float, deg: float = 10.0) -> dict:
    """A channel's deviation from the linearised simulator: over a band (a swept sine's test) and at its worst point (a
    stepped sine's); different, so that each run is seen to be judged by its own."""
    return {"max_abs_db": max_db, "max_abs_deg": 2 * deg, "sustained_db": sustained_db, "sustained_deg": deg, "points": 100}


def test_each_warning_carries_its_numbers_and_words_them():
    peaks = {"swept": {"load_pressure_pa": 8.4e6, "valve_command_v": 3.0, "joint_angle_rad": 0.1}}
    checks = {"swept": {"act": _check(0.4, LINEARITY_WARN_DB + 5), "total": _check(LINEARITY_WARN_DB + 1.2, LINEARITY_WARN_DB + 2, 14.0)}}
    said = _warnings(checks, peaks, coh_ok=False, supply_pa=7e6, amp=3.0)
    assert [(w.code, w.run) for w in said] == [("pressure_above_supply", "swept"), ("not_small_signal", "swept"), ("no_coherence", "swept")]
    pressure, linear, _ = said
    assert pressure.values == {"peak_pa": 8.4e6, "supply_pa": 7e6}
    assert "reached 8.40 MPa, 20 % above the 7 MPa supply" in pressure.text
    assert linear.values["channel"] == "total" and linear.values["deviation_db"] == pytest.approx(LINEARITY_WARN_DB + 1.2)
    assert linear.values["amplitude_v"] == 3.0 and linear.values["limit_db"] == LINEARITY_WARN_DB
    assert linear.text.startswith(f"swept run: total lies {LINEARITY_WARN_DB + 1.2:.1f} dB from the linearised simulator over a band")


def test_below_the_limits_nothing_is_said():
    peaks = {"stepped": {"load_pressure_pa": 6.9e6, "valve_command_v": 0.1, "joint_angle_rad": 0.01}}
    checks = {"stepped": {"act": _check(LINEARITY_WARN_DB + 5, LINEARITY_WARN_DB - 0.1), "total": _check(0.5, 0.5)}}
    assert _warnings(checks, peaks, coh_ok=False, supply_pa=7e6, amp=0.1) == []  # (coherence: a swept sine's)


def test_an_unknown_code_is_a_defect_not_a_blank_line():
    with pytest.raises(ValueError, match="unknown measurement warning 'x'"):
        _ = MeasureWarning("x", "swept").text
