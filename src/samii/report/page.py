"""``report.html``: one self-contained page a person reads in a browser, from a main job's folder.

Every figure is embedded (PNG as a ``data:`` URI), the style is inline, there is no script and no
address outside the page but the links to the folder's own Rerun recordings: the page opens offline,
and can be mailed or archived alone. All text from the folder's files is HTML-escaped.
"""

from __future__ import annotations

import base64
import html
import math
import os
import urllib.parse
from dataclasses import is_dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import samii
from samii import notebook as nb
from samii.errors import InputError
from samii.formats import write_text
from samii.identify.profile import interval_text
from samii.identify.report import verdict_of, verdict_text
from samii.outputs import parent_made_for
from samii.report.content import RECORDINGS, STAGE_FIGURES, gaps, parameter_rows, recordings, stage_figures, traced, traces
from samii.report.figures import figure_ch11_loper, figure_ch11_step, figure_damping
from samii.run_summary import CONTROLLERS, summary_lines
from samii.schema.closed_loop import BaseFigures, ThetaFigures
from samii.sim.param_units import unit

if TYPE_CHECKING:  # (the types only: samii.pipeline writes its report through this module)
    from collections.abc import Mapping

    from samii.pipeline import Run
    from samii.schema.summary import ClosedLoopSummary

__all__ = ["render_report", "write_report", "REPORT_NAME"]

REPORT_NAME = "report.html"

#: Physical parameters shown in the model section (name in samii params -> what it is).
_KEY_PARAMS = {
    "beam.length_m": "beam free length",
    "beam.EI_Nm2": "beam bending stiffness EI",
    "beam.mass_per_length_kg_m": "beam mass per length",
    "beam.clamp_stiffness_Nm_rad": "clamp torsional stiffness",
    "arm.joint1_stiffness_Nm_rad": "joint 1 stiffness",
    "hydraulic.supply_pressure": "supply pressure",
    "hydraulic.bulk_modulus": "oil bulk modulus",
    "hydraulic.total_volume": "oil volume",
    "hydraulic.valve_time_constant": "valve time constant",
    "hydraulic.position_gain": "servo amplifier gain",
    "hydraulic.command_delay": "command delay",
    "timestep_s": "simulation time step",
}
_CHANNELS = {"act": "θ/v", "base": "ẍ/θ", "total": "ẍ/v"}
#: A closed-loop run's figures where summary.json holds none (null: a folder of samii 0.1.0 may): each shown as "–".
_NO_THETA, _NO_BASE = ThetaFigures(None, None, None, None), BaseFigures(None, None, None, None, None)

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",sans-serif;margin:0;background:#fafafa;color:#222;line-height:1.45}
main{max-width:1060px;margin:0 auto;padding:24px 28px 60px;background:#fff}
h1{font-size:1.6em;margin:0 0 4px}h2{font-size:1.25em;margin:32px 0 8px;border-bottom:1px solid #ddd;padding-bottom:4px}
h3{font-size:1.05em;margin:20px 0 6px}.lead{color:#555;margin:0 0 12px}
table{border-collapse:collapse;margin:8px 0 12px;font-size:0.9em}th,td{border:1px solid #ddd;padding:3px 8px;text-align:right;vertical-align:top}
th{background:#f0f0f0}td.l,th.l{text-align:left}pre{background:#f5f5f5;padding:10px;white-space:pre-wrap;font-size:0.82em;line-height:1.35}
img{max-width:100%;height:auto;display:block;margin:6px 0 2px}figure{margin:12px 0 18px}figcaption{font-size:0.85em;color:#555}
.bad{color:#b00020;font-weight:600}.ok{color:#1b6e20;font-weight:600}.warn{color:#8a5a00}nav{font-size:0.9em}nav a{margin-right:12px}
code{background:#f2f2f2;padding:0 3px}
"""


def _e(x) -> str:
    return html.escape(str(x), quote=True)


def _num(x, fmt: str = ".4g", none: str = "–") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return none
    return format(float(x), fmt)


def _img(data: bytes, alt: str) -> str:
    return f'<img alt="{_e(alt)}" src="data:image/png;base64,{base64.b64encode(data).decode("ascii")}">'


def _figure(data: bytes | None, alt: str, caption: str) -> str:
    if data is None:
        return f'<p class="warn">({_e(alt)}: not in the folder)</p>'
    return f"<figure>{_img(data, alt)}<figcaption>{caption}</figcaption></figure>"


def _table(header: list[str], rows: list[list[str]], left: int = 1) -> str:
    """Cells are HTML already; the first ``left`` columns are left-aligned."""
    cls = lambda i: ' class="l"' if i < left else ""  # noqa: E731
    head = "".join(f"<th{cls(i)}>{h}</th>" for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(f"<td{cls(i)}>{c}</td>" for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _stage_figure(run: Run, key: str, alt: str, caption: str) -> str:
    """A figure a stage drew (``STAGE_FIGURES``), or a line naming its file where the folder lacks it."""
    p = stage_figures(run).get(key)
    if p is None:
        why = "is not a PNG image (damaged)" if (run.path / STAGE_FIGURES[key]).exists() else "is not in the folder"
        return f'<p class="warn">(Figure: {_e(alt)}: <code>{_e(STAGE_FIGURES[key])}</code> {why}.)</p>'
    return _figure(p.read_bytes(), alt, caption)


# ---- sections ----


def _header(run: Run, lines: list[str], lacks: list[str]) -> str:
    s = run.summary
    model = s.model_file + (f" with {', '.join(s.overrides)}" if s.overrides else "")
    sections = [("model", "Model"), ("measurement", "Measurement"), ("fit", "Identification"), ("control", "Control"),
                ("diagnosis", "Diagnosis"), ("recordings", "Recordings")]  # fmt: skip
    nav = "".join(f'<a href="#{k}">{v}</a>' for k, v in sections)
    return (f"<h1>SAMII: main job report</h1><p class=\"lead\">Model: {_e(model)}. Sensor-noise seed {_e(s.seed)}. "
            f"samii {_e(samii.__version__)}; the whole pipeline took {_num(s.wall_s, '.0f')} s. Every figure below is in this page; "
            f"the numbers are the folder's own files (<code>summary.json</code> holds them all).</p><nav>{nav}</nav>"
            + _gaps(lacks)
            + f"<h2 id=\"summary\">Summary</h2><pre>{_e(chr(10).join(lines))}</pre>")  # fmt: skip


def _gaps(lacks: list[str]) -> str:
    if not lacks:
        return ""
    items = "".join(f"<li>{_e(g)}</li>" for g in lacks)
    return (
        f'<p class="bad">This folder lacks what a main job writes; the page shows what is there and marks the rest '
        f'(run <code>samii run</code> again for a whole report):</p><ul class="warn">{items}</ul>'
    )


def _model(run: Run) -> str:
    from samii.sim.model import dotted  # (lazy: imports mujoco, only when called)

    m = run.summary.modes
    rows = []
    for i, b in enumerate(m.base_modes):
        tgt_f = nb.BASE_MODES_HZ[i] if i < len(nb.BASE_MODES_HZ) else None
        tgt_z = nb.BASE_ZETAS[i] if i < len(nb.BASE_ZETAS) else None
        diff = None if tgt_f is None else 100 * (b.freq_hz - tgt_f) / tgt_f
        rows.append([f"base mode {i + 1}", _num(b.freq_hz, ".3f"), _num(tgt_f, ".2f"), _num(diff, "+.2f"), _num(b.zeta, ".3f"), _num(tgt_z, ".3f")])
    out = ['<h2 id="model">Model</h2>', "<p>SAMII, a 6-DOF hydraulic arm at the tip of a flexible cantilevered beam, in MuJoCo. "
           "The base modes are the linearised simulator's with joint 2 held, at the nominal pose (joints "
           + _e(", ".join(str(round(a)) for a in m.pose_deg)) + " deg); the notebook's eq 9.4 modes are the simulator's calibration targets.</p>",
           _table(["", "simulator [Hz]", "eq 9.4 [Hz]", "difference [%]", "ζ simulator", "ζ eq 9.4"], rows)]  # fmt: skip
    if m.servo_pair_1_s:
        re_, im = m.servo_pair_1_s
        out.append(
            f"<p>Servo position loop (joint 2 free, unity feedback): the lightly damped pair at {_num(re_, '.2f')} ± {_num(im, '.1f')}j 1/s "
            f"({_num(im / (2 * math.pi), '.2f')} Hz, ζ {_num(-re_ / math.hypot(re_, im), '.3f')}).</p>"
        )
    flat = dotted(run.measurement_record.model.params or {})
    prow = [[_e(what), f"<code>{_e(name)}</code>", _num(flat[name], ".5g"), _e(unit(name))] for name, what in _KEY_PARAMS.items() if name in flat]
    if prow:
        out.append(
            "<h3>Key physical parameters</h3>"
            + _table(["", "name (<code>--set NAME=VALUE</code>)", "value", "unit"], prow, left=2)
            + "<p>All of them: <code>samii params</code>; where each comes from: the model card (<code>models/samii/README.md</code> "
            "in the samii repository).</p>"
        )
    return "".join(out)


def _measurement(run: Run) -> str:
    me = run.summary.measurement
    noise_txt = ", ".join(f"{_e(k)} {_num(v, '.3g')}" for k, v in (me.sensor_noise or {}).items())
    return ('<h2 id="measurement">Measurement</h2>'
            f"<p>{_e(me.excitation)}, {_num(me.amplitude_v, 'g')} V on the valve command, {_num(me.simulated_s, '.0f')} s simulated "
            f"at {_num(me.sample_rate_hz, 'g')} samples/s, recorded by the simulated DAQ with sensor noise (standard deviations: {noise_txt}; "
            f"seed {_e(run.summary.seed)}). Joint 2 runs under its unity position loop, as on the rig. The FRF (<code>measure/frf.csv</code>) "
            "is estimated from the record with the excitation as the instrument.</p>"
            + _stage_figure(run, "measure_bode", "the measured FRF", "The measured FRF (solid; pale where the coherence is below 0.95) "
                      "beside the linearised simulator (dashed), and the coherence. Where the coherence falls the channel is noise: a "
                      "small sweep moves θ less than its noise above the hydraulic resonance (θ/v and ẍ/θ there), while ẍ/v, read by the "
                      "accelerometer, is not; below base mode 1 the base hardly moves and ẍ is noise. <code>measure/bode.png</code>.")
            + _stage_figure(run, "diagnose_harmonics", "the sweep's harmonics", "The sweep's 2nd and 3rd harmonics in the measured "
                      "record, referred to the valve command, segment by segment, with twice their noise (dotted): a linear system makes "
                      "none, and one repeated in every record beyond its noise is a nonlinearity (the diagnosis below tests it). "
                      "<code>diagnose/harmonics.png</code>."))  # fmt: skip


def _interval(iv: tuple[float | None, float | None] | None) -> str:
    """A 95 % profile interval as shown (``identify.profile.interval_text``), "" for a parameter not profiled."""
    return "" if iv is None else _e(interval_text(*iv))


def _fit(run: Run) -> str:
    f = run.fit_record

    verdict = f'<span class="{"bad" if verdict_of(f) == "not sound" else "ok"}">{_e(verdict_text(f))}</span>'  # a failure told apart from caveats
    rows = []
    for r in parameter_rows(f, dict(nb.EQ9_4)):
        rows.append([f"<code>{_e(r.name)}</code>", _e(r.meaning), _num(r.value, ".5g", '<span class="bad">none in fit.json</span>'), _num(r.stderr, ".2g"), _num(r.rel_stderr_pct, ".2g"),
                     _interval(r.interval_95), _num(r.notebook, ".5g"), _num(r.diff_pct, "+.1f"), _num(r.sigmas, ".2g"), _e(r.unit)])  # fmt: skip
    rms = f.get("rms_mag_db") or {}
    ph = f.get("rms_phase_deg") or {}
    rms_txt = "; ".join(f"{_e(_CHANNELS.get(k, k))} {_num(rms[k], '.2f')} dB, {_num(ph.get(k), '.1f')} deg" for k in rms)
    concerns = "".join(f"<li>{_e(c)}</li>" for c in f.get("concerns") or [])
    caveats = "".join(f"<li>{_e(c)}</li>" for c in f.get("caveats") or [])
    return ('<h2 id="fit">Identification: the notebook\'s 3-mode model</h2>'
            f"<p>The notebook's eq 9.1/9.2 structure fitted to the measured FRF (<code>samii fit</code>, phase weight {_num(f.get('phase_weight'), 'g')}, "
            f"{_num((f.get('band_hz') or [None])[0], '.2g')}–{_num((f.get('band_hz') or [None, None])[1], '.3g')} Hz): {verdict}. "
            f"RMS error {rms_txt}.</p>"
            + (f"<p>Why its parameters should not be used:</p><ul class=\"warn\">{concerns}</ul>" if concerns else "")
            + (f"<p>Caveats (the parameters can be used but those the data do not determine):</p><ul>{caveats}</ul>" if caveats else "")
            + _stage_figure(run, "bode_fit", "Bode data with the fit", "The measured FRF (points) with the fitted model (line), and the "
                      "coherence. <code>fit/bode_fit.png</code>.")
            + "<h3>Parameters beside eq 9.4</h3>"
            + _table(["", "", "fit", "± std. error", "± %", "95 % profile interval", "eq 9.4", "fit − eq 9.4 [%]", "[std. errors]", "unit"], rows, left=2)
            + "<p>Frequencies in Hz (the fit's ω/2π). The gains are in SI; eq 9.4's are converted from the notebook's units (θ in degrees, "
            "ẍ in ft/s², which its coefficients imply; <code>experiments/closed_loop/README.md</code>). Standard errors are the fit's, "
            "from the Jacobian and the residual; the notebook gives none. A parameter many standard errors from eq 9.4 differs in the "
            "simulator, not only in the data's noise. Each frequency's 95 % interval is read off its profile (the frequency held away "
            "from the estimate, the other parameters re-solved): where the cost is lopsided or flat it is lopsided or open (≥, ≤: the "
            "data do not bound it on that side), and it is the one to use for a mode the data barely see.</p>")  # fmt: skip


def _closed_loop(run: Run) -> str:
    cl = run.summary.closed_loop
    d = run.summary.damping_design
    out = ['<h2 id="control">Control: the notebook\'s controllers and the damping controller, closed loop in the nonlinear simulator</h2>',
           f"<p>The damping controller is acceleration feedback designed on a fit of the measured FRF (<code>samii design damping --frf</code>): "
           f"gain {_num(d.gain_v_per_m_s2, '.3g')} V/(m/s²), {_num(d.gain_margin_db, '.2g')} dB below the fitted model's "
           f"stability limit of {_num(d.gain_limit_v_per_m_s2, '.3g')}, a low-pass at {_num(d.filter_hz, '.3g')} Hz and a roll-off "
           f"at {_num(d.rolloff_hz, '.3g')} Hz. The notebook's pole-cancelling compensator (chapter 10) and pole placement (chapter 8) run "
           "as the notebook built them. Every controller runs at 1 kHz inside the simulator (sampled θ and ẍ, zero-order hold, the valve's "
           "±10 V). Step: 5 deg on joint 2 at t = 1 s. Loper test: the same step under the servo loop alone, the controller switched on at "
           "t = 2 s.</p>"]  # fmt: skip
    rows = []
    names = [("servo_loop_alone", "servo loop alone")] + [(n, label) for n, _, label in CONTROLLERS]
    for name, label in names:
        for sc in ("step", "loper"):
            r = cl.get(f"{name}_{sc}")
            if r is None:
                continue
            th, ba = r.theta or _NO_THETA, r.base or _NO_BASE
            ok = r.stable
            hz = f", {_num(r.unstable_mode_hz, '.3g')} Hz" if r.unstable_mode_hz else ""
            why = _e(r.instability) if r.instability is not None else f"grows at {_num(r.growth_rate_1_s, '.3g')} 1/s{hz}"
            state = '<span class="ok">stable</span>' if ok else f'<span class="bad">UNSTABLE</span> ({why})'
            rows.append([_e(label), sc, state,
                         _num(th.overshoot_pct, ".1f") if ok and sc == "step" else "–",
                         _num(th.settle_s, ".2f") if ok and sc == "step" else "–",
                         _num(ba.peak_m_s2, ".3g") if ok else "–",
                         _num(ba.settle_s, ".2f") if ok else "–",
                         _num(ba.decay_rate_1_s, ".3g") if ok and sc == "loper" else "–",
                         _num(ba.free_decay_rate_1_s, ".3g") if ok and sc == "loper" else "–"])  # fmt: skip
    out.append(_table(["controller", "test", "", "θ overshoot [%]", "θ settles [s]", "base peak [m/s²]", "base settles [s]",
                       "base decay after switch-on [1/s]", "free decay [1/s]"], rows, left=3))  # fmt: skip
    out.append(
        "<p>Settling: the last time the signal is outside 5 % of its peak excursion. Decay rate: the envelope's exponential rate "
        "after the switch-on; the free decay is the servo loop alone's over the same time. Each run's own figures, its linear "
        "prediction and its time series are in <code>closedloop/&lt;controller&gt;_&lt;test&gt;/</code>.</p>"
    )
    tr = traces(run)
    if {"servo_loop_alone_step", "notebook_cancel_step"} <= tr.keys():
        out.append(
            _figure(
                figure_ch11_step(tr["servo_loop_alone_step"], tr["notebook_cancel_step"]),
                "Figures 11.1-11.4",
                "The notebook's Figures 11.1–11.4 as simulations (first 5 s of 10). As on the rig, the compensator shapes the "
                "step so that it excites little vibration, but it does not damp the base.",
            )
        )
    if {"servo_loop_alone_step", "notebook_cancel_loper"} <= tr.keys():
        out.append(
            _figure(
                figure_ch11_loper(tr["servo_loop_alone_step"], tr["notebook_cancel_loper"], _switch_on(run, "notebook_cancel_loper")),
                "Figure 11.5",
                "The notebook's Figure 11.5 as a simulation: switched on after the move, the pole-cancelling compensator leaves "
                'the vibration as it was ("Obviously this didn\'t work very well", chapter 11). The free decay is the servo loop '
                "alone's step run, identical to the Loper run until the switch-on.",
            )
        )
    if {"servo_loop_alone_step", "damping_step", "damping_loper"} <= tr.keys():
        out.append(
            _figure(
                figure_damping(tr["servo_loop_alone_step"], tr["damping_step"], tr["damping_loper"], _switch_on(run, "damping_loper")),
                "The damping controller",
                "The damping controller in the same tests: it shortens the base vibration after the "
                "step and damps it when switched on after the move, which the pole-cancelling compensator does not." + _overshoot(cl),
            )
        )
    place = cl.get("notebook_place_step")
    if place is not None and not place.stable:
        out.append(
            "<p>Pole placement (chapter 8) is unstable on every plant but the notebook's own 2-mode eq 1.4: its observer uses eq 1.4's "
            "direct feedthrough of ẍ/v, which no valve-driven actuator has, so any mismatch closes a loop at the sample rate with a "
            "gain far above 1 (<code>experiments/closed_loop/README.md</code>). Its runs stop where the controller's output diverges: "
            + _e("; ".join(n for n in run.closed_loop["notebook_place_step"].record.notes if "diverged at" in n))
            + ".</p>"
        )
    return "".join(out)


def _overshoot(cl: Mapping[str, ClosedLoopSummary]) -> str:
    """What the damping controller costs the joint: its θ overshoot beside the servo loop alone's, said when larger."""
    mine, alone = (cl[k].theta.overshoot_pct if k in cl and cl[k].theta else None for k in ("damping_step", "servo_loop_alone_step"))
    if mine is None or alone is None or not mine > alone:
        return ""
    return (
        f" The price is the joint's: θ overshoots the step by {_num(mine, '.0f')} % against {_num(alone, '.0f')} % under the servo loop "
        "alone: its command is added to the servo loop's on the same valve, so what it does to damp the base moves the joint "
        "too (the design sets its gain for the base's damping, with a gain margin; the step's shape is not in its objective)."
    )


def _worse(after, before, fmt: str) -> str:
    """``after`` formatted, in red when it is above ``before``."""
    txt = _num(after, fmt)
    if after is not None and before is not None and math.isfinite(after) and math.isfinite(before) and after > before and txt != _num(before, fmt):
        return f'<span class="bad">{txt}</span>'
    return txt


def _switch_on(run: Run, name: str) -> float:
    on = run.closed_loop[name].record.scenario_settings.switch_on_s
    return 2.0 if on is None else float(on)


def _diagnosis(run: Run) -> str:
    d = run.diagnosis  # (samii.schema.diagnosis.DiagnosisRecord: its fields checked when the folder was read)
    effects = d.found
    out = [
        '<h2 id="diagnosis">Diagnosis: what the fit lacks, found in the measured record</h2>',
        f"<p><code>samii diagnose measure/timeseries.csv --baseline fit/fit.json</code>: verdict <b>{_e(d.verdict)}</b>. Each effect is a physical "
        f"hypothesis fitted jointly with the baseline; {_e(d.rule)}.</p>",
    ]
    for n in d.notes:
        out.append(f'<p class="warn">{_e(n)}</p>')
    if effects:
        rows = []
        for e in effects:
            ps = ", ".join(f"{_e(k)} = {_num(v, '.4g')}" + (f" ± {_num(e.stderr.get(k), '.2g')}" if e.stderr.get(k) is not None else "")
                           for k, v in e.params.items())  # fmt: skip
            rows.append([_e(e.category), _e(e.kind), _e(_CHANNELS.get(e.channel, e.channel)), ps, _e(e.evidence)])
        out.append(_table(["category", "kind", "channel", "parameters ± std. error", "evidence"], rows, left=5))
    else:
        out.append("<p>No effect beyond the baseline's noise.</p>")
    eb, ea = d.error_before, d.error_after
    rows = []
    for ch in ("act", "base", "total"):
        if ch in eb:
            b, a = eb[ch], ea.get(ch)
            rows.append([_CHANNELS[ch]] + [c for key, fmt in (("rms_db", ".2f"), ("rms_deg", ".1f"), ("chi2", ".3g"))
                                            for c in (_num(getattr(b, key), fmt),
                                                      _worse(getattr(a, key) if a else None, getattr(b, key), fmt))])  # fmt: skip
    if rows:
        fr, fp = run.fit_record.get("rms_mag_db") or {}, run.fit_record.get("rms_phase_deg") or {}
        why = ""
        if "act" in fr and "act" in eb:
            why = (
                f" These are smaller than the Identification section's RMS error (θ/v {_num(fr['act'], '.2f')} dB, {_num(fp.get('act'), '.1f')} deg "
                f"there, {_num(eb['act'].rms_db, '.2f')} dB, {_num(eb['act'].rms_deg, '.1f')} deg here before the effects) "
                "for one reason: the fit's is over every point of its band, those where the channel is noise (coherence below 0.5) "
                "included, while the diagnosis counts only the points its noise estimate says are usable."
            )
        out.append("<h3>Error before and after the effects</h3><p>Residual over the data's usable points; "
                   f"an error that grows with the effects is in red.{why}</p>" + _table(["channel", "rms dB before", "after", "rms deg before", "after",
                                                                          "χ² per residual before (1: the noise)", "after"], rows))  # fmt: skip
    he = d.harmonic_error
    if he is not None:
        b, a = he.before, he.after
        pct = lambda x: None if x is None else 100.0 * x  # noqa: E731
        out.append(
            f"<p>The sweep's harmonics ({_e(b.n_segments)} segment harmonics), which no linear model makes: rms "
            f"{_num(pct(b.rms_ratio), '.3g')} % of the fundamental, χ² {_num(b.chi2, '.3g')} per residual; with the "
            f"nonlinear law found {_worse(pct(a.rms_ratio), pct(b.rms_ratio), '.3g')} %, "
            f"χ² {_worse(a.chi2, b.chi2, '.3g')}.</p>"
        )
    if d.refused:
        items = "".join(f"<li>{_e(r.effect)} ("
                        + ", ".join(f"{_e(k)} = {_num(v, '.4g')}" for k, v in r.params.items())
                        + f"): {_e(r.reason)}</li>" for r in d.refused)  # fmt: skip
        out.append(
            "<p>Candidates that passed the F-test but that these data do not show (not identifiable, or smaller than "
            f"the measurement's systematic floor), refused:</p><ul>{items}</ul>"
        )
    if d.unexplained:
        items = "".join(f"<li>{_e(_CHANNELS.get(u.channel, u.channel))} over {_num(u.lo_hz, '.3g')}–{_num(u.hi_hz, '.3g')} Hz: "
                        f"χ² {_num(u.chi2, '.3g')} over {_e(u.n_points)} points"
                        + ("" if u.why == "residual" else f" ({_e(u.why)}: the rig changed during the file)")
                        + "</li>" for u in d.unexplained)  # fmt: skip
        out.append(f"<p>Left unexplained by the effect library (red bands below; orange where the records differ):</p><ul>{items}</ul>")
    out.append(
        _stage_figure(
            run,
            "diagnose_bode",
            "data, baseline and the model with the effects",
            "Data, the baseline (the fit) and the model with the effects found. Where the data's coherence is below 0.5 "
            "(the identification figure above) there are no points, and the model there is an extrapolation. "
            "<code>diagnose/bode.png</code>.",
        )
    )
    out.append(
        _stage_figure(
            run,
            "diagnose_residuals",
            "residuals",
            "Residuals data/model (magnitude in dB, phase in degrees) with the noise band (±2σ from the "
            "coherence and the record-to-record spread), before and after the effects. <code>diagnose/residuals.png</code>.",
        )
    )
    return "".join(out)


def _recordings(run: Run, page_dir: Path) -> str:
    items = []
    sizes = recordings(run)
    for name, what in RECORDINGS.items():
        size = sizes.get(name)
        if size is None:
            continue
        href = urllib.parse.quote(Path(os.path.relpath(run.path.absolute() / name, page_dir.absolute())).as_posix())  # a URL: '#', '%', ' ' escaped
        items.append(f'<li><a href="{_e(href)}">{_e(name)}</a> ({size / 1e6:.0f} MB): {_e(what)}</li>')
    if not items:
        return '<h2 id="recordings">Recordings</h2><p>No Rerun recording in this folder.</p>'
    return (
        "<h2 id=\"recordings\">Recordings</h2><p>The runs in 3D with the beam's deflection magnified, the tip's trail and every signal, "
        "for the Rerun viewer (it comes with samii: <code>rerun closedloop.rrd</code> in this folder). The links open the files "
        f"beside this page.</p><ul>{''.join(items)}</ul>"
    )


def render_report(run: Run, page_dir: Path | None = None, *, name: str | None = None) -> str:
    """The page's HTML, naming the run's folder ``name`` (default: its folder's name; the main job writes the page in a
    staging folder); the links to the recordings are relative to ``page_dir`` (default: the run's folder). A stage's
    document that lacks a field the page needs, or holds a value of the wrong kind, is an InputError naming the field
    (summary.json's are checked when the run is read, samii.pipeline.Run.load)."""

    watched, log = traced(run)
    try:
        return _render(watched, page_dir, name or run.path.name)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        if isinstance(exc, AttributeError) and is_dataclass(getattr(exc, "obj", None)):
            raise  # (a typed document has its fields checked when read: a name it lacks is this page's mistake, not the folder's)
        what = (
            f"field {exc.args[0]!r} missing" if isinstance(exc, KeyError) else str(exc).replace("_TracedList", "list").replace("_TracedDict", "dict")
        )
        near = log.suspect(str(exc))
        if near:  # the field first, in the data's terms; Python's words after, for the record
            raise InputError(
                f"{run.path}: a file of this main job's folder is not as samii run writes it: probably at {near}, a value "
                f"samii does not write there (the last field read that holds no number; Python said: {what}); run samii "
                "run again"
            ) from None
        raise InputError(f"{run.path}: a file of this main job's folder is not as samii run writes it ({what}); run samii run again") from None


def _render(run: Run, page_dir: Path | None, name: str) -> str:
    body = "".join([_header(run, summary_lines(run.summary, name), gaps(run)), _model(run), _measurement(run), _fit(run), _closed_loop(run),
                    _diagnosis(run), _recordings(run, page_dir if page_dir is not None else run.path)])  # fmt: skip
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>SAMII main job report</title><style>{_CSS}</style></head><body><main>{body}</main></body></html>\n"
    )


def write_report(run: Run, path: Path | None = None, *, name: str | None = None) -> Path:
    """Write ``report.html`` (default: into the run's folder; ``name``: as :func:`render_report`) and return its path."""

    path = Path(path) if path is not None else run.path / REPORT_NAME
    if path.is_dir():
        raise InputError(f"{path}: is a folder; the report is a file (remove the folder or give --out FILE)")
    with parent_made_for(path):  # atomic, and a folder made for it removed again: a failure (a full disk) leaves nothing
        page = render_report(run, path.parent, name=name)
        try:
            return write_text(path, page, overwrite=True)
        except OSError as exc:  # named as the report, not as the hidden temporary file beside it (a read-only folder)
            if exc.errno is None or exc.filename == str(path):
                raise
            raise OSError(exc.errno, exc.strerror, str(path)) from None
