"""The Bode figure: three channels x (magnitude, phase, coherence), units on the axes, stepped points overlaid."""

import numpy as np

from samii import FrequencyResponse
from samii.viz.bode_plot import bode_plot


def _frf(f, noisy_low=False):
    s = 2j * np.pi * f
    act = 0.5 / (s * (1 + s / 160))
    base = s**4 * (-1.4e-3 / (s**2 + 0.65 * s + 118.5)) * 57.3
    coh = np.where(f < 0.3, 0.2, 1.0) if noisy_low else np.ones_like(f)
    return FrequencyResponse(f, act=act, base=base, total=act * base, act_coh=np.ones_like(f), base_coh=coh, total_coh=coh)


def test_bode_plot_layout_units_and_overlay(tmp_path):
    f = np.geomspace(0.1, 40, 200)
    steps = _frf(np.array([0.5, 2.0, 10.0]))
    fig = bode_plot(_frf(f, noisy_low=True), stepped=steps, reference=_frf(f), title="t", path=tmp_path / "bode.png")
    assert (tmp_path / "bode.png").stat().st_size > 10_000
    axes = fig.axes
    assert len(axes) == 9
    ylabels = [ax.get_ylabel() for ax in axes]
    assert "magnitude [dB re 1 rad/V]" in ylabels
    assert "magnitude [dB re 1 (m/s²)/rad]" in ylabels and "magnitude [dB re 1 (m/s²)/V]" in ylabels
    assert ylabels.count("phase [deg]") == 3 and ylabels.count("coherence [-]") == 3
    assert all(ax.get_xscale() == "log" for ax in axes)
    assert [ax.get_xlabel() for ax in axes].count("frequency [Hz]") == 3
    labels = axes[0].get_legend_handles_labels()[1]
    assert labels == ["swept sine", "reference", "stepped sine"]
    # stepped markers sit on the measured magnitude
    mag_ax = axes[0]
    marker_line = [ln for ln in mag_ax.get_lines() if ln.get_marker() == "o"][0]
    np.testing.assert_allclose(marker_line.get_ydata(), steps.magnitude_db("act"))


def test_bode_plot_of_act_only(tmp_path):
    f = np.geomspace(1, 10, 20)
    frf = FrequencyResponse(f, act=1 / (2j * np.pi * f))
    fig = bode_plot(frf)
    assert len(fig.axes) == 3
