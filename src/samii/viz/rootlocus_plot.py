"""Root-locus figures for the mass-damping study (compute lives in :mod:`samii.design.rootlocus`).

matplotlib is imported inside the functions, so importing this module is cheap.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_root_locus", "plot_variant", "stable_text", "ZOOM_RAD_S"]

#: Zoomed view around the base modes and the origin (real, imaginary limits in 1/s and rad/s),
#: as the notebook's "zooming in near the origin" figures (e.g. figure 2.2).
ZOOM_RAD_S = ((-40.0, 10.0), (-5.0, 75.0))


def _limits(data, pad: float = 1.3) -> tuple[tuple[float, float], tuple[float, float]]:
    pts = np.concatenate([data.poles, data.zeros]) if data.zeros.size else data.poles
    pts = pts[np.isfinite(pts)]
    r = max(np.max(np.abs(pts.real)), np.max(np.abs(pts.imag)), 1.0) * pad
    return (-r, 0.25 * r), (-0.05 * r, r)


def _fmt_gain(x: float) -> str:
    return "inf" if x == np.inf else "-inf" if x == -np.inf else f"{x:.4g}"


def stable_text(intervals, sign: int) -> str:
    """``"stable for -2.467 < K_a < 0"`` for the stable intervals of one sign (``"never stable"`` if none)."""
    from samii.design.rootlocus import intervals_of_sign

    parts = [f"{_fmt_gain(a)} < K_a < {_fmt_gain(b)}" for a, b in intervals_of_sign(intervals, sign)]
    return "stable for " + " and ".join(parts) if parts else f"unstable for every K_a {'> 0' if sign > 0 else '< 0'}"


def plot_root_locus(data, *, ax=None, zoom: bool = False, best=None, limit=None, stable: str | None = None, title: str | None = None):
    """Draw one root locus (:class:`samii.design.rootlocus.RootLocusData`) on ``ax``.

    Parameters
    ----------
    zoom : bool
        Limit the view to :data:`ZOOM_RAD_S` instead of all poles and zeros.
    best : tuple (gain, poles), optional
        Closed-loop poles to mark (e.g. at the best gain of the summary).
    limit : tuple (gain, poles), optional
        Closed-loop poles at the stability limit of this sign.
    stable : str, optional
        The stable gain range of this sign, shown in the legend.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(6, 5))
    loci = data.loci
    sign = "+" if data.sign > 0 else "-"
    kmax = np.max(np.abs(data.gains))
    drawn = f"K_a from 0 to {sign}{kmax:.3g}"
    start = loci[0]
    is_base = np.array([np.min(np.abs(data.base_modes - x)) < 1e-3 * max(abs(x), 1.0) or np.min(np.abs(np.conj(data.base_modes) - x)) < 1e-3 * max(abs(x), 1.0) for x in start])
    first = {True: True, False: True}
    for j in np.argsort(is_base):  # base-mode branches drawn last, on top
        b = bool(is_base[j])
        label = (f"base-mode branches, {drawn}" if b else f"other branches, {drawn}") if first[b] else None
        first[b] = False
        ax.plot(loci[:, j].real, loci[:, j].imag, "-", color="C3" if b else "C0", lw=1.4 if b else 1.0, label=label)
    ax.plot(data.poles.real, data.poles.imag, "x", color="k", ms=7, mew=1.5, label="open-loop poles (K_a = 0)")
    if data.zeros.size:
        ax.plot(data.zeros.real, data.zeros.imag, "o", mfc="none", color="C2", ms=7, mew=1.3, label="open-loop zeros")
    for i, m in enumerate(data.base_modes):
        ax.plot([m.real], [m.imag], "s", mfc="none", color="C3", ms=11, mew=1.2, label="base modes (open loop)" if i == 0 else None)
    if limit is not None:
        k, poles = limit
        ax.plot(poles.real, poles.imag, "D", mfc="none", color="C4", ms=7, mew=1.2, label=f"poles at the stability limit K_a = {k:.4g}")
    if best is not None:
        k, poles = best
        ax.plot(poles.real, poles.imag, "*", color="C1", ms=10, label=f"best K_a = {k:.4g} (6 dB margin)")
    if stable is not None:
        ax.plot([], [], " ", label=stable)
    ax.axvline(0.0, color="0.6", lw=0.8)
    ax.axhline(0.0, color="0.6", lw=0.8)
    (x0, x1), (y0, y1) = ZOOM_RAD_S if zoom else _limits(data)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    # lines of constant damping 0.05 and 0.7 for reading damping ratios off the plot
    for z, ls in ((0.05, ":"), (0.7, "--")):
        r = np.array([0.0, 2 * max(abs(x0), abs(y1))])
        ax.plot(-z * r, np.sqrt(1 - z**2) * r, ls, color="0.5", lw=0.8, label=f"damping ratio {z}")
    ax.set_xlabel("real part [1/s]")
    ax.set_ylabel("imaginary part [rad/s]")
    ax.set_title(title or f"{data.label}, K_a {sign}" + (" (zoom)" if zoom else ""), fontsize=9)
    ax.grid(True, alpha=0.3)
    return ax


def plot_variant(loop, summary=None, *, path: str | Path | None = None, n_gains: int = 1500):
    """Four panels for one variant: K_a > 0 and K_a < 0, full and zoomed; save to ``path`` if given."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from samii.design import rootlocus as rl

    fig, axes = plt.subplots(2, 2, figsize=(12, 10))
    intervals = summary.stable_intervals if summary is not None else rl.stable_gain_intervals(loop)
    for row, sign in enumerate((1, -1)):
        data = rl.root_locus_data(loop, sign=sign, n_gains=n_gains)
        best = None
        if summary is not None:
            res = summary.robust_positive if sign > 0 else summary.robust_negative
            if np.isfinite(res.best_gain) and res.best_gain != 0:
                best = (res.best_gain, rl.closed_loop_poles(loop, [res.best_gain])[0])
        k_lim = rl.stability_limit(intervals, sign)
        limit = (k_lim, rl.closed_loop_poles(loop, [k_lim])[0]) if np.isfinite(k_lim) else None
        text = stable_text(intervals, sign)
        name = "K_a > 0" if sign > 0 else "K_a < 0"
        plot_root_locus(data, ax=axes[row, 0], best=best, limit=limit, stable=text, title=f"{name}: full ({text})")
        plot_root_locus(data, ax=axes[row, 1], zoom=True, best=best, limit=limit, title=f"{name}: zoom on the base modes")
        axes[row, 0].legend(fontsize=7, loc="upper left")
    head = f"Mass-damping root locus: {loop.label} ({loop.variant.describe()})"
    if summary is not None:
        iv = ", ".join(f"({_fmt_gain(a)}, {_fmt_gain(b)})" for a, b in summary.stable_intervals)
        moving = ", ".join(f"mode {m.mode} {m.open_loop_zeta:.4f} -> {m.best_zeta:.4f}" for m in summary.modes if not m.fixed)
        excl = f"; mode {', '.join(map(str, summary.excluded_modes))} fixed by pole-zero cancellation (excluded)" if summary.excluded_modes else ""
        head += f"\nstable K_a: {iv};  best damping over stable K_a: {moving}{excl}"
        head += f"\nleast damping of the moving base modes: {summary.best_ratio:.2f}x open loop (6 dB margin: {summary.robust_ratio:.2f}x);  K_a sign: theta = G_cl (theta_ref + K_a F y), the notebook's K_a is minus ours"
    fig.suptitle(head, fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    if path is not None:
        fig.savefig(path, dpi=80)
        plt.close(fig)
    return fig
