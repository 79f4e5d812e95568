"""The notebook's looped fminsearch and its percent-change criterion (chapter 9)."""

import numpy as np
import pytest

from samii.identify.notebook_loop import NOTEBOOK_TOL_PCT, nelder_mead_loop, percent_change


def test_percent_change_is_the_notebooks_definition():
    c = percent_change(np.array([10.0, -2.0]), np.array([10.0011, -2.0]), 5.0, 4.9995)
    assert c.max_param_pct == pytest.approx(0.011)
    assert c.cost_pct == pytest.approx(-0.01)
    assert NOTEBOOK_TOL_PCT == 0.01  # "maximum percent change ... of 0.01"
    assert not c.met
    assert percent_change(np.array([10.0]), np.array([10.0009]), 5.0, 4.9996).met
    assert percent_change(np.ones(2), np.ones(2) * 1.00005, 1.0, 1.0).met
    exact = percent_change(np.ones(2), np.ones(2), 2e-9, 4e-15, cost_floor=1e-12)  # an exact fit's last step
    assert exact.met and exact.cost_at_floor and exact.cost_pct == pytest.approx(-100, abs=1e-3)
    assert not percent_change(np.ones(2), np.ones(2), 2e-9, 4e-15).met


def test_loop_meets_the_criterion_for_five_consecutive_loops():
    target = np.array([3.0, -1.0, 2.0])

    def cost(x):
        return float(np.sum((x - target) ** 2 * np.array([1.0, 10.0, 100.0]))) + 1.0

    res = nelder_mead_loop(cost, np.zeros(3))
    assert res.criterion_met
    assert res.loops >= 6  # one loop that moves, then five that meet the criterion
    np.testing.assert_allclose(res.x, target, atol=1e-2)


def test_loop_gives_up_after_twenty_loops():
    res = nelder_mead_loop(lambda x: float(np.sum(x**2)) + 1.0, np.ones(8) * 5, loops=2, maxiter=5)
    assert not res.criterion_met and res.loops == 2
