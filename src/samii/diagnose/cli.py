"""``samii diagnose DATA [DATA ...]``: what the model lacks, found in measured data.

Each DATA is a time-series CSV (its FRF and noise estimated here, the records
of ``r`` found from the data), an FRF CSV (noise from its coherence) or a
rig-era .mat. The baseline (``--baseline``) is fitted, effects from the library
are added by forward selection with an F-test against the data's noise, and
the report gives each effect with its parameters and evidence, the error
before and after per channel, and any band no effect explains.

``--out DIR`` writes ``diagnosis.json``, ``residuals.png``, ``bode.png`` and ``harmonics.png`` (and
``simulator.png`` with ``--baseline sim``);
``--json`` prints the JSON. With ``--baseline sim``, ``--rerun FILE.rrd`` writes a Rerun recording
of the simulator against the data (``samii.diagnose.recording``). Imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse

from samii.cli_args import add_band, add_json, add_model, add_no_progress, add_out, add_overwrite, add_rerun, nonempty_path, positive_float
from samii.diagnose.files import MAX_FILES

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "data",
        metavar="DATA",
        nargs="+",
        type=nonempty_path,
        help=f"measured files of one rig (at most {MAX_FILES}): time-series CSVs (t, v, theta, accel, r), FRF CSVs "
        "(DATA_FORMATS.md) or rig-era .mat; several amplitudes may be mixed",
    )
    parser.add_argument(
        "--baseline",
        default="notebook",
        metavar="notebook|sim|FIT.json",
        help="the model under test: notebook (default: eq 9.1/9.2's structure refitted to each file), sim (the simulator "
        "calibrated to the first file; the effects found are carried into it as physics, it is recalibrated and "
        "re-measured, and its error before and after is reported) or a saved fit (fit.json from samii fit --out), held fixed",
    )
    add_model(
        parser,
        "with --baseline sim: the simulator to start from, a parameter file (samii calibrate --out writes one; default: the embedded model)",
        metavar="PARAMS.json",
    )
    parser.add_argument(
        "--record-s",
        type=positive_float,
        metavar="S",
        help="length of one repetition of the excitation in the time series [s] (default: the file's record_s, else found from r)",
    )
    add_band(parser, "frequency band (default: a time series' start_hz/stop_hz or 0.1-40 Hz; an FRF file's whole span)")
    parser.add_argument("--mat-freq-name", metavar="NAME", default=None, help="name of the frequency vector in a .mat file")
    parser.add_argument("--mat-freq-unit", choices=("hz", "rad/s"), default="hz", help="unit of that vector (default hz)")
    add_out(parser, "write diagnosis.json, residuals.png and bode.png here")
    add_rerun(
        parser,
        "with --baseline sim: also write a Rerun recording of the simulator against the data: each file's "
        "record beside the simulator measured like it before and after the effects were carried (3D with the "
        "beam's deflection magnified, signals by unit; the file must not exist unless --overwrite)",
    )
    add_overwrite(parser, "replace files already in --out (and --rerun)")
    add_json(parser, "print the diagnosis as JSON (numbers not defined are null)")
    add_no_progress(parser)


def _fmt(value: float, se: float, unit: str) -> str:
    import math

    scale, shown = (1e3, "ms") if unit == "s" else (1.0, unit)
    v = value * scale
    err = "" if not math.isfinite(se) else f" ± {se * scale:.2g}"
    return f"{v:.4g}{err} {shown if shown != '1' else ''}".rstrip()


def run(args: argparse.Namespace) -> int:
    from samii.cli_progress import Bar
    from samii.diagnose.files import DiagnoseRequest, diagnose_files

    request = DiagnoseRequest(
        baseline=args.baseline,
        model=args.model,
        band_hz=tuple(args.band_hz) if args.band_hz else None,
        record_s=args.record_s,
        mat_freq_name=args.mat_freq_name,
        mat_freq_unit=args.mat_freq_unit,
    )
    bar = Bar(
        "samii diagnose", unit="fit", disable=args.no_progress or None, delay=1.0, leave=False, bar_format="{desc}: {n} fits {elapsed}{postfix}"
    )
    with bar:
        done = diagnose_files(args.data, request, out=args.out, rerun=args.rerun, rerun_fps=args.rerun_fps, overwrite=args.overwrite, progress=bar)
    if args.json:
        from samii.json_output import dumps
        from samii.schema import document

        print(dumps(document(done.record), indent=2))  # what diagnosis.json holds
        return 0
    _print(done.diagnosis, done.written)
    return 0


def _print(d, written) -> None:
    import numpy as np

    from samii.diagnose.residuals import BAND_POINTS, band_tested, even_misfit
    from samii.diagnose.select import theta_usable
    from samii.frequency_response import CHANNEL_NAMES as _NAMES
    from samii.measure.frf_variance import MAX_VAR

    print(f"samii diagnose: {len(d.measured)} file(s) against {d.baseline.label}")
    for m, ds in zip(d.measured, d.datasets):
        lay = "" if m.layout is None else f"; {m.layout.n_records} records of {m.layout.record_s:.6g} s ({m.layout.how})"
        amp = "" if m.amplitude_v is None else f", {m.amplitude_v:.3g} V"
        print(f"  {m.source}{amp}{lay}; noise: {m.noise_source}")
        empty = [_NAMES.get(ch, ch) for ch, k in ds.keep.items() if not k.any()]
        if empty:
            print(
                f"  {m.source}: no usable point in {', '.join(empty)} (its relative error, noise and floor, is over "
                f"{np.sqrt(MAX_VAR):.2g} at every point)"
            )
        if m.floor is not None and m.floor.noise_free:
            print(
                f"  NO NOISE in {m.source}: its records repeat exactly (a simulation without noise?), so it is judged against "
                "the stated floor alone (above), not against a noise it does not have: chi2 is per the floor, not per the noise"
            )
    if not theta_usable(d.datasets):
        print(
            "  no point with theta in it is usable: in xdd/v alone an actuator, a base and a sensor effect multiply the same "
            "response, so no effect can be placed (every candidate is refused; what the model misses is left unexplained)"
        )
    print(f"rule: {d.rule}")
    real = [e for e in d.effects if not e.expected]
    sim = d.simulator.verdict_text() if d.simulator is not None else ""
    if not d.effects:
        if d.simulator is not None and d.simulator.unattributed:
            why = "no effect of the library is attributed, and a residual beyond the noise remains (unexplained, below)"
        elif d.unexplained:
            why = "no effect of the library is needed, but a residual beyond the noise remains (unexplained, below)"
        elif left := even_misfit(d.error_after):
            said = ", ".join(f"{_NAMES.get(c, c)} {v:.3g}" for c, v in left.items())
            why = (
                f"no effect of the library is needed, but the residual stays above the noise (chi2 per residual {said}) "
                "evenly, with no band standing out: the noise these data are judged against is too small for them, or the "
                "baseline misses everywhere alike; not explained"
            )
        elif not band_tested(d.error_after):
            most = max((e.n_points for e in d.error_after.values()), default=0)
            why = (
                f"the baseline fits the data to within their noise, but on {most} usable point(s) a channel at most, too few "
                f"to look for a band of misfit ({2 * BAND_POINTS}): little is tested"
            )
        else:
            why = "the baseline explains the data to within their noise"
        print("verdict: none: " + why + (f"; {sim}" if sim else ""))
    else:
        left = ", but a residual beyond the noise remains (unexplained, below)" if d.unexplained and not real else ""
        if real and not d.unexplained and even_misfit(d.error_after):
            left = ", but the residual stays above the noise after them (note below)"
        print(
            f"verdict: {d.verdict}"
            + (f": {len(real)} effect(s) the model lacks{left}" if real else f": only what sampling explains{left}")
            + (f"; {sim}" if sim else "")
        )
    from samii.diagnose.effects import LIBRARY
    from samii.diagnose.nonlinear import PARAM_UNITS

    units = {k.label: {p.name: p.unit for p in k.params} for k in LIBRARY}
    for e in d.effects:
        label = f"{e.category}/{e.kind}"
        vals = ", ".join(f"{n} {_fmt(v, e.stderr.get(n, float('nan')), units.get(label, PARAM_UNITS).get(n, '1'))}" for n, v in e.params.items())
        print(f"  {'(expected) ' if e.expected else ''}{label} [{e.channel}]: {vals}")
        print(f"      {e.evidence}")
    print("error: rms dB / rms deg / chi2 per residual (1 = at the noise), before -> after")

    def chi2(v):
        return f"{v:9.3g}" if v is not None else "  unknown"

    for ch, before in d.error_before.items():
        after = d.error_after[ch]
        print(
            f"  {_NAMES[ch]:>9}: {before.rms_db:7.3g} dB {before.rms_deg:7.3g} deg {chi2(before.chi2)}  ->  "
            f"{after.rms_db:7.3g} dB {after.rms_deg:7.3g} deg {chi2(after.chi2)}"
        )
    if d.harmonic_error is not None:
        hb, ha = d.harmonic_error
        print(
            f"  harmonics: {100 * hb.rms_ratio:7.3g} % of the fundamental, chi2 {hb.chi2:.3g}  ->  {100 * ha.rms_ratio:.3g} %, "
            f"chi2 {ha.chi2:.3g} with the law ({hb.n_segments} segment harmonics; a linear model makes none)"
            + ("; the law predicts harmonics the data do not have: its level is not to be used" if ha.chi2 > hb.chi2 else "")
        )
    if d.simulator is not None:
        s = d.simulator
        print(f"simulator: carried {', '.join(s.carried) if s.carried else 'nothing'}; measured like the data, before -> after")
        for ch, before in s.error_before.items():
            after = s.error_after[ch]
            print(
                f"  {_NAMES[ch]:>9}: {before.rms_db:7.3g} dB {before.rms_deg:7.3g} deg {chi2(before.chi2)}  ->  "
                f"{after.rms_db:7.3g} dB {after.rms_deg:7.3g} deg {chi2(after.chi2)}"
            )
        for name, value in s.changes.items():
            print(f"  {name} = {value:.6g}")
        for label, misfit in (("before anything was carried it missed", s.misfit_before), ("it cannot represent the data at", s.misfit_after)):
            if misfit:
                print(f"  {label}:")
                for m in misfit:
                    print(f"    {m.source}: {m.text()}")
        if s.worse:
            print(f"  worse after the carry: {', '.join(s.worse)}")
    if d.refused:
        print("refused: passed the F-test, but the data do not show them:")
        for r in d.refused:
            vals = ", ".join(f"{n} {v:.4g}" for n, v in r["params"].items())
            print(f"  round {r['round']}: {r['effect']} ({vals}): {r['reason']}")
    if d.unexplained:
        print("unexplained: a significant residual that nothing in the library explains:")
        for b in d.unexplained:
            why = "" if b.why == "residual" else f" ({b.why}: the rig changed during the file)"
            print(f"  {b.source}: {_NAMES[b.channel]} {b.lo_hz:.3g}-{b.hi_hz:.3g} Hz, chi2 {b.chi2:.3g} over {b.n_points} points{why}")
    for n in d.notes:
        print(f"note: {n}")
    from samii.outputs import with_size

    for p in written:
        print(f"wrote {with_size(p)}")
