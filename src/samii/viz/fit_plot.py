"""Plots of Bode fits: data, fitted models and coherence, with units.

matplotlib is imported inside the functions (compute paths never import it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from samii.frequency_response import Channel, FrequencyResponse
from samii.viz.bode_plot import CHANNEL_LABELS

__all__ = ["plot_fit_overlay", "plot_model_error", "plot_parameter_sweep", "plot_panels"]

from samii.viz.figures import pyplot
from samii.viz.phase import ANCHOR_COHERENCE, anchored_phase_deg

#: Alternate solid and dashed lines so that curves lying on top of each other stay visible.
_LINESTYLES = ("-", "--")


def _finish(fig, title: str | None, note: str | None, *, note_height: float, top: float = 1.0):
    """Title on top, provenance note in small print at the bottom, tight layout (axes below ``top``)."""
    if title:
        fig.suptitle(title, fontsize=11)
    if note:
        fig.text(0.01, 0.005, note, fontsize=7, va="bottom", ha="left", color="0.25", wrap=True)
    fig.tight_layout(rect=(0, note_height if note else 0, 1, top))
    return fig


def _figure_legend(fig, handles: Mapping[str, object], *, max_cols: int, title: bool) -> float:
    """One legend for the whole figure, between the title and the plots (inside an axes it hides
    data somewhere). Returns the top of the area left for the axes, for ``_finish``."""
    rows = int(np.ceil(len(handles) / max_cols))
    ncol = int(np.ceil(len(handles) / rows))  # balanced rows (matplotlib fills column by column)
    top = 1.0 - (0.035 if title else 0.0) - 0.026 * rows
    fig.legend(
        list(handles.values()),
        list(handles),
        loc="lower center",
        bbox_to_anchor=(0.5, top - 0.012),
        ncol=ncol,
        fontsize=8,
        frameon=False,
        borderaxespad=0.0,
    )
    return top + 0.012


def _aligned_phase_deg(h: np.ndarray, ref_deg: np.ndarray | None, weight: np.ndarray | None = None) -> np.ndarray:
    """Unwrapped phase of ``h``, shifted by whole turns to sit nearest ``ref_deg`` (the data)
    at the points where ``weight`` is true (all if None)."""
    ph = np.degrees(np.unwrap(np.angle(h)))
    if ref_deg is None:
        return ph
    d = ph - ref_deg
    if weight is not None and np.any(weight):
        d = d[weight]
    return ph - 360.0 * np.round(np.median(d) / 360.0)


def _model_response(model, freq_hz: np.ndarray, channel: Channel) -> np.ndarray | None:
    """Response of a FitResult or a (ModelStructure, params) pair; None if the model cannot give that channel."""
    if hasattr(model, "structure"):
        try:
            return model.response(freq_hz, channel)
        except ValueError:  # a channel whose parameters were not fitted
            return None
    st, params = model
    return st.response(params, freq_hz, channel)


def plot_fit_overlay(
    data: FrequencyResponse,
    models: Mapping[str, object],
    *,
    channels: Sequence[Channel] | None = None,
    band_hz: tuple[float, float] | None = None,
    title: str | None = None,
    note: str | None = None,
    n_model_points: int = 600,
    model_span_hz: tuple[float, float] | None = None,
):
    """Bode overlay: one column per channel; magnitude, phase and coherence rows.

    Parameters
    ----------
    data : FrequencyResponse
        Drawn as dots (coherence as a line in the bottom row when present).
    models : mapping label -> FitResult or (ModelStructure, params)
        Drawn as lines on a dense log grid over the data's span.
    band_hz : (lo, hi), optional
        The fit band, shaded.
    model_span_hz : (lo, hi), optional
        Draw the models over this span (e.g. beyond the data) instead of the data's.
    note : str, optional
        Provenance printed under the plots (e.g. "synthetic data: ...").

    Returns
    -------
    matplotlib.figure.Figure
    """
    plt = pyplot(agg=False)

    channels = tuple(channels or [c for c in ("act", "base") if c in data.channels] or data.channels)
    f = data.freq_hz
    fm = np.geomspace(*(model_span_hz or (f[0], f[-1])), n_model_points)
    has_coh = any(data.coherence(c) is not None for c in channels)
    rows = 3 if has_coh else 2
    fig, axes = plt.subplots(
        rows,
        len(channels),
        figsize=(5.2 * len(channels), 7.4 if has_coh else 6.0),
        sharex=True,
        squeeze=False,
        gridspec_kw={"height_ratios": [3, 3, 1.3][:rows]},
    )
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    handles: dict = {}
    for j, ch in enumerate(channels):
        name, unit = CHANNEL_LABELS[ch]
        am, ap = axes[0, j], axes[1, j]
        coh = data.coherence(ch)
        ph_data = anchored_phase_deg(data.response(ch), coh)
        (handles["data"],) = am.semilogx(f, data.magnitude_db(ch), ".", ms=2.5, color="0.45", zorder=1)
        ap.semilogx(f, ph_data, ".", ms=2.5, color="0.45", zorder=1)
        good_m = None if coh is None else np.interp(np.log(fm), np.log(f), coh) >= ANCHOR_COHERENCE
        ref = np.interp(np.log(fm), np.log(f), ph_data)
        for k, (label, model) in enumerate(models.items()):
            h = _model_response(model, fm, ch)
            if h is None:
                continue
            style = dict(ls=_LINESTYLES[k % 2], lw=1.3, color=colors[k % len(colors)], zorder=2)
            (handles[label],) = am.semilogx(fm, 20 * np.log10(np.abs(h)), **style)
            ap.semilogx(fm, _aligned_phase_deg(h, ref, good_m), **style)
        am.set_title(name)
        am.set_ylabel(f"magnitude [dB re 1 {unit}]")
        ap.set_ylabel("phase [deg]")
        if has_coh:
            ac = axes[2, j]
            if coh is not None:
                ac.semilogx(f, coh, "-", lw=1.0, color="0.3")
            ac.set_ylim(0, 1.05)
            ac.set_ylabel("coherence")
        for a in axes[:, j]:
            a.grid(True, which="both", lw=0.3, alpha=0.6)
            if band_hz is not None:
                a.axvspan(*band_hz, color="tab:green", alpha=0.06, lw=0)
        axes[-1, j].set_xlabel("frequency [Hz]")
    if band_hz is not None:
        axes[0, -1].text(
            0.99,
            0.02,
            f"fit band {band_hz[0]:.3g}-{band_hz[1]:.3g} Hz (shaded)",
            transform=axes[0, -1].transAxes,
            ha="right",
            va="bottom",
            fontsize=7,
            color="tab:green",
        )
    top = _figure_legend(fig, handles, max_cols=4 if len(channels) > 1 else 2, title=bool(title))
    return _finish(fig, title, note, note_height=0.04, top=top)


def plot_model_error(
    freq_hz: np.ndarray,
    errors: Mapping[str, Mapping[str, tuple[np.ndarray, np.ndarray]]],
    *,
    band_hz: tuple[float, float] | None = None,
    title: str | None = None,
    note: str | None = None,
    what: str = "model - data",
):
    """Errors along frequency: magnitude [dB] and phase [deg] rows, one column per channel.

    ``errors``: label -> channel -> (dB error, deg error) on ``freq_hz``.
    """
    plt = pyplot(agg=False)

    channels = list(next(iter(errors.values())))
    fig, axes = plt.subplots(2, len(channels), figsize=(5.2 * len(channels), 5.9), sharex=True, squeeze=False)
    handles: dict = {}
    for j, ch in enumerate(channels):
        for k, (label, per) in enumerate(errors.items()):
            db, deg = per[ch]
            deg = np.degrees(np.unwrap(np.radians(deg)))  # errors are principal values; drawn continuous
            (handles[label],) = axes[0, j].semilogx(freq_hz, db, lw=1.2, ls=_LINESTYLES[k % 2])
            axes[1, j].semilogx(freq_hz, deg, lw=1.2, ls=_LINESTYLES[k % 2])
        axes[0, j].set_title(CHANNEL_LABELS[ch][0])
        axes[0, j].set_ylabel("magnitude error [dB]")
        axes[1, j].set_ylabel("phase error [deg]")
        axes[1, j].set_xlabel("frequency [Hz]")
        for a in axes[:, j]:
            a.axhline(0, color="0.3", lw=0.6)
            a.grid(True, which="both", lw=0.3, alpha=0.6)
            if band_hz is not None:
                a.axvspan(*band_hz, color="tab:green", alpha=0.06, lw=0)
    top = _figure_legend(fig, handles, max_cols=6 if len(channels) > 1 else 3, title=True)
    return _finish(fig, f"{title + ': ' if title else ''}{what}", note, note_height=0.05, top=top)


def plot_panels(
    x: Sequence[float],
    panels: Mapping[str, Mapping[str, Sequence[float]]],
    *,
    xlabel: str,
    title: str | None = None,
    note: str | None = None,
    logx: bool = False,
):
    """Side-by-side line plots: panel y-label -> series label -> values at ``x``."""
    plt = pyplot(agg=False)

    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 3.6), squeeze=False)
    for a, (ylabel, series) in zip(axes[0], panels.items()):
        for label, y in series.items():
            (a.semilogx if logx else a.plot)(x, y, "o-", ms=4, lw=1.2, label=label)
        if logx:  # label the points themselves, not powers of ten
            from matplotlib.ticker import NullFormatter  # (lazy: imports matplotlib, only when called)

            a.set_xticks(list(x), [f"{v:g}" for v in x])
            a.xaxis.set_minor_formatter(NullFormatter())
        a.set_xlabel(xlabel)
        a.set_ylabel(ylabel)
        a.grid(True, which="both", lw=0.3, alpha=0.6)
        a.legend(fontsize=8)
    return _finish(fig, title, note, note_height=0.06)


def _plot_reference_clipped(ax, x: np.ndarray, ref: np.ndarray, v: np.ndarray, err, label: str) -> None:
    """Reference points as open squares; one far outside the estimates' range (more than twice that
    range beyond it, such as a failed fit) is drawn as a triangle at the axis edge with its value,
    so that it does not flatten the estimates and their error bars."""
    lo, hi = np.nanmin(v - err), np.nanmax(v + err)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        ax.plot(x, ref, "s", mfc="none", ms=5, color="tab:red", label=label)
        return
    span = max(hi - lo, 1e-12 * max(abs(lo), abs(hi), 1.0))
    near = (ref >= lo - 2 * span) & (ref <= hi + 2 * span)
    ax.plot(x[near], ref[near], "s", mfc="none", ms=5, color="tab:red", label=label)
    if np.all(near):
        return
    inside = np.concatenate([[lo, hi], ref[near]])
    y0, y1 = inside.min(), inside.max()
    pad = 0.1 * (y1 - y0)
    ax.set_ylim(y0 - pad, y1 + pad)
    for xi, ri in zip(x[~near], ref[~near]):
        y = y1 + pad * 0.5 if ri > y1 else y0 - pad * 0.5
        ax.plot(xi, y, "^" if ri > y1 else "v", mfc="none", ms=5, color="tab:red")
        ax.annotate(f"{ri:.3g}", (xi, y), textcoords="offset points", xytext=(-4, -10 if ri > y1 else 4), ha="right", fontsize=6, color="tab:red")


#: A standard error above this many times its estimate marks a parameter the data do not
#: determine: its 95 % bar is clipped at the axis (arrows) and labelled, so it does not flatten the panel.
NOT_IDENTIFIABLE_REL = 10.0
#: A panel of positive values spanning more than this factor is drawn on a log axis.
LOG_SPAN = 30.0


def _not_identifiable(v: np.ndarray, se: np.ndarray) -> np.ndarray:
    """Mask of estimates whose standard error is infinite, undefined or above NOT_IDENTIFIABLE_REL times the estimate."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(v) & ~(se <= NOT_IDENTIFIABLE_REL * np.abs(v))


def _mark_not_identifiable(ax, x: np.ndarray, v: np.ndarray, se: np.ndarray, wild: np.ndarray, color) -> None:
    """Draw the 95 % bars of ``wild`` estimates only up to the axis edges, with arrows, and label them."""
    y0, y1 = ax.get_ylim()
    for xi, vi, si in zip(x[wild], v[wild], se[wild]):
        for end in (y1, y0):
            ax.annotate(
                "",
                xy=(xi, end),
                xytext=(xi, vi),
                annotation_clip=False,
                arrowprops=dict(arrowstyle="-|>", color=color, lw=0.8, ls=":", mutation_scale=7, shrinkA=0, shrinkB=0),
            )
        size = f"±{1.96 * si:.2g}" if np.isfinite(si) else "±inf"
        ax.annotate(
            f"not identifiable\n({size})", (xi, vi), textcoords="offset points", xytext=(5, -3), fontsize=6, color="tab:red", ha="left", va="top"
        )
    ax.set_ylim(y0, y1)


def plot_parameter_sweep(
    x: Sequence[float],
    estimates: Sequence[Mapping[str, float]],
    stderrs: Sequence[Mapping[str, float]] | None,
    names: Sequence[str],
    *,
    xlabel: str,
    reference: Mapping[str, Sequence[float]] | None = None,
    reference_label: str = "notebook",
    truth: Mapping[str, float] | None = None,
    units: Mapping[str, str] | None = None,
    title: str | None = None,
    note: str | None = None,
):
    """Small multiples: each parameter against ``x`` with 95 % error bars.

    ``reference`` (name -> values at the same ``x``) is drawn as open markers,
    ``truth`` (name -> value) as a horizontal line, ``units`` (name -> unit, e.g.
    ``ModelStructure.units()``) go into each panel's title. Parameters not
    fitted (NaN) leave their panel empty, so marked. A parameter the data do not
    determine (standard error infinite or above ``NOT_IDENTIFIABLE_REL`` times
    the estimate) keeps its point, but its bar is cut at the axis with arrows
    and labelled "not identifiable" with its size: the axis stays on the
    estimates and the reference. Positive values spanning more than a factor
    ``LOG_SPAN`` (a lag on its bound at 1e6 rad/s beside 100 rad/s) get a log axis.
    """
    plt = pyplot(agg=False)

    n = len(names)
    cols = 4 if n > 9 else 3
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.1 * cols, 2.1 * rows + 0.6), squeeze=False)
    x = np.asarray(x, float)
    for i, name in enumerate(names):
        a = axes.flat[i]
        v = np.array([e[name] for e in estimates], float)
        ref = np.asarray(reference[name], float) if reference is not None and name in reference else None
        fin = v[np.isfinite(v)]
        if fin.size and np.all(fin > 0) and fin.max() / fin.min() > LOG_SPAN:
            a.set_yscale("log")
        if stderrs is not None:
            se = np.array([s[name] for s in stderrs], float)
            wild = _not_identifiable(v, se)
            err = np.where(wild | ~np.isfinite(se), 0.0, 1.96 * se)
            lines = a.errorbar(x, v, yerr=err, fmt="o-", ms=3, lw=1, capsize=2, label="samii ±95 %")
        else:
            se, wild, err = np.zeros_like(v), np.zeros(v.shape, bool), 0.0
            lines = a.plot(x, v, "o-", ms=3, lw=1, label="samii")
        if ref is not None:
            _plot_reference_clipped(a, x, ref, v, err, reference_label)
        if truth is not None and name in truth:
            a.axhline(truth[name], color="0.4", lw=0.8, ls="--", label="data generated with")
        if np.any(wild):
            color = lines[0].get_color() if hasattr(lines[0], "get_color") else "C0"
            _mark_not_identifiable(a, x, v, se, wild, color)
        unit = (units or {}).get(name)
        a.set_title(f"{name} [{unit}]" if unit else name, fontsize=9)
        if not np.any(np.isfinite(v)):
            a.text(0.5, 0.5, "not fitted", transform=a.transAxes, ha="center", va="center", fontsize=8, color="0.4")
            a.set_xticks([])
            a.set_yticks([])
        a.tick_params(labelsize=7)
        a.grid(True, lw=0.3, alpha=0.6)
        a.set_xlabel(xlabel, fontsize=7)
    for a in list(axes.flat)[n:]:
        a.set_visible(False)
    handles: dict = {}
    for a in axes.flat[:n]:
        for h, label in zip(*a.get_legend_handles_labels()):
            handles.setdefault(label, h)
    axes.flat[0].legend(list(handles.values()), list(handles), fontsize=6)
    return _finish(fig, title, note, note_height=0.04)
