"""Root-locus figures for the mass-damping study (compute lives in :mod:`samii.design.rootlocus`).

matplotlib is imported inside the functions, so importing this module is cheap.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from samii.viz.figures import pyplot, save_figure

__all__ = ["plot_root_locus", "plot_variant", "stable_text", "ZOOM_RAD_S", "FONT", "DPI", "FIGSIZE_IN"]

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
    from samii.design.rootlocus import intervals_of_sign  # (lazy: imports PIL, control, matplotlib, scipy, only when called)

    parts = [f"{_fmt_gain(a)} < K_a < {_fmt_gain(b)}" for a, b in intervals_of_sign(intervals, sign)]
    return "stable for " + " and ".join(parts) if parts else f"unstable for every K_a {'> 0' if sign > 0 else '< 0'}"


#: Font sizes [pt] of the root-locus figures (saved at :data:`DPI`, read at 100 %).
FONT = {"base": 11, "title": 12, "suptitle": 13, "legend": 10.5}

#: Resolution of the saved figures; with :data:`FIGSIZE_IN` about 1800 x 1300 pixels.
DPI = 100
FIGSIZE_IN = (18.0, 13.0)


def _finite(poles: np.ndarray) -> np.ndarray:
    poles = np.asarray(poles, complex)
    return poles[np.isfinite(poles)]


def plot_root_locus(data, *, ax=None, zoom: bool = False, best=None, limit=None, stable: str | None = None, title: str | None = None):
    """Draw one root locus (:class:`samii.design.rootlocus.RootLocusData`) on ``ax``; no legend (see :func:`plot_variant`).

    Parameters
    ----------
    zoom : bool
        Limit the view to :data:`ZOOM_RAD_S` instead of all poles and zeros.
    best : tuple (gain, poles), optional
        Closed-loop poles to mark (e.g. at the best gain of the summary).
    limit : tuple (gain, poles), optional
        Closed-loop poles at the stability limit of this sign; a pole at
        infinity (a biproper loop at ``K_a = 1/D``) is named in its label.
    stable : str, optional
        The stable gain range of this sign, added as a legend entry.
    """
    plt = pyplot(agg=False)

    if ax is None:
        _, ax = plt.subplots(figsize=(8, 6.5))
    loci = data.loci
    sign = "+" if data.sign > 0 else "-"
    kmax = np.max(np.abs(data.gains))
    drawn = f"$K_a$ from 0 to {sign}{kmax:.3g}"
    (x0, x1), (y0, y1) = ZOOM_RAD_S if zoom else _limits(data)
    # the unstable half plane, behind everything
    ax.axvspan(0.0, max(x1, 1.0), color="C3", alpha=0.07, lw=0, label="unstable region (Re s > 0)")
    start = loci[0]
    is_base = np.array(
        [
            np.min(np.abs(data.base_modes - x)) < 1e-3 * max(abs(x), 1.0) or np.min(np.abs(np.conj(data.base_modes) - x)) < 1e-3 * max(abs(x), 1.0)
            for x in start
        ]
    )
    first = {True: True, False: True}
    for j in np.argsort(is_base):  # base-mode branches drawn last, on top
        b = bool(is_base[j])
        label = (f"base-mode branches, {drawn}" if b else f"other branches, {drawn}") if first[b] else None
        first[b] = False
        ax.plot(loci[:, j].real, loci[:, j].imag, "-", color="C3" if b else "C0", lw=2.0 if b else 1.4, label=label)
    ax.plot(data.poles.real, data.poles.imag, "x", color="k", ms=9, mew=2.0, label="open-loop poles ($K_a$ = 0)")
    if data.zeros.size:
        ax.plot(data.zeros.real, data.zeros.imag, "o", mfc="none", color="C2", ms=9, mew=1.6, label="open-loop zeros")
    for i, m in enumerate(data.base_modes):
        ax.plot([m.real], [m.imag], "s", mfc="none", color="C3", ms=14, mew=1.5, label="base modes (open loop)" if i == 0 else None)
    if limit is not None:
        k, poles = limit
        fin = _finite(poles)
        at_inf = len(np.atleast_1d(poles)) - len(fin)
        extra = f" and {at_inf} at infinity (the loop is singular there)" if at_inf else ""
        ax.plot(fin.real, fin.imag, "D", mfc="none", color="C4", ms=9, mew=1.6, label=f"poles at the stability limit $K_a$ = {k:.4g}{extra}")
    if best is not None:
        k, poles = best
        fin = _finite(poles)
        ax.plot(fin.real, fin.imag, "*", color="C1", ms=14, mec="k", mew=0.5, label=f"best $K_a$ = {k:.4g} (6 dB gain margin)")
    if stable is not None:
        ax.plot([], [], " ", label=stable.replace("K_a", "$K_a$"))
    ax.axvline(0.0, color="0.45", lw=1.0)
    ax.axhline(0.0, color="0.6", lw=0.8)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    # lines of constant damping 0.05 and 0.7 for reading damping ratios off the plot
    for z, ls in ((0.05, ":"), (0.7, "--")):
        r = np.array([0.0, 2 * max(abs(x0), abs(y1))])
        ax.plot(-z * r, np.sqrt(1 - z**2) * r, ls, color="0.4", lw=1.0, label=f"damping ratio {z}")
    ax.set_xlabel("real part [1/s]", fontsize=FONT["base"])
    ax.set_ylabel("imaginary part [rad/s]", fontsize=FONT["base"])
    ax.tick_params(labelsize=FONT["base"] - 1)
    ax.set_title(title or f"{data.label}, $K_a$ {sign}" + (" (zoom)" if zoom else ""), fontsize=FONT["title"])
    ax.grid(True, alpha=0.3)
    return ax


def _header(loop, summary) -> str:
    lines = [f"Mass-damping root locus: {loop.label} ({loop.variant.describe()})"]
    if summary is not None:
        iv = ", ".join(f"({_fmt_gain(a)}, {_fmt_gain(b)})" for a, b in summary.stable_intervals)
        moving = ", ".join(f"mode {m.mode} {m.open_loop_zeta:.4f} -> {m.best_zeta:.4f}" for m in summary.modes if not m.fixed)
        excl = f"; mode {', '.join(map(str, summary.excluded_modes))} fixed by pole-zero cancellation (excluded)" if summary.excluded_modes else ""
        lines.append(f"stable $K_a$: {iv};  best damping ratio over stable $K_a$: {moving}{excl}")
        lines.append(
            f"least damping of the moving base modes: {summary.best_ratio:.2f}x open loop (with a 6 dB gain margin: {summary.robust_ratio:.2f}x)"
        )
    lines.append("sign: theta = G_cl (theta_ref + $K_a$ F y); the notebook's $K_a$ is minus ours")
    return "\n".join(textwrap.fill(line, 170) for line in lines)


def plot_variant(loop, summary=None, *, path: str | Path | None = None, n_gains: int = 1500):
    """Four panels for one variant: K_a > 0 and K_a < 0, full and zoomed, each row's legend beside it; save to ``path`` if given.

    At a stability limit where the loop is singular (a biproper loop at
    ``K_a = 1/D``, where a pole passes through infinity) the finite poles are
    drawn and the legend says how many are at infinity.
    """

    plt = pyplot(agg=path is not None)

    from samii.design import rootlocus as rl  # (lazy: imports PIL, control, matplotlib, scipy, only when called)

    header = _header(loop, summary)
    # a fixed layout (constrained layout costs a third of the drawing time): the header's lines, then two rows
    fig = plt.figure(figsize=FIGSIZE_IN)
    line_h = 1.45 * FONT["suptitle"] / 72.0 / FIGSIZE_IN[1]  # one header line as a fraction of the figure height
    top = 1.0 - 0.012 - line_h * (header.count("\n") + 1) - 0.035
    gs = fig.add_gridspec(2, 3, width_ratios=(1.0, 1.0, 0.68), left=0.045, right=0.995, bottom=0.05, top=top, wspace=0.14, hspace=0.2)
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
        name = "$K_a$ > 0" if sign > 0 else "$K_a$ < 0"
        full, zoom, side = fig.add_subplot(gs[row, 0]), fig.add_subplot(gs[row, 1]), fig.add_subplot(gs[row, 2])
        plot_root_locus(data, ax=full, best=best, limit=limit, title=f"{name}: all poles and zeros")
        plot_root_locus(data, ax=zoom, zoom=True, best=best, limit=limit, title=f"{name}: zoom on the base modes")
        side.axis("off")
        handles, labels = full.get_legend_handles_labels()
        labels = [textwrap.fill(t, 44, subsequent_indent="  ") for t in labels]
        side.legend(handles, labels, loc="center left", fontsize=FONT["legend"], frameon=True, borderaxespad=0.0,
                    title=f"{name}: {text.replace('K_a', '$K_a$')}", title_fontsize=FONT["legend"] + 0.5, alignment="left")  # fmt: skip
    fig.suptitle(header, fontsize=FONT["suptitle"], y=0.994, va="top")
    if path is not None:
        save_figure(fig, path, dpi=DPI)
    return fig
