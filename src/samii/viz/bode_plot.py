"""Bode plot of measured frequency responses: magnitude, phase and coherence of act, base, total.

Plotting only; matplotlib is imported here, never in compute paths.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from samii.frequency_response import CHANNELS, FrequencyResponse
from samii.viz.phase import anchored_phase_deg

__all__ = ["bode_plot", "CHANNEL_LABELS"]

#: (title, magnitude unit) per channel.
CHANNEL_LABELS = {
    "act": ("actuator  θ/v", "rad/V"),
    "base": ("flexible base  ẍ/θ", "(m/s²)/rad"),
    "total": ("total  ẍ/v", "(m/s²)/V"),
}


def _anchored_phase(frf: FrequencyResponse, ch: str, threshold: float | None) -> np.ndarray:
    """Phase [deg] unwrapped through the coherent points (:func:`samii.viz.phase.anchored_phase_deg`),
    on the branch where the coherent point nearest the band's geometric centre lies in -180...180."""
    coh = frf.coherence(ch)
    kw = {} if threshold is None else {"min_coherence": threshold}
    ph = anchored_phase_deg(frf.response(ch), coh if threshold is not None else None, **kw)
    good = np.ones(ph.size, bool) if coh is None or threshold is None else coh >= threshold
    if not np.any(good):
        good[:] = True
    centre = 0.5 * (np.log(frf.freq_hz[0]) + np.log(frf.freq_hz[-1]))
    candidates = np.flatnonzero(good)
    i = int(candidates[np.argmin(np.abs(np.log(frf.freq_hz[candidates]) - centre))])
    return ph - 360.0 * np.round(ph[i] / 360.0)


def _coherence(frf: FrequencyResponse, ch: str) -> np.ndarray | None:
    """Coherence of ``ch``, or None when the data carry none (one record: every value NaN)."""
    coh = frf.coherence(ch)
    if coh is None or not np.any(np.isfinite(coh)):
        return None
    return coh


def _mark_off_scale(ax, freq_hz: np.ndarray, values: np.ndarray, color: str) -> int:
    """Draw points that lie beyond ``ax``'s y-limits as triangles on its edge; return how many."""
    lo, hi = ax.get_ylim()
    above, below = values > hi, values < lo
    span = hi - lo
    if np.any(above):
        ax.semilogx(freq_hz[above], np.full(above.sum(), hi - 0.03 * span), "^", color=color, ms=5, mfc="none", clip_on=False)
    if np.any(below):
        ax.semilogx(freq_hz[below], np.full(below.sum(), lo + 0.03 * span), "v", color=color, ms=5, mfc="none", clip_on=False)
    return int(above.sum() + below.sum())


def _faded(y: np.ndarray, coh: np.ndarray | None, threshold: float | None) -> np.ndarray:
    """``y`` with the points below the coherence threshold blanked (NaN, not drawn)."""
    if coh is None or threshold is None:
        return y
    return np.where(coh >= threshold, y, np.nan)


def _align_phase(phase_deg: np.ndarray, freq_hz: np.ndarray, ref_phase_deg: np.ndarray, ref_freq_hz: np.ndarray) -> np.ndarray:
    """Shift each point by whole turns to the branch of a reference curve."""
    ref = np.interp(np.log(freq_hz), np.log(ref_freq_hz), ref_phase_deg)
    return phase_deg - 360.0 * np.round((phase_deg - ref) / 360.0)


def bode_plot(
    frf: FrequencyResponse | None,
    *,
    stepped: FrequencyResponse | None = None,
    reference: FrequencyResponse | None = None,
    reference_label: str = "reference",
    title: str | None = None,
    coherence_threshold: float | None = 0.95,
    path=None,
):
    """Draw magnitude [dB], phase [deg] and coherence of every channel of ``frf``.

    Parameters
    ----------
    frf : FrequencyResponse or None
        The swept-sine (or any) measurement, drawn as lines; None to draw
        only ``stepped``.
    stepped : FrequencyResponse, optional
        Stepped-sine points, drawn as markers on the same axes.
    reference : FrequencyResponse, optional
        A model or exact response, drawn dashed.
    title : str, optional
    coherence_threshold : float, optional
        Drawn as a dotted line on the coherence axes; swept-sine points below
        it are drawn light.
    path : path-like, optional
        Save the figure there (PNG by extension).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure  # (lazy: imports matplotlib, only when called)

    if frf is None and stepped is None:
        raise ValueError("bode_plot needs frf or stepped")
    present = set(frf.channels if frf is not None else ()) | set(stepped.channels if stepped is not None else ())
    channels = [ch for ch in CHANNELS if ch in present]
    fig = Figure(figsize=(4.6 * len(channels), 8.6), layout="constrained")
    axes = fig.subplots(3, len(channels), sharex="col", squeeze=False, gridspec_kw={"height_ratios": [3, 2.2, 1.2]})
    for j, ch in enumerate(channels):
        name, unit = CHANNEL_LABELS[ch]
        ax_mag, ax_ph, ax_coh = axes[:, j]
        # Phase branch: with a reference curve (smooth, dense), every measured point is
        # drawn on the reference's branch (within 180 deg of it), so that a noisy
        # stretch cannot carry the rest of the curve whole turns away; without
        # one, the measurement is unwrapped from a coherent mid-band anchor and
        # the stepped points follow it. ``branch`` is that curve: (freq_hz, phase_deg).
        branch = None
        lims = []
        if reference is not None and ch in reference.channels:
            ref_phase = np.degrees(np.unwrap(np.angle(reference.response(ch))))
            ref_phase -= 360.0 * np.round(np.median(ref_phase) / 360.0)
            branch = (reference.freq_hz, ref_phase)
            lims.append(ref_phase)
        if frf is not None and ch in frf.channels:
            coh = _coherence(frf, ch)
            if branch is None:
                phase = _anchored_phase(frf, ch, coherence_threshold)
                branch = (frf.freq_hz, phase)
            else:
                phase = _align_phase(frf.phase_deg(ch), frf.freq_hz, branch[1], branch[0])
            mag = frf.magnitude_db(ch)
            # the whole curve light, the coherent part solid
            ax_mag.semilogx(frf.freq_hz, mag, color="C0", lw=0.8, alpha=0.35)
            ax_ph.semilogx(frf.freq_hz, phase, color="C0", lw=0.8, alpha=0.35)
            ax_mag.semilogx(frf.freq_hz, _faded(mag, coh, coherence_threshold), color="C0", lw=1.3, label="swept sine")
            ax_ph.semilogx(frf.freq_hz, _faded(phase, coh, coherence_threshold), color="C0", lw=1.3)
            if coh is not None:
                ax_coh.semilogx(frf.freq_hz, coh, color="C0", lw=1.0)
            else:
                ax_coh.text(
                    0.5,
                    0.5,
                    "no coherence: one record\n(--averages 1)",
                    transform=ax_coh.transAxes,
                    ha="center",
                    va="center",
                    fontsize="small",
                    color="0.4",
                )
            coherent = np.isfinite(_faded(phase, coh, coherence_threshold))  # incoherent phase must not squash the axis
            lims.append(phase[coherent])
        if reference is not None and ch in reference.channels:  # drawn after the measurement: legend order
            ax_mag.semilogx(reference.freq_hz, reference.magnitude_db(ch), "k--", lw=0.9, label=reference_label)
            ax_ph.semilogx(reference.freq_hz, branch[1], "k--", lw=0.9)
        stepped_ph = None
        if stepped is not None and ch in stepped.channels:
            ph = stepped.phase_deg(ch)
            if branch is not None:
                ph = _align_phase(ph, stepped.freq_hz, branch[1], branch[0])
            ax_mag.semilogx(stepped.freq_hz, stepped.magnitude_db(ch), "o", color="C3", ms=4.5, mfc="none", label="stepped sine")
            ax_ph.semilogx(stepped.freq_hz, ph, "o", color="C3", ms=4.5, mfc="none")
            coh = _coherence(stepped, ch)
            if coh is not None:
                ax_coh.semilogx(stepped.freq_hz, coh, "o", color="C3", ms=3.5, mfc="none")
            lims.append(ph[np.isfinite(_faded(ph, coh, coherence_threshold))])
            stepped_ph = ph
        allv = np.concatenate(lims) if lims else np.empty(0)
        if allv.size:
            lo, hi = float(np.min(allv)), float(np.max(allv))
            pad = max(20.0, 0.08 * (hi - lo))
            ax_ph.set_ylim(lo - pad, hi + pad)
        if stepped_ph is not None:  # incoherent points beyond the axis: shown on its edge and counted, never dropped silently
            n_off = _mark_off_scale(ax_ph, stepped.freq_hz, stepped_ph, "C3")
            if n_off:
                ax_ph.text(
                    0.02,
                    0.03,
                    f"{n_off} stepped point(s) off scale (low coherence), drawn on the edge",
                    transform=ax_ph.transAxes,
                    fontsize="x-small",
                    color="C3",
                )
        ax_mag.set_title(name)
        ax_mag.set_ylabel(f"magnitude [dB re 1 {unit}]")
        ax_ph.set_ylabel("phase [deg]")
        ax_coh.set_ylabel("coherence [-]")
        ax_coh.set_ylim(-0.03, 1.05)
        if coherence_threshold is not None:
            ax_coh.axhline(coherence_threshold, color="0.5", lw=0.8, ls=":")
        ax_coh.set_xlabel("frequency [Hz]")
        for ax in (ax_mag, ax_ph, ax_coh):
            ax.grid(True, which="both", lw=0.3, alpha=0.6)
        if j == 0:
            ax_mag.legend(loc="best", fontsize="small")
    if title:
        fig.suptitle(title)
    if path is not None:
        fig.savefig(Path(path), dpi=110)
    return fig
