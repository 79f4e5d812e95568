"""Profile intervals (samii.identify.profile; issue 32, item 1): what they read off a cost, and their coverage."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2, norm

from samii import notebook as nb
from samii.identify import ModelStructure, SweptSineNoise, fit, synthesize
from samii.identify.fit import PROFILE_3SIGMA, PROFILE_BELOW_CONCERN
from samii.identify.profile import RANGE_FACTOR, TAU_STOP, profile_scan

ST3 = ModelStructure.notebook_3mode()
F_HZ = np.geomspace(0.1, 40.0, 400)  # issue 5's grid, as tests/test_identify_fit.py


def _scan(cost_of_v, v_hat=10.0, se=0.1, sigma2=2.0, limits=(0.0, np.inf)):
    """Profile a one-parameter 'fit' whose held value alone decides the cost (nothing to re-solve)."""
    x = np.array([v_hat])
    c_hat = cost_of_v(v_hat)
    return profile_scan("w", x, 0, c_hat, sigma2, se, lambda x0: (x0, cost_of_v(x0[0])), lambda xc: limits)


def test_a_quadratic_cost_gives_the_normal_interval():
    # S(v) = S_hat + sigma2 (v - v_hat)^2 / SE^2: tau is exactly (v - v_hat) / SE
    se, s2 = 0.1, 2.0
    p = _scan(lambda v: 50.0 + s2 * ((v - 10.0) / se) ** 2, se=se, sigma2=s2)
    for level in (0.95, PROFILE_3SIGMA):
        z = norm.ppf(0.5 + level / 2)
        lo, hi = p.interval(level)
        assert lo == pytest.approx(10.0 - z * se, abs=2e-3) and hi == pytest.approx(10.0 + z * se, abs=2e-3)
        assert p.bounded(level) == (True, True)
    assert p.lowest == 0.0
    # the quadratic check: |tau| is 3 and 6 at 3 and 6 standard errors either side, so those four solves are the profile
    assert p.values.size == 5 and np.allclose(p.tau, [-6.0, -3.0, 0.0, 3.0, 6.0])
    # a cost 30 % steeper above than its curvature says is scanned: past TAU_STOP on both sides, then stopped
    q = _scan(lambda v: 50.0 + s2 * ((v - 10.0) / se) ** 2 * (1.0 if v < 10.0 else 1.69), se=se, sigma2=s2)
    assert 5 < q.values.size < 60 and q.tau[0] < -TAU_STOP and q.tau[-1] > TAU_STOP
    assert q.interval(0.95)[1] == pytest.approx(10.0 + 1.96 * se / 1.3, abs=2e-3)


def test_a_flat_side_is_open_and_a_lopsided_cost_gives_a_lopsided_interval():
    # steep below the estimate, flat above (a mode in the noise): bounded below, open above at the scan's end
    p = _scan(lambda v: 50.0 + 2.0 * (min(v - 10.0, 0.0) / 0.1) ** 2 + 0.1 * max(v - 10.0, 0.0), se=0.1)
    lo, hi = p.interval(0.95)
    assert lo == pytest.approx(10.0 - 1.96 * 0.1, abs=3e-3)
    assert hi == pytest.approx(10.0 * RANGE_FACTOR, rel=0.05)
    assert p.bounded(0.95) == (True, False)
    # a neighbouring mode ends the scan before its range: still open there, never across it
    q = _scan(lambda v: 50.0 + 0.1 * abs(v - 10.0), limits=(9.0, 12.0))
    assert q.values.min() > 9.0 and q.values.max() < 12.0 and q.bounded(0.95) == (False, False)


def test_a_second_dip_within_the_level_widens_the_interval_and_a_lower_one_is_reported():
    # two wells 7 standard errors apart: the estimate's and one at 10.7 whose floor is 2.5^2 squared
    # standard errors up, behind a hump of 3.9 (below TAU_STOP: the scan goes on across it)
    def two_wells(floor):
        return lambda v: 50.0 + 2.0 * min(((v - 10.0) / 0.1) ** 2, ((v - 10.7) / 0.1) ** 2 + floor)

    p = _scan(two_wells(2.5**2))
    lo, hi = p.interval(PROFILE_3SIGMA)
    # the 3-sigma interval reaches across the second well (its end read between two steps: within 0.5 %)
    assert hi == pytest.approx(10.7 + np.sqrt(9 - 6.25) * 0.1, rel=0.005)
    assert lo == pytest.approx(9.7, abs=0.01) and p.bounded(PROFILE_3SIGMA) == (True, True)
    assert p.interval(0.95)[1] < 10.3  # at 95 % the second well is out: the interval is the estimate's own
    lower = _scan(two_wells(-4.0))  # the second well is lower: the fit's minimum is not the lowest
    # (the lowest of the values scanned: at most the well's floor of -4)
    assert -4.0 <= lower.lowest < -3.0 and lower.lowest_at == pytest.approx(10.7, abs=0.08)


def test_profiles_agree_with_the_standard_errors_where_the_cost_is_quadratic():
    data = synthesize(F_HZ, {c: ST3.response(nb.EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(5))
    res = fit(data, ST3, phase_weight=0.1)
    assert set(res.profiles) == {"wp", "w1", "wz", "w3"}
    for k, p in res.profiles.items():
        lo, hi = res.interval(k, 0.95)
        se = res.stderr[k]
        # the modes of eq 9.4 are well inside 0.1-40 Hz with coherence: the profile is nearly quadratic
        assert lo == pytest.approx(res.params[k] - 1.96 * se, abs=0.25 * 1.96 * se), k
        assert hi == pytest.approx(res.params[k] + 1.96 * se, abs=0.25 * 1.96 * se), k
        assert p.bounded(0.95) == (True, True) and p.lowest >= -1.0, k
    table = res.table()
    assert "95 % profile interval" in table and "w3/2pi" in table
    d = res.to_dict()["profile_intervals"]
    assert set(d) == {"wp", "w1", "wz", "w3"} and d["w1"]["95%"]["bounded_low"] is True
    assert fit(data, ST3, phase_weight=0.1, profile=False).profiles == {}
    with pytest.raises(ValueError, match="not among the structure's frequencies"):
        fit(data, ST3, phase_weight=0.1, profile=("zp",))


def test_profile_intervals_keep_the_calibrated_width_where_the_cost_is_quadratic():
    # the normal intervals' coverage is checked in test_identify_fit (eq 9.4, 40 trials); on the same
    # kind of data the profile's must be the same intervals, trial by trial (over 60 trials of seeds
    # 300-359 both covered wp/wz/w1/w3 at 0.917, widths 0.98-1.02 of the normal ones), so that the
    # profile widens an interval only where the cost is not quadratic
    ratios = []
    for seed in range(8):
        data = synthesize(
            F_HZ, {c: ST3.response(nb.EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(300 + seed)
        )
        res = fit(data, ST3, phase_weight=0.1, n_perturbed=0)
        for k in res.profiles:
            lo, hi = res.interval(k, 0.95)
            ratios.append((hi - lo) / (2 * 1.959964 * res.stderr[k]))
    assert 0.95 < min(ratios) and max(ratios) < 1.08, (min(ratios), max(ratios))


def test_large_data_are_profiled_on_all_points_when_asked_and_said_when_not():
    # 3000 points (an FFT's): the fit's search is thinned to 1000, its profile must not be (a thinned cost's own
    # minimum lies sqrt(k) standard errors away: read off it, an interval came out 2.3 times too wide here)
    f = np.geomspace(0.1, 40.0, 3000)
    data = synthesize(f, {c: ST3.response(nb.EQ9_4, f, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(5))
    res = fit(data, ST3, phase_weight=0.1, n_perturbed=0, profile=True)
    for k in res.profiles:
        lo, hi = res.interval(k, 0.95)
        assert (hi - lo) / (2 * 1.959964 * res.stderr[k]) == pytest.approx(1.0, abs=0.05), k
    auto = fit(data, ST3, phase_weight=0.1, n_perturbed=0)  # "auto": not on more than SEARCH_POINTS points
    assert auto.profiles == {} and "No profile intervals on 3000 points" in auto.message


def test_samii_fit_profiles_option(tmp_path, capsys):
    import json

    from samii.cli import main
    from samii.formats import write_frf_csv

    data = synthesize(F_HZ, {c: ST3.response(nb.EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(5))
    path = tmp_path / "frf.csv"
    write_frf_csv(data, path)
    assert main(["fit", str(path), "--json", "--no-progress"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["profile_intervals"]) == {"wp", "w1", "wz", "w3"}
    lo, hi = out["profile_intervals"]["w1"]["95%"]["low"], out["profile_intervals"]["w1"]["95%"]["high"]
    assert lo < out["params"]["w1"] < hi
    assert main(["fit", str(path), "--json", "--no-progress", "--profiles", "off"]) == 0
    assert json.loads(capsys.readouterr().out)["profile_intervals"] == {}


def test_the_profile_concern_level_is_chi2_s_999_quantile_on_one_dof():
    # fit.py keeps the number typed (scipy.stats is not imported by the fit): it must be the quantile its comment names
    assert PROFILE_BELOW_CONCERN == pytest.approx(chi2.isf(1e-3, 1), abs=5e-3)


def test_a_fit_its_own_profile_undercuts_is_not_sound(monkeypatch):
    """A profile that finds a cost more than the chi-square 0.999 quantile (10.83) below the fit's puts the fit's
    value outside its own 99.9 % interval: a concern (not sound); less is a warning only. The scan's result is
    patched (a real second minimum is the starts' work to avoid), the verdict read from it."""
    import dataclasses
    import importlib

    fit_module = importlib.import_module("samii.identify.fit")
    data = synthesize(F_HZ, {c: ST3.response(nb.EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(5))
    real = fit_module.profile_scan
    for drop, concern in ((4.0, False), (30.0, True)):

        def undercut(name, x, i, *args, drop=drop):
            p = real(name, x, i, *args)
            return dataclasses.replace(p, lowest=-drop, lowest_at=x[i] * 1.3) if name == "wp" else p

        monkeypatch.setattr(fit_module, "profile_scan", undercut)
        r = fit(data, ST3, phase_weight=0.1)
        said = [c for c in r.concerns if c.code == "not_lowest" and c.names == ("wp",)]
        assert bool(said) == concern, r.concerns
        if concern:  # the figures it rests on: the drop and where the profile found it
            v = said[0].values
            assert v["below"] == pytest.approx(drop) and v["held_hz"] == pytest.approx(1.3 * v["fit_hz"])  # (undercut's)
            assert said[0].text.startswith("wp is not at the minimum of the fit's cost")
        assert any(w.startswith("holding wp at") for w in r.warnings)
        assert r.sound == (not concern) and (r.verdict == "not sound") == concern
