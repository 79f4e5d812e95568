"""Plots of fits (samii.viz.fit_plot): phase drawn where the data put it, units in titles, legend off the data."""

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402

from samii import notebook as nb  # noqa: E402
from samii.identify import ModelStructure, SweptSineNoise, fit, synthesize  # noqa: E402
from samii.viz.fit_plot import plot_fit_overlay, plot_parameter_sweep  # noqa: E402
from samii.viz.phase import ANCHOR_COHERENCE, anchored_phase_deg  # noqa: E402

F_HZ = np.geomspace(0.1, 40.0, 400)  # the notebook's swept-sine span (chapter 9)


def test_phase_is_unwrapped_through_well_measured_points_only():
    # a 50 ms delay: the true phase falls to -720 deg at 40 Hz. The first 60 points (below 0.24 Hz)
    # are noise with coherence 0.1 (as the simulator's base channel below 0.3 Hz) whose phase happens
    # to step by -2.5 rad from point to point: np.unwrap takes each step (< pi) as real and counts
    # 60 x 2.5 rad = 24 turns that are not there
    true_deg = -360.0 * F_HZ * 0.05
    ph = np.radians(true_deg)
    ph[:60] = np.angle(np.exp(-2.5j * np.arange(60)))
    h = np.exp(1j * ph)
    coh = np.where(np.arange(F_HZ.size) < 60, 0.1, 0.999)
    good = coh >= ANCHOR_COHERENCE
    anchored = anchored_phase_deg(h, coh)
    np.testing.assert_allclose(anchored[good], true_deg[good], atol=1e-9)
    assert np.all(np.abs(anchored[~good] - true_deg[~good]) <= 180.0 + 1e-9)  # noisy points near their neighbours' phase
    naive = np.degrees(np.unwrap(ph))
    assert np.max(np.abs(naive[good] - true_deg[good])) >= 360.0 - 1e-9  # what np.unwrap from the first point does


def test_overlay_legend_sits_outside_the_axes_and_parameter_titles_carry_units():
    st = ModelStructure.notebook_3mode()
    data = synthesize(F_HZ, {c: st.response(nb.EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(1))
    res = fit(data, st, phase_weight=0.1, n_perturbed=0)
    fig = plot_fit_overlay(data, {"fit": res, "eq 9.4": (st, nb.EQ9_4)}, title="t")
    assert len(fig.legends) == 1 and all(a.get_legend() is None for a in fig.axes)
    fig.canvas.draw()
    legend_box = fig.legends[0].get_window_extent()
    assert all(not legend_box.overlaps(a.get_window_extent()) for a in fig.axes)
    fig = plot_parameter_sweep([0.1], [res.params], [res.stderr], st.param_names, xlabel="phase weight", units=st.units())
    titles = [a.get_title() for a in fig.axes if a.get_visible()]
    assert "wp [rad/s]" in titles and "K1 [rad/(V·s)]" in titles and "z1 [1]" in titles
