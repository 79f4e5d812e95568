"""The main job's summary as a person reads it: :func:`summary_lines` renders ``summary.json``
(:class:`samii.schema.summary.RunSummary`, its typed values) in at most 20 lines; and what a main job runs and writes
beside its stages' folders (:data:`CONTROLLERS`, :data:`SCENARIOS`, :data:`RECORDINGS`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from samii.identify.report import verdict_text
from samii.schema.summary import RunSummary

__all__ = ["CONTROLLERS", "SCENARIOS", "RECORDINGS", "summary_lines"]

#: (name in the output, samii closedloop --controller, label in the summary) run closed loop; "damping" is designed by the main job.
CONTROLLERS = (
    ("notebook_cancel", "notebook-cancel", "pole cancelling (ch 10)"),
    ("notebook_place", "notebook-place", "pole placement (ch 8)"),
    ("damping", None, "damping controller"),
)
SCENARIOS = ("step", "loper")
#: The Rerun recordings a main job writes beside its stages' folders, and what each shows.
RECORDINGS = {"measure.rrd": "the swept-sine measurement", "closedloop.rrd": "the damping controller's Loper test beside the servo loop alone"}


def _f(x, spec: str) -> str:
    """``x`` formatted, "n/a" for None (a figure a run does not have: the settling time of a joint that did not follow
    its step)."""
    return "n/a" if x is None else format(x, spec)


def summary_lines(s: RunSummary, out) -> list[str]:
    """The summary a person reads: at most 20 lines."""

    m = s.modes
    lines = [
        "SAMII main job: "
        + ("embedded model" if s.model_file == "embedded default" else s.model_file)
        + (f" with {', '.join(s.overrides)}" if s.overrides else "")
    ]
    lines.append(
        "base modes (joint 2 held): "
        + ", ".join(f"{b.freq_hz:.2f} Hz (zeta {b.zeta:.3f})" for b in m.base_modes)
        + (f"; servo-loop pair {m.servo_pair_1_s[0]:.1f} ± {m.servo_pair_1_s[1]:.1f}j 1/s" if m.servo_pair_1_s else "")
    )
    me = s.measurement
    lines.append(
        f"measured: {me.excitation}, {me.amplitude_v:g} V on the valve command, {me.simulated_s:.0f} s at "
        f"{me.sample_rate_hz:g} samples/s, sensor noise (seed {s.seed})"
    )
    f, eq = s.fit.params, s.fit.eq9_4

    def hz(d: Mapping, name: str) -> str:  # a frequency [rad/s] in Hz; n/a for a parameter not fitted
        w = d.get(name)
        return _f(None if w is None else w / (2 * np.pi), ".2f")

    def zeta(d: Mapping, name: str) -> str:
        return _f(d.get(name), ".3f")

    def ratio(d: Mapping, a: str, b: str) -> str:
        x, y = d.get(a), d.get(b)
        return _f(None if x is None or not y else x / y, ".3f")

    lines.append(f"fit of the notebook's 3-mode model beside eq 9.4: {verdict_text(s.fit.to_json())} (fit/fit.json):")
    lines.append(
        f"  modes {hz(f, 'w1')} / {hz(f, 'wz')} / {hz(f, 'w3')} Hz (eq 9.4: {hz(eq, 'w1')} / {hz(eq, 'wz')} / {hz(eq, 'w3')}); "
        f"zeta {zeta(f, 'z1')} / {zeta(f, 'zz')} / {zeta(f, 'z3')} ({zeta(eq, 'z1')} / {zeta(eq, 'zz')} / {zeta(eq, 'z3')})"
    )
    lines.append(
        f"  actuator pair {hz(f, 'wp')} Hz zeta {zeta(f, 'zp')} (eq 9.4: {hz(eq, 'wp')} Hz, {zeta(eq, 'zp')}); "
        f"B2/B1 {ratio(f, 'B2', 'B1')} ({ratio(eq, 'B2', 'B1')}), B3/B1 {ratio(f, 'B3', 'B1')} ({ratio(eq, 'B3', 'B1')})"
    )
    cl = s.closed_loop
    lines.append("closed loop in the nonlinear simulator (step 5 deg; Loper: switched on at 2 s):")
    for name, _, label in CONTROLLERS:
        st, lo = cl[f"{name}_step"], cl[f"{name}_loper"]
        if not st.stable or not lo.stable:
            bad = st if not st.stable else lo
            if bad.instability:
                grow, hz_ = bad.instability, ""
            else:
                grow = f"growing at {bad.growth_rate_1_s:.3g} 1/s" if bad.growth_rate_1_s else "diverging"
                hz_ = f" at {bad.unstable_mode_hz:.3g} Hz" if bad.unstable_mode_hz else ""
            what = f"UNSTABLE ({grow}{hz_}; the run is in closedloop/{name}_{'step' if bad is st else 'loper'}/)"
        else:
            th, ba, lb = st.theta, st.base, lo.base
            what = (
                f"stable; step: theta settles {_f(th and th.settle_s, '.2f')} s, base {_f(ba and ba.settle_s, '.2f')} s; "
                f"Loper: base decays at {_f(lb and lb.decay_rate_1_s, '.2f')} 1/s"
            )
        lines.append(f"  {label:<24} {what}")
    dl, ds, alone = cl["damping_loper"], cl["damping_step"], cl["servo_loop_alone_step"]
    over = [r.theta and r.theta.overshoot_pct for r in (ds, alone)]  # what damping the base costs the joint
    (t_alone, t_damped) = [r.base and r.base.settle_s for r in (alone, ds)]
    rate, free = dl.base and dl.base.decay_rate_1_s, dl.base and dl.base.free_decay_rate_1_s
    if dl.stable and ds.stable and None not in (t_alone, rate) and t_damped and free:  # (ratios of figures each run has)
        lines.append(
            f"damping controller: the base settles {t_alone / t_damped:.1f}x sooner after the step "
            f"({t_damped:.2f} s against {t_alone:.2f} s under the servo loop alone); in the Loper test "
            f"its vibration decays {rate / free:.1f}x faster than free"
            + ("" if None in over else f"; theta overshoots the step by {over[0]:.0f} % ({over[1]:.0f} % alone)")
        )
    dg = s.diagnosis
    eff = ", ".join(f"{e.category}/{e.kind}" for e in dg.effects) or "nothing"
    lines.append(f"diagnosis of the fit against the measured record: {dg.verdict}; found {eff}")

    def num(v: float | None) -> float:  # (a figure may be null: chi2 with no noise estimate)
        return float("nan") if v is None else float(v)

    for ch, name, note in (("act", "theta/v", " (chi2 1: the noise)"), ("total", "xdd/v", "")):
        b, a = dg.error_before.get(ch), dg.error_after.get(ch)
        if b and a:
            lines.append(
                f"  {name} error {num(b.rms_db):.2g} dB / {num(b.rms_deg):.2g} deg, chi2 {num(b.chi2):.3g} -> "
                f"{num(a.rms_db):.2g} dB / {num(a.rms_deg):.2g} deg, chi2 {num(a.chi2):.3g} with them{note}"
            )
    report = "report.html (open it in a browser), " if not s.report_error else "(NOT report.html: see the warning above) "
    rrd = " and ".join(f"{n} ({s.recordings_mb[n]:.0f} MB)" if s.recordings_mb.get(n) is not None else n for n in RECORDINGS)
    lines.append(
        f"wrote {out}/ in {_f(s.wall_s, '.0f')} s: {report}summary.json, measure/, fit/, controllers/, "
        f"closedloop/, diagnose/; {rrd} (open with `rerun FILE`)"
    )
    return lines[:20]
