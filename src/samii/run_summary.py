"""The main job's summary: what ``summary.json`` holds beside the stages' own files, and the lines a person reads.

Shared by the main job (:mod:`samii.main_job`, which writes it) and the report (:mod:`samii.report.page`, which reads it).
"""

from __future__ import annotations

__all__ = ["CONTROLLERS", "SCENARIOS", "MARKER", "summary_lines"]

#: (name in the output, samii closedloop --controller, label in the summary) run closed loop; "damping" is designed by the main job.
CONTROLLERS = (
    ("notebook_cancel", "notebook-cancel", "pole cancelling (ch 10)"),
    ("notebook_place", "notebook-place", "pole placement (ch 8)"),
    ("damping", None, "damping controller"),
)
SCENARIOS = ("step", "loper")
#: summary.json says it is a main job's: a folder holding one may be replaced by the next main job.
MARKER = "samii run"


def summary_lines(s: dict, out) -> list[str]:
    """The summary a person reads: at most 20 lines."""
    import numpy as np

    m = s["modes"]
    lines = [
        "SAMII main job: "
        + ("embedded model" if s["model"]["file"] == "embedded default" else s["model"]["file"])
        + (f" with {', '.join(s['model']['overrides'])}" if s["model"]["overrides"] else "")
    ]
    lines.append(
        "base modes (joint 2 held): "
        + ", ".join(f"{b['freq_hz']:.2f} Hz (zeta {b['zeta']:.3f})" for b in m["base_modes"])
        + (f"; servo-loop pair {m['servo_pair_1_s'][0]:.1f} ± {m['servo_pair_1_s'][1]:.1f}j 1/s" if m["servo_pair_1_s"] else "")
    )
    me = s["measurement"]
    lines.append(
        f"measured: {me['excitation']}, {me['amplitude_v']:g} V on the valve command, {me['simulated_s']:.0f} s at "
        f"{me['sample_rate_hz']:g} samples/s, sensor noise (seed {s['seed']})"
    )
    f = s["fit"]["params"]
    eq = s["fit"]["eq9_4"]

    def hz(w):
        return w / (2 * np.pi)

    from samii.identify.report import verdict_text

    lines.append(f"fit of the notebook's 3-mode model beside eq 9.4: {verdict_text(s['fit'])} (fit/fit.json):")
    lines.append(
        f"  modes {hz(f['w1']):.2f} / {hz(f['wz']):.2f} / {hz(f['w3']):.2f} Hz (eq 9.4: {hz(eq['w1']):.2f} / {hz(eq['wz']):.2f} / "
        f"{hz(eq['w3']):.2f}); zeta {f['z1']:.3f} / {f['zz']:.3f} / {f['z3']:.3f} ({eq['z1']:.3f} / {eq['zz']:.3f} / {eq['z3']:.3f})"
    )
    lines.append(
        f"  actuator pair {hz(f['wp']):.2f} Hz zeta {f['zp']:.3f} (eq 9.4: {hz(eq['wp']):.2f} Hz, {eq['zp']:.3f}); "
        f"B2/B1 {f['B2'] / f['B1']:.3f} ({eq['B2'] / eq['B1']:.3f}), B3/B1 {f['B3'] / f['B1']:.3f} ({eq['B3'] / eq['B1']:.3f})"
    )
    cl = s["closed_loop"]
    lines.append("closed loop in the nonlinear simulator (step 5 deg; Loper: switched on at 2 s):")
    for name, _, label in CONTROLLERS:
        st, lo = cl[f"{name}_step"], cl[f"{name}_loper"]
        if not st["stable"] or not lo["stable"]:
            bad = st if not st["stable"] else lo
            if bad.get("instability"):
                grow, hz_ = bad["instability"], ""
            else:
                grow = f"growing at {bad['growth_rate_1_s']:.3g} 1/s" if bad.get("growth_rate_1_s") else "diverging"
                hz_ = f" at {bad['unstable_mode_hz']:.3g} Hz" if bad.get("unstable_mode_hz") else ""
            what = f"UNSTABLE ({grow}{hz_}; the run is in closedloop/{name}_{'step' if bad is st else 'loper'}/)"
        else:
            what = (
                f"stable; step: theta settles {st['theta']['settle_s']:.2f} s, base {st['base']['settle_s']:.2f} s; "
                f"Loper: base decays at {lo['base']['decay_rate_1_s']:.2f} 1/s"
            )
        lines.append(f"  {label:<24} {what}")
    dl, ds, alone = cl["damping_loper"], cl["damping_step"], cl["servo_loop_alone_step"]
    over = [(r.get("theta") or {}).get("overshoot_pct") for r in (ds, alone)]  # what damping the base costs the joint
    if dl["stable"] and ds["stable"] and dl["base"].get("free_decay_rate_1_s"):
        lines.append(
            f"damping controller: the base settles {alone['base']['settle_s'] / ds['base']['settle_s']:.1f}x sooner after the step "
            f"({ds['base']['settle_s']:.2f} s against {alone['base']['settle_s']:.2f} s under the servo loop alone); in the Loper test "
            f"its vibration decays {dl['base']['decay_rate_1_s'] / dl['base']['free_decay_rate_1_s']:.1f}x faster than free"
            + ("" if None in over else f"; theta overshoots the step by {over[0]:.0f} % ({over[1]:.0f} % alone)")
        )
    dg = s["diagnosis"]
    eff = ", ".join(f"{e['category']}/{e['kind']}" for e in dg["effects"]) or "nothing"
    lines.append(f"diagnosis of the fit against the measured record: {dg['verdict']}; found {eff}")

    def num(d: dict, key: str) -> float:  # (a figure may be null: chi2 with no noise estimate)
        v = d.get(key)
        return float("nan") if v is None else float(v)

    for ch, name, note in (("act", "theta/v", " (chi2 1: the noise)"), ("total", "xdd/v", "")):
        b, a = dg["error_before"].get(ch, {}), dg["error_after"].get(ch, {})
        if b and a:
            lines.append(
                f"  {name} error {num(b, 'rms_db'):.2g} dB / {num(b, 'rms_deg'):.2g} deg, chi2 {num(b, 'chi2'):.3g} -> "
                f"{num(a, 'rms_db'):.2g} dB / {num(a, 'rms_deg'):.2g} deg, chi2 {num(a, 'chi2'):.3g} with them{note}"
            )
    report = "report.html (open it in a browser), " if not s.get("report_error") else "(NOT report.html: see the warning above) "
    rrd = " and ".join(
        f"{n} ({s['recordings_mb'][n]:.0f} MB)" if (s.get("recordings_mb") or {}).get(n) is not None else n for n in ("measure.rrd", "closedloop.rrd")
    )
    lines.append(
        f"wrote {out}/ in {s['wall_s']:.0f} s: {report}summary.json, measure/, fit/, controllers/, "
        f"closedloop/, diagnose/; {rrd} (open with `rerun FILE`)"
    )
    return lines[:20]
