"""Figures of a closed-loop run (the notebook's Figures 11.1-11.5 as simulations). Plotting only: no computation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from samii.closedloop.scenario import ClosedLoopResult

__all__ = ["plot_theta", "plot_base", "plot_linear", "FIGURES"]

FIGURES = ("theta.png", "base_accel.png", "linear_vs_nonlinear.png")


def _figure(rows: int = 1, height: float = 3.6):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(rows, 1, figsize=(9.0, height * rows), sharex=True, squeeze=False)
    return plt, fig, ax[:, 0]


def _save(plt, fig, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mark_events(ax, r: ClosedLoopResult) -> None:
    s = r.signals
    if s.switch_on_s is not None:
        ax.axvline(s.switch_on_s, color="k", ls=":", lw=1, label=f"controller on (t = {s.switch_on_s:g} s)")
    if s.diverged_at_s is not None:
        ax.axvline(s.diverged_at_s, color="r", ls="--", lw=1, label=f"diverged (t = {s.diverged_at_s:.3g} s)")


def _title(r: ClosedLoopResult) -> str:
    state = "stable" if r.stable else f"UNSTABLE ({r.instability()})"
    return f"{r.controller}, {r.scenario.name} scenario: {state}"


def plot_theta(r: ClosedLoopResult, path: Path) -> None:
    """Desired vs actual joint-2 angle (Figures 11.1-11.3), with the servo loop alone for comparison."""
    plt, fig, (ax,) = _figure()
    s = r.signals
    ax.plot(s.t, np.degrees(s.theta_ref), color="k", lw=1.2, ls="--", label="desired theta_ref")
    if r.comparison is not None:
        c = r.comparison
        ax.plot(c.t, np.degrees(c.theta), color="tab:gray", lw=2.2, alpha=0.6, label="actual, servo loop alone")
    ax.plot(s.t, np.degrees(s.theta), color="tab:blue", lw=1.2, label=f"actual, {r.controller}")
    _mark_events(ax, r)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("joint-2 angle from the nominal pose [deg]")
    ax.set_title(_title(r))
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    _save(plt, fig, path)


def plot_base(r: ClosedLoopResult, path: Path) -> None:
    """Base acceleration with and without the controller (Figures 11.4-11.5)."""
    accel_rest = r.accel_rest_m_s2
    plt, fig, (ax,) = _figure()
    s = r.signals
    if r.comparison is not None:
        c = r.comparison
        label = "free decay (never switched on)" if r.scenario.name == "loper" else "servo loop alone"
        ax.plot(c.t, c.accel - accel_rest, color="tab:gray", lw=2.2, alpha=0.6, label=label)
    ax.plot(s.t, s.accel - accel_rest, color="tab:red", lw=0.8, label=r.controller)
    _mark_events(ax, r)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("base acceleration [m/s^2]")
    b = r.base
    extra = f"residual rms {b.residual_rms_m_s2:.3g} m/s^2" if b.residual_rms_m_s2 is not None else ""
    ax.set_title(f"{_title(r)}\n{extra}", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    _save(plt, fig, path)


def plot_linear(r: ClosedLoopResult, path: Path) -> None:
    """The nonlinear run against the linear prediction, theta and base acceleration."""
    theta_rest, accel_rest = r.theta_rest_rad, r.accel_rest_m_s2
    plt, fig, (a1, a2) = _figure(2, 3.0)
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
    a2.set_ylabel("base acceleration [m/s^2]")
    a2.set_xlabel("time [s]")
    _save(plt, fig, path)
