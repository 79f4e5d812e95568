"""Pole maps of the chapter-8 design (the notebook's figures 8.1 and 8.2). Compute lives in :mod:`samii.design.placement`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from samii.viz.figures import pyplot, save_figure

__all__ = ["plot_pole_sets"]


def plot_pole_sets(design, *, path: str | Path | None = None):
    """s-plane and z-plane maps: open loop, unity theta feedback, desired controller poles, observer poles.

    ``design`` is a :class:`samii.design.placement.PlacementDesign`.
    """

    plt = pyplot(agg=path is not None)

    from samii.design.placement import unity_feedback_poles  # (lazy: imports PIL, control, matplotlib, scipy, only when called)

    T = design.sample_time_s
    ol = np.linalg.eigvals(np.asarray(design.model.A))
    ufb = unity_feedback_poles(design.model)
    zeta = "1/sqrt(2)" if np.isclose(design.zeta, 1 / np.sqrt(2), rtol=1e-12, atol=0) else f"{design.zeta:.5g}"
    sets = [
        ("open loop (eq 8.1)", ol, "x", "k"),
        ("unity theta feedback (eq 8.2)", ufb, "+", "C0"),
        (f"desired, zeta = {zeta} (eq 8.3)", design.poles_s, "o", "C3"),
    ]
    if design.observer_poles_s is not None:
        sets.append(("observer, 2x desired", design.observer_poles_s, "s", "C2"))
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(15, 7), layout="constrained")
    for label, p, m, c in sets:
        a1.plot(p.real, p.imag, m, color=c, mfc="none", ms=8, mew=1.4, label=label)
        z = np.exp(p * T)
        z = z[z.imag >= 0]  # upper half: the conjugates mirror them
        a2.plot(z.real, z.imag, m, color=c, mfc="none", ms=8, mew=1.4, label=label)
    if design.observer_poles_s is None:
        z = np.asarray(design.observer_poles_z)
        z = z[z.imag >= 0]
        a2.plot(z.real, z.imag, "s", color="C2", mfc="none", ms=8, label="Kalman filter poles")
    a1.set_xlabel("real part [1/s]", fontsize=11)
    a1.set_ylabel("imaginary part [rad/s]", fontsize=11)
    a1.set_title("continuous poles (s plane)", fontsize=12)
    a1.axvline(0, color="0.6", lw=0.8)
    a1.grid(True, alpha=0.3)
    th = np.linspace(0, np.pi / 2, 200)
    a2.plot(np.cos(th), np.sin(th), "-", color="0.6", lw=0.8, label="unit circle")
    a2.set_xlim(0.6, 1.02)
    a2.set_ylim(-0.01, 0.2)
    a2.set_xlabel("real part of z", fontsize=11)
    a2.set_ylabel("imaginary part of z", fontsize=11)
    a2.set_title(f"digital poles z = exp(s T), T = {T * 1e3:g} ms; Im z >= 0 (conjugates omitted)", fontsize=12)
    a2.grid(True, alpha=0.3)
    for ax in (a1, a2):
        ax.tick_params(labelsize=10)
    # one legend below both panels (the z-plane's entries include the s-plane's), covering no pole
    fig.legend(*a2.get_legend_handles_labels(), loc="outside lower center", ncols=3, fontsize=10.5)
    fig.suptitle("Chapter 8 pole placement on the eq 1.4 model (1 accelerometer, canonical form of chapter 5)", fontsize=13)
    if path is not None:
        save_figure(fig, path, dpi=100)
    return fig
