"""A robustness study's figures. Plotting only: the numbers come from :mod:`samii.robust.study`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from samii.robust.sampling import DELAY_SAMPLES, PlantDraws
from samii.robust.study import StudySummary
from samii.robust.task import SampleResult
from samii.sim.param_units import unit as param_unit
from samii.viz.figures import pyplot, save_figure

__all__ = ["plot_histograms", "plot_influence", "FIGURES"]

FIGURES = ("histograms.png", "influence.png")


def _percentiles(ax, percentiles, fmt: str, unit: str = "") -> None:
    """Dotted lines at the percentiles, each labelled at its own height (close percentiles never overprint),
    and their values in the legend."""
    if not percentiles:
        return
    top = ax.get_ylim()[1]
    ax.set_ylim(0, 1.3 * top)  # headroom for the labels, above the bars
    label = f"percentiles {' / '.join(str(p) for p in percentiles)} %: " + " / ".join(f"{v:{fmt}}" for v in percentiles.values()) + unit
    for i, (p, v) in enumerate(percentiles.items()):
        ax.axvline(v, color="0.3", ls=":", lw=1, label=label if i == 0 else None)
        ax.text(v, top * (1.27 - 0.09 * i), f" {p}%", fontsize=7, va="top")


def plot_histograms(results: list[SampleResult], summary: StudySummary, title: str, path: Path) -> None:
    from matplotlib.ticker import MaxNLocator  # (lazy: imports matplotlib, only when called)

    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.3))
    for a in (a1, a2):
        a.yaxis.set_major_locator(MaxNLocator(integer=True))
    z_st = [r.zeta for r in results if r.stable and r.zeta is not None]
    z_un = [r.zeta for r in results if not r.stable and r.zeta is not None]
    allz = z_st + z_un
    bins = np.linspace(min(allz), max(allz), 25) if allz and min(allz) < max(allz) else 10
    if z_st:
        a1.hist(z_st, bins=bins, color="tab:green", alpha=0.8, label=f"stable ({len(z_st)})")
    if z_un:
        a1.hist(z_un, bins=bins, color="tab:red", alpha=0.8, label=f"unstable ({len(z_un)})")
    if allz and min(allz) <= 0.0:  # the stability boundary, drawn when a sample reaches it (else it squeezes the histogram)
        a1.axvline(0.0, color="k", lw=0.8, label="zeta = 0: stability boundary")
    _percentiles(a1, summary.zeta_percentiles, ".3g")
    a1.set_xlabel("closed-loop damping ratio of the least-damped mode (negative: growing)")
    a1.set_ylabel("samples")
    a1.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
    settle = [r.base_settle_s for r in results if r.stable and r.base_settle_s is not None]
    if settle:
        a2.hist(settle, bins=20, color="tab:blue", alpha=0.8)
        _percentiles(a2, summary.settle_percentiles, ".3g", " s")
        a2.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False)
    a2.set_xlabel("base settling time [s] (stable samples)")
    a2.set_ylabel("samples")
    lo, hi = summary.p_unstable_ci95
    fig.suptitle(f"{title}: P(unstable) = {summary.n_unstable}/{summary.n} = {summary.p_unstable:.3g} (95 % CI {lo:.3g}-{hi:.3g})", fontsize=10)
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def plot_influence(draws: PlantDraws, results: list[SampleResult], summary: StudySummary, path: Path, top: int = 3) -> None:
    """Closed-loop damping against the most influential parameters (in % from nominal), unstable samples in red."""
    plt = pyplot()
    names = [d["name"] for d in summary.influence[:top]] or list(draws.names[:top])
    fig, axes = plt.subplots(1, len(names), figsize=(4.0 * len(names), 3.6), squeeze=False, sharey=True)
    for a, name in zip(axes[0], names):
        j = draws.names.index(name)
        unit = "controller samples" if name == DELAY_SAMPLES else param_unit(name)
        scale, shown = (1e3, "ms") if unit == "s" else (1.0, unit or "-")  # a delay about 0 reads in ms
        rho = next((d["spearman"] for d in summary.influence if d["name"] == name), None)
        for stable, color, label in ((True, "tab:green", "stable"), (False, "tab:red", "unstable")):
            rs = [r for r in results if r.stable == stable and r.zeta is not None]
            if not rs:
                continue
            raw = draws.values[[r.index for r in rs], j]
            x = 100.0 * (raw / draws.nominal[j] - 1.0) if draws.nominal[j] else raw * scale
            a.scatter(x, [r.zeta for r in rs], s=12, color=color, alpha=0.8, label=label)
        a.axhline(0.0, color="k", lw=0.8)
        a.set_xlabel(f"{name} [% from nominal]" if draws.nominal[j] else f"{name} [{shown}]")
        a.set_title(f"Spearman rho {rho:+.2f}" if rho is not None else "", fontsize=9)
        a.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("closed-loop damping ratio")
    axes[0][0].legend(fontsize=8)
    fig.suptitle("stability against the most influential parameters", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
