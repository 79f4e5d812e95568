"""The notebook's closed-loop experiments (chapters 8 and 11) in the simulator, and the damping controller's method.

Usage::

    python experiments/closed_loop/run.py [--out experiments/closed_loop/out]

Writes ``out/``: ``results.json``, ``table.md`` and the figures ``ch8_kalman_mode3.png``,
``ch11_step.png`` (Figures 11.1-11.4 as simulations), ``ch11_loper.png`` (Figure 11.5),
``damping_methods.png``. About a minute of wall time. The README beside this script sets
each result beside the notebook's words.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np

warnings.filterwarnings("ignore", message="logm result may be inaccurate")

import control  # noqa: E402

from samii import notebook as nb  # noqa: E402
from samii.closedloop.card import build_card_model  # noqa: E402
from samii.closedloop.controllers import (  # noqa: E402
    NOTEBOOK_INPUT_SCALE,
    NOTEBOOK_UNITS_SI,
    SavedController,
    accel_unit_evidence,
    notebook_cancel,
    notebook_place,
)
from samii.closedloop.linear import linear_loop  # noqa: E402
from samii.closedloop.scenario import NoiseSpec, default_spec_factory, run_closed_loop, scenario  # noqa: E402
from samii.design import canonical as cc  # noqa: E402
from samii.design import placement as pl  # noqa: E402
from samii.measure.daq import SensorNoise  # noqa: E402
from samii.sim.model import load_model, load_spec  # noqa: E402


def _modes(r) -> list[list[float]]:
    return [[round(m.freq_hz, 3), round(m.zeta, 4)] for m in r.modes]


def _unstable(poles_s: np.ndarray) -> list[list[float]]:
    bad = poles_s[(poles_s.real > 0) & (poles_s.imag >= 0)]
    return [[round(float(b.real), 3), round(float(abs(b.imag) / (2 * np.pi)), 3)] for b in sorted(bad, key=lambda p: -p.real)]


def _linear_unstable(model, controller, replaces=True) -> list[list[float]]:
    spec, _ = load_spec()
    cm = build_card_model(spec, controller, replaces_servo=replaces, home_qpos=model.key_qpos[0], home_act=model.key_act[0])
    return _unstable(linear_loop(cm).poles_s())


def chapter8(model, factory, out: Path) -> dict:
    """The 2-mode placement design: with the placement observer, and with Kalman observers of several noise ratios."""
    ccf = cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)
    res: dict = {}
    # (a) the placement observer (eq 8.3, observer at twice the controller poles)
    c = notebook_place().controller
    robust = {}
    for f in (1.0, 1.01, 1.05):
        # the runnable controller (its last state is the previous command, which the observer uses for eq 1.4's
        # feedthrough D) on eq 1.4 with K1 scaled, in notebook units: y_k = C x_k + D v_(k-1)
        p = dict(nb.EQ1_4_OPTIMIZED)
        p["K1"] *= f
        sd = control.c2d(cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), p), 1e-3, "zoh")
        Ap, Bp, Cp, Dp = (np.asarray(x) for x in (sd.A, sd.B, sd.C, sd.D))
        n, nz = Ap.shape[0], c.A.shape[0]
        Phi = np.zeros((n + nz, n + nz))
        for col in range(n + nz):
            X = np.zeros(n + nz)
            X[col] = 1.0
            x, z = X[:n], X[n:]
            y = Cp @ x + Dp[:, 0] * z[-1]
            w = np.array([0.0, y[0], y[1]])
            v = float(c.C[0] @ z + c.D[0] @ w)
            Phi[:, col] = np.concatenate([Ap @ x + Bp[:, 0] * v, c.A @ z + c.B @ w])
        robust[f"K1 x {f:g}"] = round(float(np.max(np.abs(np.linalg.eigvals(Phi)))), 4)
    run = run_closed_loop(notebook_place(), scenario("step"), label="notebook-place", spec_factory=factory, comparison=False)
    res["placement_observer"] = {
        "controller_max_abs_z": round(float(np.max(np.abs(np.linalg.eigvals(c.A)))), 3),
        "closed_loop_max_abs_z_on_eq1_4_with_K1_scaled": robust,
        "simulator": {"stable": run.stable, "diverged_at_s": run.signals.diverged_at_s, "linear_unstable_poles": _unstable(run.linear_poles_s)[:4]},
    }
    # (b) Kalman observers: sweep the noise standard deviations (input [V], theta [deg], accel [ft/s^2])
    vals = (1e-2, 1e-1, 1.0)
    sweep = []
    for q, rt, ra in itertools.product(vals, vals, vals):
        dk = pl.design_placement(ccf, sample_time_s=1e-3, zeta=nb.EQ8_3_ZETA, observer="kalman", input_noise_std=q, measurement_noise_std=(rt, ra))
        ck = dk.controller(input_scale=dict(NOTEBOOK_INPUT_SCALE), model_units=NOTEBOOK_UNITS_SI)
        sweep.append({"input_V": q, "theta_deg": rt, "accel_ft_s2": ra, "unstable": _linear_unstable(model, ck)})
    res["kalman_sweep"] = sweep
    # (c) one of them in the nonlinear simulator: a fast observer that leans on theta
    q, rt, ra = 1.0, 1e-2, 1.0
    dk = pl.design_placement(ccf, sample_time_s=1e-3, zeta=nb.EQ8_3_ZETA, observer="kalman", input_noise_std=q, measurement_noise_std=(rt, ra))
    ck = SavedController(dk.controller(input_scale=dict(NOTEBOOK_INPUT_SCALE), model_units=NOTEBOOK_UNITS_SI), True)
    r = run_closed_loop(ck, scenario("step", duration_s=10.0), label="chapter 8, Kalman observer", spec_factory=factory)
    res["kalman_run"] = {"noise_std": [q, rt, ra], "stable": r.stable, "unstable_mode_hz": r.unstable_mode_hz, "growth_rate_1_s": r.growth_rate_1_s,
                         "linear_unstable_poles": _unstable(r.linear_poles_s), "notes": r.notes,
                         "valve_saturated_fraction": float(np.mean(np.abs(r.signals.v) >= 9.999))}  # fmt: skip
    _plot_ch8(r, out / "ch8_kalman_mode3.png")
    return res


def chapter11(factory, out: Path) -> dict:
    cancel = notebook_cancel()
    step = run_closed_loop(cancel, scenario("step"), label="notebook-cancel", spec_factory=factory)
    unity = run_closed_loop(None, scenario("step"), label="unity", spec_factory=factory)
    loper = run_closed_loop(cancel, scenario("loper"), label="notebook-cancel", spec_factory=factory)
    _plot_ch11_step(step, out / "ch11_step.png")
    _plot_ch11_loper(loper, out / "ch11_loper.png")
    return {
        "step": {"cancel": step.as_json(), "unity": unity.as_json()},
        "residual_rms_ratio_unity_over_cancel": unity.base.residual_rms_m_s2 / step.base.residual_rms_m_s2,
        "loper": loper.as_json(),
        "loper_decay_ratio": loper.base.decay_rate_1_s / loper.free_decay_rate_1_s,
    }


def damping_methods(model, factory, out: Path) -> dict:
    """Tuned acceleration feedback against 3-mode pole placement (placement and Kalman observers) on the same fit."""
    from samii.closedloop.damping import damping_from_simulation

    d = damping_from_simulation(model)
    fit = d.params
    ccf3 = cc.numeric_statespace(cc.derive_canonical_form(3, "accel"), fit)
    candidates = {"tuned acceleration feedback": d.controller}
    place = pl.design_placement(ccf3, sample_time_s=1e-3, zeta=1 / math.sqrt(2), observer="placement")
    candidates["3-mode placement, placement observer"] = SavedController(place.controller(model_units="SI"), True)
    kal = pl.design_placement(
        ccf3,
        sample_time_s=1e-3,
        zeta=1 / math.sqrt(2),
        observer="kalman",
        input_noise_std=0.1,
        measurement_noise_std=(SensorNoise.theta_rad, SensorNoise.accel_m_s2),  # the simulated sensors' noise
    )
    candidates["3-mode placement, Kalman observer"] = SavedController(kal.controller(model_units="SI"), True)
    free_step = run_closed_loop(None, scenario("step"), label="unity", spec_factory=factory, comparison=False)
    rows = {}
    runs = {}
    for name, sc in candidates.items():
        step = run_closed_loop(sc, scenario("step"), label=name, spec_factory=factory, comparison=False, delay_samples=1, noise=NoiseSpec(seed=1))
        loper = run_closed_loop(sc, scenario("loper"), label=name, spec_factory=factory, delay_samples=1, noise=NoiseSpec(seed=2))
        runs[name] = step
        m1 = [m for m in step.modes if abs(m.freq_hz - nb.BASE_MODES_HZ[0]) < 0.3]
        rows[name] = {
            "stable": bool(step.stable and loper.stable),
            "diverged_at_s": step.signals.diverged_at_s,
            "unstable_mode_hz": step.unstable_mode_hz,
            "mode1_zeta": m1[0].zeta if m1 else None,
            "loper_decay_ratio": (loper.base.decay_rate_1_s / loper.free_decay_rate_1_s) if loper.stable and loper.base.decay_rate_1_s else None,
            "settle_ratio": (free_step.base.settle_s / step.base.settle_s) if step.stable and step.base.settle_s else None,
            "modes": _modes(step),
        }
    rows["servo loop alone"] = {"stable": True, "mode1_zeta": [m.zeta for m in free_step.modes if abs(m.freq_hz - nb.BASE_MODES_HZ[0]) < 0.3][0],
                                "settle_s": free_step.base.settle_s, "modes": _modes(free_step)}  # fmt: skip
    _plot_methods(runs, free_step, out / "damping_methods.png")
    return {"fit": {k: float(v) for k, v in fit.items()}, "fit_summary": d.fit_summary, "gain_v_per_m_s2": d.gain_v_per_m_s2,
            "filter_hz": d.filter_hz, "design_modes": d.mode_table(), "methods": rows}  # fmt: skip


# ---- figures (plotting only) ----


def _fig(rows=1, h=3.4):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(rows, 1, figsize=(9, h * rows), squeeze=False)
    return plt, fig, ax[:, 0]


def _plot_ch8(r, path):
    plt, fig, (a1, a2) = _fig(2)
    s = r.signals
    a1.plot(s.t, s.accel - r.accel_rest_m_s2, lw=0.6, color="tab:red")
    a1.set_ylabel("base acceleration [m/s^2]")
    a1.set_title(f"chapter 8 (2-mode placement, Kalman observer) in the simulator: mode {r.unstable_mode_hz:.3g} Hz grows at "
                 f"{r.growth_rate_1_s:.3g} 1/s, then a limit cycle", fontsize=10)  # fmt: skip
    k = (s.t >= 4.0) & (s.t <= 4.4)
    a2.plot(s.t[k], s.accel[k] - r.accel_rest_m_s2, lw=1.0, color="tab:red")
    a2.set_ylabel("base acceleration [m/s^2]")
    a2.set_xlabel("time [s] (zoom)")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
    a1.set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_ch11_step(r, path):
    plt, fig, (a1, a2) = _fig(2)
    s, c = r.signals, r.comparison
    a1.plot(s.t, np.degrees(s.theta_ref), "k--", lw=1, label="desired")
    a1.plot(c.t, np.degrees(c.theta), color="tab:gray", lw=2, alpha=0.6, label="no vibration suppression (servo loop)")
    a1.plot(s.t, np.degrees(s.theta), color="tab:blue", lw=1.2, label="pole-cancelling compensator")
    a1.set_ylabel("joint-2 angle [deg]")
    a1.set_title("Figures 11.1-11.4 as simulations: a 5 deg step", fontsize=10)
    a2.plot(c.t, c.accel - r.accel_rest_m_s2, color="tab:gray", lw=1.5, alpha=0.7, label="no vibration suppression")
    a2.plot(s.t, s.accel - r.accel_rest_m_s2, color="tab:red", lw=0.8, label="pole-cancelling compensator")
    a2.set_ylabel("base acceleration [m/s^2]")
    a2.set_xlabel("time [s]")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_ch11_loper(r, path):
    plt, fig, (a1,) = _fig(1)
    s, c = r.signals, r.comparison
    a1.plot(c.t, c.accel - r.accel_rest_m_s2, color="tab:gray", lw=2, alpha=0.6, label="never switched on (free decay)")
    a1.plot(s.t, s.accel - r.accel_rest_m_s2, color="tab:red", lw=0.8, label="compensator switched on")
    a1.axvline(s.switch_on_s, color="k", ls=":", label="switch-on")
    a1.set_title(f"Figure 11.5 as a simulation (Loper test): decay {r.base.decay_rate_1_s:.3g} 1/s after switch-on, "
                 f"{r.free_decay_rate_1_s:.3g} 1/s free", fontsize=10)  # fmt: skip
    a1.set_ylabel("base acceleration [m/s^2]")
    a1.set_xlabel("time [s]")
    a1.grid(True, alpha=0.3)
    a1.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_methods(runs, free, path):
    plt, fig, axes = _fig(len(runs) + 1, 2.4)
    axes[0].plot(free.signals.t, free.signals.accel - free.accel_rest_m_s2, color="tab:gray", lw=0.8)
    axes[0].set_title("servo loop alone", fontsize=9)
    for a, (name, r) in zip(axes[1:], runs.items()):
        a.plot(r.signals.t, r.signals.accel - r.accel_rest_m_s2, color="tab:red", lw=0.8)
        state = "stable" if r.stable else ("DIVERGED" if r.signals.diverged_at_s is not None else "UNSTABLE")
        a.set_title(f"{name}: {state} (5 deg step, 1-sample delay, sensor noise)", fontsize=9)
    for a in axes:
        a.set_ylabel("xdd [m/s^2]")
        a.grid(True, alpha=0.3)
        a.set_xlim(0, 10)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("out"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    model = load_model()
    factory = default_spec_factory()
    ev = accel_unit_evidence(model)
    results = {
        "units": {
            "freq_hz": ev.freq_hz,
            "b_notebook": ev.b_notebook,
            "b_simulator_m_per_rad": ev.b_simulator,
            "notebook_accel_units_per_m_s2": ev.units_per_m_s2,
            "geometric_mean": ev.geometric_mean,
        },  # fmt: skip
        "chapter8": chapter8(model, factory, args.out),
        "chapter11": chapter11(factory, args.out),
        "damping": damping_methods(model, factory, args.out),
    }
    from samii.json_output import dumps

    (args.out / "results.json").write_text(dumps(results, indent=1) + "\n")
    m = results["damping"]["methods"]
    lines = [
        "| method | stable | unstable at [Hz] | mode-1 zeta | Loper decay / free | settle: servo alone / method | modes of the 5 deg step response (Hz, zeta) |",
        "|---|---|---|---|---|---|---|",
    ]
    f = lambda x, d=3: "-" if x is None else (f"{x:.{d}g}" if isinstance(x, float) else str(x))  # noqa: E731
    for name, r in m.items():
        where = f"diverged at {r['diverged_at_s']:.3g} s" if r.get("diverged_at_s") is not None else f(r.get("unstable_mode_hz"))
        lines.append(f"| {name} | {r['stable']} | {where} | {f(r.get('mode1_zeta'))} | {f(r.get('loper_decay_ratio'))} | {f(r.get('settle_ratio'))} | "
                     + ", ".join(f"{a:.3g} ({b:.3f})" for a, b in r.get("modes", [])) + " |")  # fmt: skip
    (args.out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(json.dumps({k: results["chapter8"][k] for k in ("placement_observer", "kalman_run")}, indent=1, default=str))
    print(
        "chapter 11: residual ratio",
        results["chapter11"]["residual_rms_ratio_unity_over_cancel"],
        "loper ratio",
        results["chapter11"]["loper_decay_ratio"],
    )
    return None


if __name__ == "__main__":
    sys.exit(main())
