"""The report's closed-loop figures: the notebook's Figures 11.1-11.5 as simulations, and the damping
controller in the same tests. Plotting only: each function takes closed-loop runs' time series (samii.timeseries.TimeSeries: t [s], theta and
theta_ref [rad], accel [m/s²]) and returns PNG bytes."""

from __future__ import annotations

import io

import numpy as np

from samii.timeseries import TimeSeries
from samii.viz.figures import panels, pyplot

__all__ = ["figure_ch11_step", "figure_ch11_loper", "figure_damping"]

_ALONE = dict(color="0.55", lw=2.0, alpha=0.7)
_DPI = 100


def _figure(rows: int, height: float = 2.9):
    fig, axes = panels(rows, height)
    return pyplot(), fig, axes


def _png(plt, fig, axes, t_end: float) -> bytes:
    for a in axes:
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8, loc="lower right" if "angle" in a.get_ylabel() else "upper right")
        a.set_xlim(0.0, t_end)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI)
    plt.close(fig)
    return buf.getvalue()


def _rest(tr: TimeSeries) -> float:
    """The base acceleration at rest (the first sample), removed so the traces show the vibration."""
    return float(tr.accel[0]) if tr.accel.size else 0.0


def _angle(ax, alone: TimeSeries, run: TimeSeries, labels: tuple[str, str], color: str) -> None:
    """Desired and actual joint-2 angle: the servo loop alone beside ``run``."""
    if alone.theta_ref is not None:  # (samii closedloop writes it; a time series without it shows no desired angle)
        ax.plot(alone.t, np.degrees(alone.theta_ref), "k--", lw=1, label="desired")
    ax.plot(alone.t, np.degrees(alone.theta), **_ALONE, label=labels[0])
    ax.plot(run.t, np.degrees(run.theta), color=color, lw=1.2, label=labels[1])
    ax.set_ylabel("joint-2 angle [deg]")


def _accel(ax, ref: TimeSeries, run: TimeSeries, labels: tuple[str, str], color: str, ylabel: str, switch_on_s: float | None = None) -> None:
    """The base acceleration of ``run`` beside a reference run (grey)."""
    ax.plot(ref.t, ref.accel - _rest(ref), **_ALONE, label=labels[0])
    ax.plot(run.t, run.accel - _rest(run), color=color, lw=0.9, label=labels[1])
    if switch_on_s is not None:
        ax.axvline(switch_on_s, color="k", ls=":", lw=1, label=f"switch-on, t = {switch_on_s:g} s")
    ax.set_ylabel(ylabel)


def figure_ch11_step(alone: TimeSeries, cancel: TimeSeries, *, t_end: float = 5.0) -> bytes:
    """Figures 11.1-11.4: desired vs actual joint-2 angle, and the base acceleration, with and without the
    pole-cancelling compensator (5 deg step)."""
    plt, fig, (a1, a2) = _figure(2)
    _angle(a1, alone, cancel, ("no vibration suppression (servo loop alone): Fig 11.1", "pole-cancelling compensator: Fig 11.2, 11.3"), "tab:blue")
    a1.set_title("Figures 11.1-11.4 as simulations: a 5 deg step of joint 2", fontsize=10)
    _accel(a2, alone, cancel, ("no vibration suppression", "pole-cancelling compensator: Fig 11.4"), "tab:red", "base acceleration [m/s²]")
    return _png(plt, fig, (a1, a2), t_end)


def figure_ch11_loper(free: TimeSeries, cancel: TimeSeries, switch_on_s: float, *, t_end: float = 10.0) -> bytes:
    """Figure 11.5: the Loper test: the arm moved by the servo loop alone, the compensator switched on after."""
    plt, fig, (a1,) = _figure(1, 3.2)
    _accel(
        a1,
        free,
        cancel,
        ("never switched on (free decay)", "pole-cancelling compensator switched on"),
        "tab:red",
        "base acceleration [m/s²]",
        switch_on_s,
    )
    a1.set_title("Figure 11.5 as a simulation: the Loper test with the pole-cancelling compensator", fontsize=10)
    return _png(plt, fig, (a1,), t_end)


def figure_damping(alone: TimeSeries, step: TimeSeries, loper: TimeSeries, switch_on_s: float, *, t_end: float = 10.0) -> bytes:
    """The damping controller in the same tests: the step (angle, base) and the Loper test, beside the servo loop alone."""
    plt, fig, (a1, a2, a3) = _figure(3, 2.6)
    _angle(a1, alone, step, ("servo loop alone", "damping controller"), "tab:green")
    a1.set_title("The damping controller (acceleration feedback designed on the fit): step, then the Loper test", fontsize=10)
    _accel(a2, alone, step, ("servo loop alone (step)", "damping controller (step)"), "tab:green", "base accel. [m/s²]")
    _accel(
        a3, alone, loper, ("never switched on (free decay)", "damping controller switched on (Loper)"), "tab:green", "base accel. [m/s²]", switch_on_s
    )
    return _png(plt, fig, (a1, a2, a3), t_end)
