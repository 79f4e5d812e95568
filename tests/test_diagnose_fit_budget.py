"""Fits that matter only if they beat a chi2 stop when they cannot (``samii.diagnose.model.HOPELESS_AFTER``).

A rival of an effect, the baseline refitted alone from a candidate's baseline, the model without an effect in the
backward step: each is only compared with a chi2 it must get below. A model that cannot describe the data (the
baseline without the delay the data have) crawls along a valley of two modes with huge opposite gains and runs to
its evaluation budget; the rule stops it when, at its pace, it would need more iterations than the budget has.
Checked here: the rule on chi2 histories, a crawl stopped (eq 9.4 with a 4 ms command delay fitted without one
from a start with modes 2 and 3 at ten times their gains, opposite), and a fit that gets below its chi2 (or
converges) left exactly as without the rule.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import OptimizeResult

from samii.diagnose.effects import LIBRARY
from samii.diagnose.model import HOPELESS_AFTER, HOPELESS_PACE, HOPELESS_WINDOW, Baseline, Dataset, _hopeless, fit_model, notebook_reference
from samii.identify.structures import ModelStructure

KINDS = {k.label: k for k in LIBRARY}


def _run(history, beat):
    """The iteration (1-based) at which the rule stops a fit whose chi2 goes through ``history``, or None."""
    cb = _hopeless(beat)
    for k, chi2 in enumerate(history, start=1):
        try:
            cb(OptimizeResult(cost=chi2 / 2.0))
        except StopIteration:
            return k
    return None


def test_the_rule_stops_a_crawl_above_its_chi2_and_nothing_else():
    n = 150
    crawl = 1000.0 + 100.0 * np.exp(-np.arange(n) / 300.0)  # 0.3 a step, 100 above: ~3 per window against a gap of ~100
    k = _run(crawl, beat=1000.0)
    assert k == max(HOPELESS_AFTER, HOPELESS_WINDOW) + 1  # as soon as the rule may judge
    # falling fast enough to close the gap within HOPELESS_PACE windows: not stopped
    fast = 1000.0 + 100.0 * np.maximum(1.0 - np.arange(n) / (0.8 * HOPELESS_WINDOW * HOPELESS_PACE), 0.0) - 1.0
    assert _run(fast, beat=1000.0) is None
    # below the chi2 to beat: never stopped, however slowly it moves
    assert _run(crawl - 200.0, beat=1000.0) is None
    # above it and not moving at all (converged in a worse basin): stopped
    assert _run(np.full(n, 1100.0), beat=1000.0) == max(HOPELESS_AFTER, HOPELESS_WINDOW) + 1


@pytest.fixture(scope="module")
def delayed():
    """Eq 9.4 (SI) with a 4 ms command delay on theta/v and xdd/v, 1 % log noise, 0.1-40 Hz: the dataset, the baseline,
    the baseline's fit without the delay and with it."""
    rng = np.random.default_rng(0)
    f = np.geomspace(0.1, 40.0, 250)
    st, ref = ModelStructure.notebook_3mode(), notebook_reference()
    data, keep, inv = {}, {}, {}
    for ch in ("act", "total"):
        h = (
            st.response(ref, f, ch)
            * np.exp(-2j * np.pi * f * 0.004)
            * np.exp(0.01 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)))
        )
        data[ch], keep[ch], inv[ch] = h, np.ones(f.size, bool), np.full(f.size, 100.0)
    ds = [Dataset("a", f, data, keep, inv, True, 1.0, 0.1)]
    bl = Baseline(structure=st, params=(ref,), reference=ref)
    return ds, bl, fit_model(ds, bl, []), fit_model(ds, bl, [(KINDS["delay/command"], np.array([0.002]))])


def _counting(monkeypatch):
    from samii.diagnose import model

    calls = {"n": 0}
    orig = model._Problem.residuals

    def counted(self, z):
        calls["n"] += 1
        return orig(self, z)

    monkeypatch.setattr(model._Problem, "residuals", counted)
    return calls


def test_a_model_that_cannot_fit_stops_crawling(delayed, monkeypatch):
    ds, bl, without, with_delay = delayed
    assert with_delay.chi2 < 0.01 * without.chi2  # the delay is what the data need
    st, ref = bl.structure, bl.reference
    # modes 2 and 3 at ten times their gains, opposite: the valley of huge opposite gains
    start = [st.vector({**ref, "B2": 10.0 * ref["B2"], "B3": -10.0 * ref["B3"]})]
    calls = _counting(monkeypatch)
    free = fit_model(ds, bl, [], start_baseline=start)
    n_free = calls["n"]
    calls["n"] = 0
    stopped = fit_model(ds, bl, [], start_baseline=start, beat=with_delay.chi2)
    assert n_free >= 200 and not free.stopped  # the crawl runs to the budget
    assert stopped.stopped and calls["n"] < n_free / 3
    assert stopped.chi2 > with_delay.chi2 and free.chi2 > with_delay.chi2  # the decision it fed is the same


@pytest.mark.parametrize("beat", ["reached", "converged"])
def test_a_fit_that_can_matter_is_left_as_it_was(delayed, beat):
    ds, bl, without, with_delay = delayed
    st, ref = bl.structure, bl.reference
    start = [st.vector({**ref, "B3": 50.0 * ref["B3"]})]  # converges to the baseline's minimum in a few tens of steps
    free = fit_model(ds, bl, [], start_baseline=start)
    # a chi2 it gets below, or one it cannot reach but converges towards too fast to be judged hopeless
    target = 1.01 * free.chi2 if beat == "reached" else with_delay.chi2
    ruled = fit_model(ds, bl, [], start_baseline=start, beat=target)
    assert not ruled.stopped
    assert ruled.chi2 == free.chi2
    assert ruled.baseline_params == free.baseline_params
