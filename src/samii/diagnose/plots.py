"""Figures of a diagnosis: the residual with its noise band, and data, baseline and augmented model overlaid.

Compute lives in :mod:`samii.diagnose.diagnosis`; these functions only draw.
"""

from __future__ import annotations

import numpy as np

from samii.diagnose.diagnosis import Diagnosis
from samii.diagnose.model import Dataset
from samii.diagnose.nonlinear import MATERIAL, predicted_ratio
from samii.identify.cost import DB_PER_NEPER, DEG_PER_RAD
from samii.identify.lack_of_fit import is_stepped_sine
from samii.measure.frf_variance import MAX_VAR
from samii.viz.figures import pyplot, save_figure

__all__ = ["residual_figure", "bode_figure", "harmonic_figure", "simulator_figure"]

_DB, _DEG = DB_PER_NEPER, DEG_PER_RAD
_NAMES = {"act": "θ/v", "base": "ẍ/θ", "total": "ẍ/v"}
_UNITS = {"act": "rad/V", "base": "(m/s²)/rad", "total": "(m/s²)/V"}


def _finish(fig, title: str, path, fontsize: float | None = None):
    """Title and lay out ``fig``; saved to ``path`` and closed when a path is given."""
    fig.suptitle(title, fontsize=fontsize)
    # laid out as it is drawn (the same layout as tight_layout(), without a second pass over every tick label first:
    # the residual figure's six log axes took 1.5 s to save, 1.0 s so)
    fig.set_layout_engine("tight")
    if path is not None:
        save_figure(fig, path)
    return fig


def _unusable(residuals, ch: str) -> bool:
    """No file has a usable point in channel ``ch`` (``residuals``: per file, channel -> (residual, NaN where unusable;
    variance), :meth:`Diagnosis.residuals`)."""
    return not any(np.isfinite(r[ch][0]).any() for r in residuals if ch in r)


def _say_unusable(axes, y: float = 0.5) -> None:
    """Write on each of ``axes``, at height ``y`` (axes fraction), that its channel has no usable point (an empty
    panel with no word reads as a bug)."""

    for ax in axes:
        ax.text(
            0.5,
            y,
            f"no usable data point: the error (noise and floor)\nis over {np.sqrt(MAX_VAR):.2g} at every point",
            transform=ax.transAxes,
            ha="center",
            va="center",
            fontsize=9,
            color="0.35",
        )


def _near(phase: np.ndarray, ref) -> np.ndarray:
    """``phase`` [rad] shifted by the whole turns that bring it nearest ``ref`` (a phase or phases)."""
    return phase + 2 * np.pi * np.round((ref - phase) / (2 * np.pi))


def _label(d: Diagnosis, i: int) -> str:
    src = d.measured[i].source
    return src if len(src) <= 40 else "…" + src[-39:]


def residual_figure(d: Diagnosis, path=None):
    """Residual data/model of θ/v, ẍ/θ and ẍ/v, its magnitude in dB and its phase in degrees, before and after, with ±2σ of the data's noise (and
    systematic floor); unexplained bands in red, bands where the records differ in orange."""
    plt = pyplot()

    before, after = d.residuals("before"), d.residuals("after")
    same = not d.effects and d.raw_measured is None  # nothing found: the residual before is the residual after
    chans = [c for c in ("act", "base", "total") if any(c in r for r in after)]
    fig, axes = plt.subplots(2, len(chans), figsize=(5.5 * len(chans), 6.5), sharex=True, squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for col, ch in enumerate(chans):
        ax_m, ax_p = axes[0, col], axes[1, col]
        for i, ds in enumerate(d.datasets):
            if ch not in after[i]:
                continue
            f = ds.freq_hz
            eb, _ = before[i][ch]
            ea, var = after[i][ch]
            sig = np.sqrt(var / 2.0)
            c = colors[i % len(colors)]
            tag = f" ({_label(d, i)})" if len(d.datasets) > 1 else ""
            # a stepped sine's dwells as points (the lines between them are no data), as samii measure and frf draw them
            mk = {"marker": "o", "ms": 3} if is_stepped_sine(d.measured[i].frf.metadata) else {}
            if ds.known_noise:  # else the weights are a placeholder, not the data's noise
                what = "noise and floor" if ds.floor_var is not None else "noise"  # (the floor is part of each point's error)
                ax_m.fill_between(f, -2 * _DB * sig, 2 * _DB * sig, color=c, alpha=0.15, lw=0, label=f"±2σ {what}{tag}")
                ax_p.fill_between(f, -2 * _DEG * sig, 2 * _DEG * sig, color=c, alpha=0.15, lw=0)
            nl = d.raw_measured is not None
            if same:  # nothing found: one residual, no "with the effects" to tell from it
                ax_m.plot(f, _DB * ea.real, color=c, lw=1.0, label=f"against the baseline{tag}", **mk)
                ax_p.plot(f, _DEG * ea.imag, color=c, lw=1.0, **mk)
                continue
            ax_m.plot(f, _DB * eb.real, color="0.55", lw=0.8, label=f"baseline{' (data as measured)' if nl else ''}{tag}", **mk)
            ax_p.plot(f, _DEG * eb.imag, color="0.55", lw=0.8, **mk)
            ax_m.plot(
                f,
                _DB * ea.real,
                color=c,
                lw=1.0,
                label=f"with the effects{' (and the nonlinearity divided out)' if nl and ch != 'base' else ''}{tag}",
                **mk,
            )
            ax_p.plot(f, _DEG * ea.imag, color=c, lw=1.0, **mk)
        for b in d.unexplained:
            if b.channel == ch:
                for ax in (ax_m, ax_p):
                    ax.axvspan(b.lo_hz, b.hi_hz, color="tab:red" if b.why == "residual" else "tab:orange", alpha=0.12, lw=0)
        eb_, ea_ = d.error_before.get(ch), d.error_after.get(ch)
        title = f"{_NAMES[ch]}: residual data/model (magnitude in dB, phase in deg)"
        if eb_ and ea_ and same:
            title += f"\nrms {ea_.rms_db:.2g} dB, {ea_.rms_deg:.2g}°" + (f", χ² {ea_.chi2:.3g}" if ea_.chi2 is not None else "")
        elif eb_ and ea_:
            title += f"\nrms {eb_.rms_db:.2g} → {ea_.rms_db:.2g} dB, {eb_.rms_deg:.2g} → {ea_.rms_deg:.2g}°"
            if eb_.chi2 is not None:
                title += f", χ² {eb_.chi2:.3g} → {ea_.chi2:.3g}"
        if _unusable(after, ch):
            _say_unusable((ax_m, ax_p))
        ax_m.set_title(title, fontsize=10)
        ax_m.set_ylabel("magnitude residual [dB]")
        ax_p.set_ylabel("phase residual [deg]")
        ax_p.set_xlabel("frequency [Hz]")
        for ax in (ax_m, ax_p):
            ax.set_xscale("log")
            ax.axhline(0.0, color="k", lw=0.5)
            ax.grid(True, which="both", alpha=0.3)
            _clip(ax)
        if not _unusable(after, ch):
            ax_m.legend(fontsize=8, loc="best")
    found = ", ".join(f"{e.category}/{e.kind}" + (" (expected)" if e.expected else "") for e in d.effects) or "none"
    unattributed = d.simulator is not None and bool(d.simulator.unattributed)
    title = (
        f"Diagnosis: effects found: {found}"
        if d.effects
        else "Diagnosis: no effect attributed (what was found cannot be told from images of what the simulator lacks)"
        if unattributed
        else "Diagnosis: no effect found"
    )
    kinds = {b.why for b in d.unexplained}
    keys = (["red: unexplained"] if "residual" in kinds else []) + (["orange: the records differ (the rig changed)"] if kinds - {"residual"} else [])
    return _finish(fig, title + "".join(f"; {k}" for k in keys), path, fontsize=11)


def _clip(ax) -> None:
    """Keep a few wild noise points (ẍ at 0.1 Hz) from flattening everything else: limits at the 1-99 % of what is drawn, widened."""
    ys = np.concatenate([ln.get_ydata()[np.isfinite(ln.get_ydata())] for ln in ax.get_lines() if len(ln.get_ydata()) > 2] or [np.zeros(1)])
    if ys.size:
        lo, hi = np.percentile(ys, [1, 99])
        pad = 0.3 * (hi - lo) + 1e-3
        ax.set_ylim(lo - pad, hi + pad)


def _phase_over(f: np.ndarray, h: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The phase [rad] of ``h`` unwrapped over ``lo``..``hi`` Hz (the data's usable points), NaN outside: unwrapped
    through a band where the response is under the estimator's own error (a simulator's xdd/v below 1 Hz, 40 dB
    down) the phase walks by whole turns, and the curve where it can be compared went to -3000 deg."""
    out = np.full(f.size, np.nan)
    inside = (f >= lo) & (f <= hi)
    out[inside] = np.unwrap(np.angle(h[inside]))
    return out


def _before_after(
    ax_m, ax_p, f_before, before, f_after, after, ph_after, color, before_label: str, after_label: str, band: tuple[float, float] = (0.0, np.inf)
) -> None:
    """A model before (dashed grey) and after (solid ``color``) on a magnitude and a phase axis; the before's phase
    (over ``band``, as ``ph_after``'s) shifted by whole turns to start where the after's unwrapped phase ``ph_after`` does."""
    ph_before = _phase_over(f_before, before, *band)
    a, b = np.flatnonzero(np.isfinite(ph_after)), np.flatnonzero(np.isfinite(ph_before))
    if a.size and b.size:
        ph_before = ph_before + (_near(ph_before[b[0]], np.interp(f_before[b[0]], f_after[a], ph_after[a])) - ph_before[b[0]])
    ax_m.plot(f_before, _DB * np.log(np.abs(before)), "--", color="0.35", lw=1.0, label=before_label)
    ax_p.plot(f_before, _DEG * ph_before, "--", color="0.35", lw=1.0)
    ax_m.plot(f_after, _DB * np.log(np.abs(after)), "-", color=color, lw=1.2, label=after_label)
    ax_p.plot(f_after, _DEG * ph_after, "-", color=color, lw=1.2)


def _label_bode(axes, chans) -> None:
    """Titles (channel and unit), axis labels, log frequency and a legend on a 2 x channels Bode grid."""
    for col, ch in enumerate(chans):
        axes[0, col].set_title(f"{_NAMES[ch]} [{_UNITS[ch]}]", fontsize=10)
        axes[0, col].set_ylabel("magnitude [dB]")
        axes[1, col].set_ylabel("phase [deg]")
        axes[1, col].set_xlabel("frequency [Hz]")
    for ax in axes.ravel():
        ax.set_xscale("log")
        ax.grid(True, which="both", alpha=0.3)
    # the legend where every kind of curve is drawn (a first channel with no usable point has no data points)
    top = max(axes[0], key=lambda ax: len(ax.get_legend_handles_labels()[0]))
    top.legend(fontsize=8, loc="best")


def bode_figure(d: Diagnosis, path=None):
    """Magnitude and phase of θ/v, ẍ/θ and ẍ/v: data (points, where usable), baseline (dashed) and the augmented model (solid), every file."""
    plt = pyplot()

    residuals = d.residuals("after")
    same = not d.effects and d.raw_measured is None  # nothing found: the augmented model is the baseline
    chans = [c for c in ("act", "base", "total") if any(c in r for r in residuals)]
    fig, axes = plt.subplots(2, len(chans), figsize=(5.5 * len(chans), 6.5), sharex=True, squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (m, ds) in enumerate(zip(d.measured, d.datasets)):
        c = colors[i % len(colors)]
        f = ds.freq_hz
        fm = np.geomspace(f[0], f[-1], 800)
        mb, ma = d.model(i, fm, "before"), d.model(i, fm, "after")
        full = residuals[i]
        tag = f" ({_label(d, i)})" if len(d.datasets) > 1 else ""
        for col, ch in enumerate(chans):
            if ch not in full:
                continue
            e, _ = full[ch]
            ok = np.isfinite(e)
            h = m.frf.response(ch) if ch in m.frf.channels else (m.frf.total / m.frf.act if ch == "base" else m.frf.act * m.frf.base)
            ref = ma[ch]
            # against the simulator the model holds its re-measurement's correction, which under the data's usable band
            # is the estimator's own error (xdd/v 40 dB down): its phase is drawn over the usable band only
            band = (float(f[ok].min()), float(f[ok].max())) if d.simulator is not None and ok.any() else (0.0, np.inf)
            ph_model = _phase_over(fm, ref, *band)
            inside = np.isfinite(ph_model)
            ph_data = _near(np.angle(h[ok]), np.interp(f[ok], fm[inside], ph_model[inside])) if inside.any() else np.angle(h[ok])
            ax_m, ax_p = axes[0, col], axes[1, col]
            if d.raw_measured is not None and ch != "base":  # the data as measured, before the nonlinearity was divided out
                raw = d.raw_measured[i].frf.response(ch)[ok]
                ph_raw = _near(np.angle(raw), ph_data)
                ax_m.plot(f[ok], _DB * np.log(np.abs(raw)), ".", ms=2.5, color="0.6", label=f"data as measured{tag}")
                ax_p.plot(f[ok], _DEG * ph_raw, ".", ms=2.5, color="0.6")
            divided = " (nonlinearity divided out)" if d.raw_measured is not None and ch != "base" else ""
            if ok.any():  # (no legend entry for points that are not there)
                ax_m.plot(f[ok], _DB * np.log(np.abs(h[ok])), ".", ms=2.5, color=c, alpha=0.6, label=f"data{divided}{tag}")
                ax_p.plot(f[ok], _DEG * ph_data, ".", ms=2.5, color=c, alpha=0.6)
            if same:  # nothing found: the model is the baseline, one curve
                ax_m.plot(fm, _DB * np.log(np.abs(ref)), "-", color=c, lw=1.2, label=f"baseline (no effect found){tag}")
                ax_p.plot(fm, _DEG * ph_model, "-", color=c, lw=1.2)
            else:
                _before_after(ax_m, ax_p, fm, mb[ch], fm, ref, ph_model, c, f"baseline{tag}", f"with the effects{tag}", band)
    for col, ch in enumerate(chans):
        if _unusable(residuals, ch):
            _say_unusable(axes[:, col], y=0.12)
    _label_bode(axes, chans)
    title = "Data and the baseline (no effect found)" if same else "Data, baseline and the model with the effects found"
    return _finish(fig, title, path, fontsize=11)


def harmonic_figure(d: Diagnosis, path=None):
    """The sweep's 2nd and 3rd harmonics referred to the valve command, relative to its fundamental, per segment of
    every time-series file, with twice their noise and the 1 % level below which none is claimed; significant
    segments filled; the law found (its describing function's c3/c1, an asymmetry's c2/c1) as a line."""
    plt = pyplot()
    import matplotlib.ticker  # (lazy: imports matplotlib, only when called)

    hs = list(d.harmonics)
    laws = list(d.nonlinear)
    fig, axes = plt.subplots(1, max(len(hs), 1), figsize=(6.0 * max(len(hs), 1), 4.2), squeeze=False)
    if not hs:
        ax = axes[0, 0]
        ax.text(
            0.5, 0.5, "no time series with records:\nno harmonic test (it needs the records and r)", ha="center", va="center", transform=ax.transAxes
        )
        ax.set_axis_off()
    colors = {2: "tab:blue", 3: "tab:red"}
    for ax, h in zip(axes[0], hs):
        if not any(np.isfinite(h.log10_p[k]).any() for k in h.ratio):
            src = h.source if len(h.source) <= 40 else "…" + h.source[-39:]
            ax.text(
                0.5,
                0.5,
                "no segment could be tested\n(the fundamental or the noise too small in every one)",
                ha="center",
                va="center",
                transform=ax.transAxes,
            )
            ax.set_title(src, fontsize=9)
            ax.set_axis_off()
            continue
        for k in sorted(h.ratio):
            tested = np.isfinite(h.log10_p[k])
            if not tested.any():
                continue
            f, r, sd = h.freq_hz[tested], np.abs(h.ratio[k][tested]), h.ratio_sd[k][tested]
            sig = h.significant(k)[tested]
            order = np.argsort(f)
            # a log axis takes positive values only (an excess over a reference can be exactly 0, a noise-free sd too)
            pos = sd[order] > 0
            ax.loglog(f[order][pos], 100 * 2 * np.sqrt(2) * sd[order][pos], ":", color=colors[k], lw=1, label=f"{k}× noise (2σ)")
            plain, marked = ~sig & (r > 0), sig & (r > 0)
            ax.loglog(f[plain], 100 * r[plain], "o", mfc="none", color=colors[k], ms=5, label=f"{k}× {'excess' if h.reference else 'harmonic'}")
            if marked.any():
                ax.loglog(f[marked], 100 * r[marked], "o", color=colors[k], ms=6, label=f"{k}× significant")
            for finding in laws:
                if h.source not in {x.source for x in finding.harmonics}:
                    continue
                pred = predicted_ratio(finding, h, k)
                if pred is not None and np.any(np.abs(pred[tested]) > 0):
                    ax.loglog(
                        f[order],
                        100 * np.abs(pred[tested][order]),
                        "-",
                        color=colors[k],
                        lw=1.2,
                        label=f"{k}× the {finding.kind.replace('_', ' ')} found",
                    )
        ax.axhline(100 * MATERIAL, color="k", lw=0.8, ls="--", label=f"{100 * MATERIAL:g} % (claimed above)")
        ax.set_xlabel("sweep frequency (fundamental) [Hz]")
        ax.set_ylabel("harmonic excess / fundamental [%]" if h.reference else "harmonic / fundamental at the valve command [%]")
        ax.xaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.yaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))  # (not 2x10^0 under a decade)
        ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        src = h.source if len(h.source) <= 40 else "…" + h.source[-39:]
        ax.set_title(f"{src}: {h.n_significant} significant segment(s)", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    refs = sorted({h.reference for h in hs if h.reference})
    title = (
        f"Harmonics of the sweep beyond {refs[0]}\n(measured like the file, scaled to its command; at the valve command)"
        if refs
        else "Harmonics of the sweep (a linear system makes none)"
    )
    return _finish(fig, title, path)


def simulator_figure(d: Diagnosis, path=None):
    """``--baseline sim``: each file's data (points) beside the simulator measured like it, calibrated
    without the effects (dashed) and with them carried and recalibrated (solid); θ/v and ẍ/v, the
    channels the valve's command drives. None when the diagnosis has no simulator block."""
    plt = pyplot()

    rep = d.simulator
    if rep is None:
        return None
    measured = d.raw_measured if d.raw_measured is not None else d.measured
    chans = [c for c in ("act", "total") if any(c in m.frf.channels for m in measured)]

    usable = [Dataset.from_measured(m, channels=chans) for m in measured]
    fig, axes = plt.subplots(2, len(chans), figsize=(6.0 * len(chans), 6.5), sharex=True, squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, m in enumerate(measured):
        c = colors[i % len(colors)]
        tag = f" ({_label(d, i)})" if len(measured) > 1 else ""
        before, after = rep.remeasured_before[i], rep.remeasured_after[i]
        for col, ch in enumerate(chans):
            if ch not in m.frf.channels:
                continue
            ax_m, ax_p = axes[0, col], axes[1, col]
            h = m.frf.response(ch)
            ok = usable[i].keep[ch] if ch in usable[i].keep else np.ones(h.size, bool)
            f_ok = m.frf.freq_hz[ok]
            band = (float(f_ok.min()), float(f_ok.max())) if f_ok.size else (0.0, np.inf)
            ph_after = _phase_over(after.freq_hz, after.response(ch), *band)
            inside = np.isfinite(ph_after)
            ph_data = _near(np.angle(h[ok]), np.interp(f_ok, after.freq_hz[inside], ph_after[inside])) if inside.any() else np.angle(h[ok])
            if ok.any():  # (no legend entry for points that are not there)
                ax_m.plot(m.frf.freq_hz[ok], _DB * np.log(np.abs(h[ok])), ".", ms=2.5, color=c, alpha=0.5, label=f"data{tag}")
                ax_p.plot(m.frf.freq_hz[ok], _DEG * ph_data, ".", ms=2.5, color=c, alpha=0.5)
            if rep.carried:
                _before_after(
                    ax_m,
                    ax_p,
                    before.freq_hz,
                    before.response(ch),
                    after.freq_hz,
                    after.response(ch),
                    ph_after,
                    c,
                    f"simulator, calibrated{tag}",
                    f"simulator with the effects{tag}",
                    band,
                )
            else:  # nothing carried: one simulator, no "after" to tell from it
                ax_m.plot(after.freq_hz, _DB * np.log(np.abs(after.response(ch))), "-", color=c, lw=1.2, label=f"simulator, calibrated{tag}")
                ax_p.plot(after.freq_hz, _DEG * ph_after, "-", color=c, lw=1.2)
    for col, ch in enumerate(chans):
        if not any(ch in u.keep and u.keep[ch].any() for u in usable):
            _say_unusable(axes[:, col], y=0.12)
    _label_bode(axes, chans)
    head = (
        f"The simulator measured like the data: before and after carrying in {', '.join(rep.carried)}"
        if rep.carried
        else "The simulator measured like the data (calibrated; the diagnosis found nothing to carry into it)"
    )
    return _finish(fig, f"{head}\n(points: those the diagnosis uses, where the data's noise is small enough)", path, fontsize=11)
