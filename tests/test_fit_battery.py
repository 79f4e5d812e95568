"""`samii fit` on rigs it was not built on: small draws of experiments/fit_battery (issue 32, item 1).

The full draws (200 plants of the notebook's structure, 40 simulator rigs with spread physical
parameters) are in the scripts and the README; these take other seeds, so the tests see draws the
scripts' tables were not made on. A fit is right when wp, w1, wz and w3 are within 2 % of the truth
or within 3 of its standard errors (its profile interval at that level: experiments/fit_battery/criterion.py);
where it is not, it must name every parameter it missed as not determined by the data (or say it is not
a sound fit), never be wrong without saying so.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from samii.identify import ModelStructure, fit
from samii.identify.fit import resolve_weighting

BATTERY = Path(__file__).resolve().parents[1] / "experiments" / "fit_battery"


def _load(name: str):
    if str(BATTERY) not in sys.path:  # the scripts import their shared criterion as siblings
        sys.path.insert(0, str(BATTERY))
    spec = importlib.util.spec_from_file_location(f"fit_battery_{name}", BATTERY / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_notebook_plants_spread_40_percent_reach_the_true_minimum():
    plants = _load("notebook_plants")
    rows = [plants.run_plant(i, seed=7) for i in range(24)]
    silent = [r["plant"] for r in rows if not r["ok"] and not r["said"]]
    assert not silent, f"plants fitted wrong without a word: {silent}"
    assert sum(r["ok"] for r in rows) >= 23  # the full draw: 199 of 200


@pytest.mark.slow
@pytest.mark.parametrize("case", [0, 1, 2, 3])
def test_simulator_rigs_with_spread_parameters_are_fitted_in_their_physical_minimum(case, tmp_path):
    spread = _load("simulator_spread")
    rec = spread.measure_case(case, seed=11, cache=tmp_path)
    if "error" in rec:  # a rig whose servo loop is unstable is refused, as `samii measure` refuses it
        assert "unstable" in rec["error"]
        pytest.skip(rec["error"])
    row = spread.fit_case(rec)
    assert row["ok"] or row["said"], row
    # mode 1 and the hydraulic resonance are always in the data: they are never the ones missed
    assert all(row["errs"][k][2] for k in ("wp", "w1")), row


def test_a_mode_put_in_an_unmodelled_floor_is_discarded_for_the_physical_minimum():
    """The README's --set example (clamp 2e5 N m/rad, seed 1 of `samii run`): the lowest minimum of the cost put
    the hydraulic pair on base mode 1 and mode 1 at 0.22 Hz, in xdd/theta's floor below 1 Hz (the tilt the
    accelerometer sees, which the s^4 structure lacks). The fit must keep the physical minimum. The rig is
    measured as the main job measures it (about 3 s): the trap lives in that record's floor and noise."""
    from samii.measure.campaign import measure_swept
    from samii.measure.daq import SensorNoise
    from samii.sim.model import load_model
    from samii.sim.plugin import load_plugin

    load_plugin()
    model = load_model(overrides={"beam.clamp_stiffness_Nm_rad": 2e5})
    data = measure_swept(model, noise=SensorNoise(), rng=np.random.default_rng(1)).frf
    res = fit(data, ModelStructure.notebook_3mode(), phase_weight=0.1, weighting=resolve_weighting(data, None, "auto"))
    hz = {k: res.params[k] / (2 * np.pi) for k in ("wp", "w1", "wz")}
    # `samii modes --set beam.clamp_stiffness_Nm_rad=2e5`: base modes 1.94 / 9.91 / 25.56 Hz; the servo pair near 8 Hz
    assert hz["w1"] == pytest.approx(1.94, rel=0.02)
    assert hz["wz"] == pytest.approx(9.91, rel=0.03)
    assert 7.0 < hz["wp"] < 9.5
    assert res.sound and not {"w1", "z1", "wp", "zp", "wz"} & set(res.undetermined)


def test_base_modes_above_the_hydraulic_resonance_are_read_off_xdd_v_where_xdd_theta_is_noise():
    """Above the hydraulic resonance a small sweep moves theta less than its noise: xdd/theta (theta in its
    denominator) is noise there, xdd/v is not. Eq 9.4's responses with xdd/theta and theta/v replaced by noise of
    coherence 0.3 above 1.3 wp: the peaks of xdd/theta are anywhere, those of xdd/v divided by the theta/v model
    are the plant's modes, and the fit finds mode 3. Mode 3 is moved to 20 Hz (0.8 of eq 9.4's): eq 9.4's own
    24.96 Hz is where ``auto_start`` pads a mode it cannot see (2.5 times the highest peak, wz), by chance."""
    from samii import notebook as nb
    from samii.frequency_response import FrequencyResponse
    from samii.identify.cost import FitProblem
    from samii.identify.starts import auto_start, modes_from_total

    st = ModelStructure.notebook_3mode()
    f = np.geomspace(0.1, 40.0, 500)
    true = {k: nb.EQ9_4[k] for k in st.param_names} | {"w3": 2 * np.pi * 20.0}
    act, base, total = (st.response(true, f, c) for c in ("act", "base", "total"))
    rng = np.random.default_rng(3)
    noisy = 2 * np.pi * f > 1.3 * true["wp"]
    coh = np.where(noisy, 0.3, 0.999)

    def swamp(h):  # noise of coherence 0.3 (noise power 2.3x the signal's) where theta is under its noise
        z = (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)) * np.abs(h) * np.sqrt(0.7 / 0.3 / 2)
        return np.where(noisy, h + z, h)

    data = FrequencyResponse(f, act=swamp(act), base=swamp(base), total=total, act_coh=coh, base_coh=coh, total_coh=np.full(f.size, 0.999))
    problem = FitProblem(data, st, phase_weight=0.1, weighting="coherence")
    auto = auto_start(problem)
    assert abs(np.log(auto["w3"] / true["w3"])) > np.log(1.1), auto["w3"] / 2 / np.pi  # what xdd/theta's peaks give
    start = modes_from_total(problem, auto)
    assert start is not None
    for k in ("w1", "wz", "w3"):
        assert abs(np.log(start[k] / true[k])) < np.log(1.1), (k, start[k] / 2 / np.pi, true[k] / 2 / np.pi)
    res = fit(data, st, phase_weight=0.1, weighting="coherence")
    assert abs(res.params["w3"] / true["w3"] - 1) < 0.02, res.params["w3"] / 2 / np.pi
    # without xdd/v no such start exists
    assert modes_from_total(FitProblem(FrequencyResponse(f, act=act, base=base), st, phase_weight=0.1), true) is None


@pytest.mark.slow
def test_a_mode_3_that_xdd_theta_hides_in_its_noise_is_found_from_xdd_v(tmp_path):
    """Simulator rig 23 of the battery's seed 0 (the only silent miss of that draw before the xdd/v start): the
    0.1 V sweep leaves xdd/theta noise above 10 Hz, every start read off it put mode 3 at 10 Hz beside the
    actuator pair (wz 5.4 % off, said of w3 only); its true minimum is lower and the xdd/v start reaches it."""
    spread = _load("simulator_spread")
    row = spread.fit_case(spread.measure_case(23, seed=0, cache=tmp_path))
    assert row["ok"], row
    assert any(label.startswith("auto, modes from xdd/v") for label, *_ in row["starts"])


def test_a_point_whose_records_agreed_by_chance_does_not_decide_the_actuator_zero(tmp_path):
    """Simulator rig 23 of the battery's seed 2: at theta/v's notch the 3-record coherence estimate reads 0.18,
    0.89, 0.99, 0.80 on neighbouring points, and weighted point by point the 0.99 one (weight 10 against 2)
    put wz at 10.44 Hz against the truth's 9.91 (5.4 %, 3.3 standard errors; over 10 other noise seeds the fit
    scatters 0.11 Hz around 9.87). With the coherence pooled over neighbours (``cost.pooled_coherence``) the fit
    is in the truth's minimum."""
    spread = _load("simulator_spread")
    row = spread.fit_case(spread.measure_case(23, seed=2, cache=tmp_path))
    assert row["ok"], row
    assert abs(row["errs"]["wz"][0]) < 0.03, row["errs"]["wz"]


@pytest.mark.slow
def test_a_start_s_search_never_narrows_a_mode_below_the_grid_s_resolution(tmp_path):
    """Simulator rig 39 of the battery's seed 1: the start read off xdd/v put mode 3 at 34 Hz and its grid search
    drove z3 from 0.04 to 0.0025, a half-power band of 0.17 Hz between points 0.78 Hz apart: the cost along w3 then
    has a local minimum between each pair of points, and the solver stayed in one (cost 903.6; with every other
    start mode 3 slid to 13 Hz beside the actuator zero, 901.1) while the minimum with mode 3 at 30 Hz is 892.6. A
    start's search holds a damping at half the grid's local spacing (``starts.resolvable_damping``), and the fit
    reaches that minimum."""
    from samii.formats import read_frf_csv
    from samii.frequency_response import FrequencyResponse
    from samii.identify.cost import FitProblem
    from samii.identify.starts import auto_start, modes_from_total, resolvable_damping

    spread = _load("simulator_spread")
    rec = spread.measure_case(39, seed=1, cache=tmp_path)
    row = spread.fit_case(rec)
    assert row["ok"], row
    assert row["cost"] < 895.0, row["cost"]
    problem = FitProblem(read_frf_csv(rec["frf"]), ModelStructure.notebook_3mode(), phase_weight=0.1, weighting="coherence")
    # samii measure's 100-per-decade grid: ln(10) / 100 / 2 = 0.0115 wherever a mode is
    for f_hz in (2.0, 9.0, 30.0):
        assert 0.01 < resolvable_damping(problem, 2 * np.pi * f_hz) < 0.013
    start = modes_from_total(problem, auto_start(problem))
    for k, v in start.items():
        if k.startswith("z"):
            assert v >= 0.99 * resolvable_damping(problem, start["w" + k[1:]]), (k, v)
    # a linear (FFT) grid is coarse in ln f at low frequency: its floor is the local spacing's
    f = np.arange(0.05, 100.0, 0.05)
    lin = FitProblem(FrequencyResponse(f, act=np.ones(f.size), base=np.ones(f.size)), ModelStructure.notebook_3mode())
    assert resolvable_damping(lin, 2 * np.pi * 2.0) == pytest.approx(0.5 * 0.05 / 2.0, rel=0.02)
    assert resolvable_damping(lin, 2 * np.pi * 50.0) == pytest.approx(0.5 * 0.05 / 50.0, rel=0.02)


@pytest.mark.slow
@pytest.mark.parametrize("seed, case, name", [(4, 8, "wz"), (2, 6, "w3")])
def test_a_lopsided_cost_is_read_off_its_profile_not_its_curvature(seed, case, name, tmp_path):
    """Two rigs of the battery whose data's own minimum lies more than 3 local standard errors from the
    truth's: seed 4 rig 8's actuator zero (11.63 Hz against 11.97, 2.9 %; its profile rises to t = 2.5
    above the estimate, then lies in a shallow second dip, t 2.1-2.9 over 11.95-12.55 Hz, where the truth
    is) and seed 2 rig 6's mode 3 (26.46 against 27.65 Hz, in the noise of the 0.1 V sweep). ``value +- 3
    SE`` misses the truth; the profile interval at the same level (``samii.identify.profile``) is lopsided
    the way the cost is and holds it."""
    from samii.identify.fit import PROFILE_3SIGMA

    spread = _load("simulator_spread")
    rec = spread.measure_case(case, seed=seed, cache=tmp_path)
    row = spread.fit_case(rec)
    assert row["ok"], row
    assert not row["ok_local"] and row["errs"][name][1] > 3.0, row["errs"][name]  # the local reading misses
    from samii.formats import read_frf_csv

    data = read_frf_csv(rec["frf"])
    res = fit(data, ModelStructure.notebook_3mode(), phase_weight=0.1, weighting=resolve_weighting(data, None, "auto"))
    v, t = res.params[name], rec["truth"]["params"][name]
    lo, hi = res.interval(name, PROFILE_3SIGMA)
    assert lo < t < hi, (lo, t, hi)
    assert (hi - v) > 1.3 * (v - lo)  # lopsided toward the truth, which lies above the estimate
