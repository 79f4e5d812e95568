"""Issue 8: the simulator's swept-sine data, fitted by the notebook's own procedure, give the
notebook's eq 9.4 back (the rig was measured and fitted that way; eq 9.4 is what came out).

Targets and tolerances: ``samii.calibrate.targets`` (frequencies +-3 %, wp +-5 %, tau +-15 %,
K1 +-10 %, damping ratios +-30 %, B signs exact, B1/B2 and B3/B2 +-30 %).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from samii.calibrate.targets import check_fit_against_eq9_4
from samii.identify.fit import fit
from samii.identify.structures import ModelStructure
from samii.measure.campaign import linearised_frf, measure_swept
from samii.measure.excitation import SweptSine
from samii.sim.model import load_model


@pytest.fixture(scope="module")
def model():
    return load_model()


@pytest.fixture(scope="module")
def measured(model):
    """``samii measure`` with its defaults: swept sine 0.1-40 Hz, 0.1 V, 3 sign-alternating records."""
    return measure_swept(model, SweptSine())


def _failures(params):
    checks = check_fit_against_eq9_4(params)
    return [c.row() for c in checks if not c.ok], checks


@pytest.mark.slow
def test_default_measurement_fitted_as_the_notebook_gives_eq9_4(measured):
    """`samii measure && samii fit frf.csv --modes 3 --numerator s4 --phase-weight 0.1`."""
    res = fit(measured.frf, ModelStructure(n_modes=3, numerator="s4"), phase_weight=0.1)
    assert res.converged
    failed, checks = _failures(res.params)
    assert not failed, "\n".join(failed)
    assert len(checks) == 15


def test_linearised_simulator_fitted_as_the_notebook_gives_eq9_4(model, measured):
    """The same on the linearised simulator's FRF at the measurement's frequencies: what the
    measurement converges to; at 0.1 V the two fits agree to a few per cent."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lin = linearised_frf(model, measured.frf.freq_hz)
    res = fit(lin, ModelStructure(n_modes=3, numerator="s4"), phase_weight=0.1)
    failed, _ = _failures(res.params)
    assert not failed, "\n".join(failed)
    meas = fit(measured.frf, ModelStructure(n_modes=3, numerator="s4"), phase_weight=0.1)
    for name in ("w1", "wz", "w3", "wp", "K1"):
        assert meas.params[name] == pytest.approx(res.params[name], rel=0.03), name


def test_target_table_catches_a_miss():
    """The check itself: eq 9.4 passes; B2's sign flipped or wp off by 6 % fail."""
    from samii import notebook as nb

    p = dict(nb.EQ9_4)
    p["K1"] = p["K1"] * np.pi / 180  # the check takes SI (theta in rad)
    assert all(c.ok for c in check_fit_against_eq9_4(p))
    bad = dict(p, B2=-p["B2"])
    assert {c.name for c in check_fit_against_eq9_4(bad) if not c.ok} >= {"sign B2"}
    off = dict(p, wp=1.06 * p["wp"])
    assert [c.name for c in check_fit_against_eq9_4(off) if not c.ok] == ["wp"]
