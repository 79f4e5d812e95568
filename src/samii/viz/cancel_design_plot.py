"""Root locus of the chapter-10 compensator loop up to the chosen gain (the notebook's figures 10.2 and 10.3).

Compute lives in :mod:`samii.design.cancel`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from samii.viz.figures import pyplot, save_figure

__all__ = ["plot_cancel_locus"]


def plot_cancel_locus(design, *, notebook_gain: float | None = None, path: str | Path | None = None, n_gains: int = 400):
    """Closed-loop poles of ``1 + K L = 0`` for K from 0 to the design gain; full view and zoom near the origin."""

    import control  # (lazy: imports control, only when called)

    plt = pyplot(agg=path is not None)

    from samii.design.cancel import closed_loop_poles, pair_zetas  # (lazy: imports PIL, control, matplotlib, scipy, only when called)

    def zetas(k: float) -> str:
        return ", ".join(f"{z:.3f}" for z in pair_zetas(design.open_loop, k))

    kmax = max(design.gain, notebook_gain or 0.0)
    ks = np.linspace(0.0, kmax, n_gains)
    rl = control.root_locus_map(design.open_loop, gains=ks)
    loci = np.asarray(rl.loci)
    fig, axes = plt.subplots(1, 2, figsize=(15, 7.5), layout="constrained")
    for ax, zoom in zip(axes, (False, True)):
        for j in range(loci.shape[1]):
            ax.plot(loci[:, j].real, loci[:, j].imag, "-", color="C0", lw=1.0, label=f"closed-loop poles, K 0 to {kmax:.4g}" if j == 0 else None)
        p, z = design.open_loop.poles(), design.open_loop.zeros()
        ax.plot(p.real, p.imag, "x", color="k", ms=7, label="open-loop poles")
        ax.plot(z.real, z.imag, "o", mfc="none", color="C2", ms=7, label="open-loop zeros")
        end = design.closed_loop
        ax.plot(
            end.real,
            end.imag,
            "*",
            color="C3",
            ms=10,
            label=f"our K = {design.gain:.4g}: moving pairs zeta {zetas(design.gain)} (and the cancelled pair, on its zeros)",
        )
        if notebook_gain is not None:
            nbp = closed_loop_poles(design.open_loop, notebook_gain)
            ax.plot(nbp.real, nbp.imag, "^", mfc="none", color="C1", ms=8, label=f"notebook's K = {notebook_gain:g}: zeta {zetas(notebook_gain)}")
        r = np.array([0.0, 400.0])
        ax.plot(-0.7 * r, np.sqrt(1 - 0.49) * r, "--", color="0.5", lw=0.8, label="damping ratio 0.7")
        ax.axvline(0, color="0.45", lw=1.0)
        ax.axvspan(0.0, 30.0, color="C3", alpha=0.07, lw=0, label="unstable region (Re s > 0)")
        ax.set_xlabel("real part [1/s]", fontsize=11)
        ax.set_ylabel("imaginary part [rad/s]", fontsize=11)
        ax.tick_params(labelsize=10)
        if zoom:
            ax.set_xlim(-70, 5)
            ax.set_ylim(-5, 70)
            ax.set_title("zoom near the origin", fontsize=12)
        else:
            ax.set_xlim(-220, 20)
            ax.set_ylim(-5, 200)
            ax.set_title("full", fontsize=12)
        ax.grid(True, alpha=0.3)
    # one legend below both panels, where it covers no branch
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=10.5)
    fig.suptitle(
        f"Chapter 10 pole-cancelling compensator on eq 9.4, '{design.loop}' loop: root locus in K (1 + K L = 0); "
        "our K: slowest moving pair at zeta 0.7",
        fontsize=13,
    )
    if path is not None:
        save_figure(fig, path, dpi=100)
    return fig
