"""Bode plot of measured frequency responses: magnitude, phase and coherence of act, base, total.

Plotting only; matplotlib is imported here, never in compute paths.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from samii.frequency_response import CHANNELS, FrequencyResponse

__all__ = ["bode_plot", "CHANNEL_LABELS"]

#: (title, magnitude unit) per channel.
CHANNEL_LABELS = {
    "act": ("actuator  θ/v", "rad/V"),
    "base": ("flexible base  ẍ/θ", "(m/s²)/rad"),
    "total": ("total  ẍ/v", "(m/s²)/V"),
}


def _anchored_phase(frf: FrequencyResponse, ch: str, threshold: float | None) -> np.ndarray:
    """Unwrapped phase [deg], put on the branch where it lies in -180...180 mid-band.

    The anchor is the coherent point nearest the band's geometric centre, not
    the lowest frequency: a weak signal at the band's edge (the base
    acceleration near 0.1 Hz) can throw an unwrap started there whole turns off.
    """
    ph = frf.phase_deg(ch)
    coh = frf.coherence(ch)
    good = np.ones(ph.size, bool) if coh is None or threshold is None else coh >= threshold
    if not np.any(good):
        good[:] = True
    centre = 0.5 * (np.log(frf.freq_hz[0]) + np.log(frf.freq_hz[-1]))
    candidates = np.flatnonzero(good)
    i = int(candidates[np.argmin(np.abs(np.log(frf.freq_hz[candidates]) - centre))])
    return ph - 360.0 * np.round(ph[i] / 360.0)


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
    from matplotlib.figure import Figure

    if frf is None and stepped is None:
        raise ValueError("bode_plot needs frf or stepped")
    present = set(frf.channels if frf is not None else ()) | set(stepped.channels if stepped is not None else ())
    channels = [ch for ch in CHANNELS if ch in present]
    fig = Figure(figsize=(4.6 * len(channels), 8.6), layout="constrained")
    axes = fig.subplots(3, len(channels), sharex="col", squeeze=False, gridspec_kw={"height_ratios": [3, 2.2, 1.2]})
    for j, ch in enumerate(channels):
        name, unit = CHANNEL_LABELS[ch]
        ax_mag, ax_ph, ax_coh = axes[:, j]
        ref_phase = None
        if frf is not None and ch in frf.channels:
            ref_phase = _anchored_phase(frf, ch, coherence_threshold)
            coh = frf.coherence(ch)
            mag = frf.magnitude_db(ch)
            # the whole curve light, the coherent part solid
            ax_mag.semilogx(frf.freq_hz, mag, color="C0", lw=0.8, alpha=0.35)
            ax_ph.semilogx(frf.freq_hz, ref_phase, color="C0", lw=0.8, alpha=0.35)
            ax_mag.semilogx(frf.freq_hz, _faded(mag, coh, coherence_threshold), color="C0", lw=1.3, label="swept sine")
            ax_ph.semilogx(frf.freq_hz, _faded(ref_phase, coh, coherence_threshold), color="C0", lw=1.3)
            if coh is not None:
                ax_coh.semilogx(frf.freq_hz, coh, color="C0", lw=1.0)
            good = np.isfinite(_faded(ref_phase, coh, coherence_threshold))
            if np.any(good) and not np.all(good):  # keep incoherent phase from squashing the axis
                lo, hi = ref_phase[good].min(), ref_phase[good].max()
                pad = max(20.0, 0.08 * (hi - lo))
                ax_ph.set_ylim(lo - pad, hi + pad)
        if reference is not None and ch in reference.channels:
            ph = reference.phase_deg(ch)
            if ref_phase is not None:
                lo, hi = frf.freq_hz[np.isfinite(_faded(ref_phase, frf.coherence(ch), coherence_threshold))][[0, -1]]
                near = (reference.freq_hz >= lo) & (reference.freq_hz <= hi)
                gap = ph[near] - np.interp(reference.freq_hz[near], frf.freq_hz, ref_phase)
                ph = ph - 360.0 * np.round(np.median(gap) / 360.0) if gap.size else ph
            ax_mag.semilogx(reference.freq_hz, reference.magnitude_db(ch), "k--", lw=0.9, label=reference_label)
            ax_ph.semilogx(reference.freq_hz, ph, "k--", lw=0.9)
        if stepped is not None and ch in stepped.channels:
            ph = stepped.phase_deg(ch)
            if ref_phase is not None:
                ph = _align_phase(ph, stepped.freq_hz, ref_phase, frf.freq_hz)
            ax_mag.semilogx(stepped.freq_hz, stepped.magnitude_db(ch), "o", color="C3", ms=4.5, mfc="none", label="stepped sine")
            ax_ph.semilogx(stepped.freq_hz, ph, "o", color="C3", ms=4.5, mfc="none")
            coh = stepped.coherence(ch)
            if coh is not None:
                ax_coh.semilogx(stepped.freq_hz, coh, "o", color="C3", ms=3.5, mfc="none")
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
