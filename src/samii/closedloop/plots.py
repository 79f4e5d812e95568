"""Figures of a closed-loop run (the notebook's Figures 11.1-11.5 as simulations). Plotting only: no computation."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from samii.closedloop.scenario import ClosedLoopResult
from samii.viz.figures import panels, pyplot, save_figure

__all__ = ["plot_theta", "plot_base", "plot_linear", "FIGURES"]

FIGURES = ("theta.png", "base_accel.png", "linear_vs_nonlinear.png")


def _save(fig, path: Path) -> None:
    fig.tight_layout()
    save_figure(fig, path)


def _mark_events(ax, r: ClosedLoopResult) -> None:
    s = r.signals
    if s.switch_on_s is not None:
        ax.axvline(s.switch_on_s, color="k", ls=":", lw=1, label=f"controller on (t = {s.switch_on_s:g} s)")
    if s.diverged_at_s is not None:
        ax.axvline(s.diverged_at_s, color="r", ls="--", lw=1, label=f"diverged (t = {s.diverged_at_s:.3g} s)")


def _too_short(r: ClosedLoopResult) -> bool:
    """The run (cut at its divergence) spans under 2 % of the comparison's time axis: a line would be invisible."""
    s, c = r.signals, r.comparison
    if c is None or s.t.size < 2 or c.t.size < 2:
        return False
    return (s.t[-1] - s.t[0]) < 0.02 * (c.t[-1] - c.t[0])


def _figure_with_zoom():
    """One panel and, beside it, a narrow one for the first moments of a run too short to see in it."""
    plt = pyplot()

    fig, (ax, zoom) = plt.subplots(1, 2, figsize=(11.0, 3.6), gridspec_kw={"width_ratios": [3, 1.2]})
    return fig, ax, zoom


def _axes(r: ClosedLoopResult):
    """``(fig, ax, zoom)``: ``zoom`` is None unless the run is too short to see (:func:`_too_short`)."""
    if _too_short(r):
        return _figure_with_zoom()
    fig, (ax,) = panels(1, 3.6)
    return fig, ax, None


def _zoom(zoom, r: ClosedLoopResult, curves: list[tuple[np.ndarray, np.ndarray, dict]], ylabel: str) -> None:
    """The first moments of a run too short for the main panel (a controller that diverged at once): each
    curve ``(t, y, style)`` over the run's own span and as much again, so the reader sees what it did
    before it diverged."""
    s = r.signals
    span = max(float(s.t[-1] - s.t[0]), 1e-3)
    lo, hi = s.t[0] - 0.1 * span, s.t[-1] + 1.0 * span
    for t, y, style in curves:
        keep = (t >= lo) & (t <= hi)
        zoom.plot(t[keep], y[keep], **style)
    if s.diverged_at_s is not None:
        zoom.axvline(s.diverged_at_s, color="r", ls="--", lw=1)
    zoom.set_xlim(lo, hi)
    zoom.set_title(f"its {1e3 * (s.t[-1] - s.t[0]):.3g} ms before it diverged", fontsize=9)
    zoom.set_xlabel("time [s]")
    zoom.set_ylabel(ylabel)
    zoom.grid(True, alpha=0.3)


def _title(r: ClosedLoopResult) -> str:
    state = "stable" if r.stable else f"UNSTABLE ({r.instability()})"
    return textwrap.fill(f"{r.controller}, {r.scenario.name} scenario: {state}", width=100)  # a runaway's reason is long


_GREY = {"color": "tab:gray", "lw": 2.2, "alpha": 0.6}


def plot_theta(r: ClosedLoopResult, path: Path) -> None:
    """Desired vs actual joint-2 angle (Figures 11.1-11.3), with the servo loop alone for comparison; a run
    that diverged at once gets a panel of its own first moments beside."""
    fig, ax, zoom = _axes(r)
    s, c = r.signals, r.comparison
    ref_t, ref = (c.t, c.theta_ref) if zoom is not None else (s.t, s.theta_ref)  # a diverged run's reference: the whole test's
    ax.plot(ref_t, np.degrees(ref), color="k", lw=1.2, ls="--", label="desired theta_ref")
    if c is not None:
        ax.plot(c.t, np.degrees(c.theta), **_GREY, label="actual, servo loop alone")
    mine = {"color": "tab:blue", "lw": 1.2, "marker": "." if zoom is not None else None, "ms": 3}
    ax.plot(s.t, np.degrees(s.theta), **mine, label=f"actual, {r.controller}" + (" (diverged at once: right)" if zoom is not None else ""))
    if zoom is not None:
        _zoom(
            zoom,
            r,
            [(c.t, np.degrees(c.theta), _GREY), (ref_t, np.degrees(ref), {"color": "k", "lw": 1.2, "ls": "--"}), (s.t, np.degrees(s.theta), mine)],
            "joint-2 angle [deg]",
        )
    _mark_events(ax, r)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("joint-2 angle from the nominal pose [deg]")
    ax.set_title(_title(r), fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    _save(fig, path)


def plot_base(r: ClosedLoopResult, path: Path) -> None:
    """Base acceleration with and without the controller (Figures 11.4-11.5); a run that diverged at once
    gets a panel of its own first moments beside."""
    accel_rest = r.accel_rest_m_s2
    fig, ax, zoom = _axes(r)
    s, c = r.signals, r.comparison
    if c is not None:
        label = "free decay (never switched on)" if r.scenario.name == "loper" else "servo loop alone"
        ax.plot(c.t, c.accel - accel_rest, **_GREY, label=label)
    mine = {"color": "tab:red", "lw": 0.8, "marker": "." if zoom is not None else None, "ms": 3}
    ax.plot(s.t, s.accel - accel_rest, **mine, label=r.controller + (" (diverged at once: right)" if zoom is not None else ""))
    if zoom is not None:
        _zoom(zoom, r, [(c.t, c.accel - accel_rest, _GREY), (s.t, s.accel - accel_rest, mine)], "base acceleration [m/s²]")
    _mark_events(ax, r)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("base acceleration [m/s²]")
    b = r.base
    extra = f"residual rms {b.residual_rms_m_s2:.3g} m/s²" if b.residual_rms_m_s2 is not None else ""
    ax.set_title(f"{_title(r)}\n{extra}", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    _save(fig, path)


def plot_linear(r: ClosedLoopResult, path: Path) -> None:
    """The nonlinear run against the linear prediction, theta and base acceleration."""
    theta_rest, accel_rest = r.theta_rest_rad, r.accel_rest_m_s2
    fig, (a1, a2) = panels(2, 3.0)
    s = r.signals
    a1.plot(s.t, np.degrees(s.theta - theta_rest), color="tab:blue", lw=1.0, label="nonlinear simulator")
    a2.plot(s.t, s.accel - accel_rest, color="tab:red", lw=0.8, label="nonlinear simulator")
    if r.linear is not None:
        lin = r.linear
        a1.plot(lin.t + s.t[0], np.degrees(lin.theta), color="k", lw=0.8, ls="--", label="linear prediction")
        a2.plot(lin.t + s.t[0], lin.accel, color="k", lw=0.6, ls="--", label="linear prediction")
        e = r.rms_error_pct
        fmt = lambda x: "n/a" if x is None else f"{x:.3g} %"  # noqa: E731
        a1.set_title(f"{_title(r)}\nrms(nonlinear - linear)/rms(linear): theta {fmt(e['theta'])}, accel {fmt(e['accel'])}", fontsize=10)
    else:
        a1.set_title(f"{_title(r)}\nthe linear prediction is unstable: not drawn", fontsize=10)
    for ax in (a1, a2):
        _mark_events(ax, r)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    a1.set_ylabel("theta from rest [deg]")
    a2.set_ylabel("base acceleration [m/s²]")
    a2.set_xlabel("time [s]")
    _save(fig, path)
