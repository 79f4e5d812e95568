"""``samii fit FRF``: fit the notebook's models to a frequency-response file (CSV or rig-era .mat).

Every option is checked when the command line is parsed (``samii.cli_args``);
the output folder (``--out``) is checked before any work and written all or
nothing (``samii.outputs.OutputFolder``). Input a user can fix raises
:class:`samii.errors.InputError` naming the file or the option: one line on
stderr, exit code 2. Long fits show their progress on stderr (a terminal
only; ``--no-progress`` turns it off).

Imports nothing heavy at module level (the ``samii`` command imports every
stage's cli module to build its help).
"""

from __future__ import annotations

import argparse

from samii.cli_args import add_band, add_json, add_no_progress, add_out, add_overwrite, float_in, int_in, nonempty_path
from samii.identify.concerns import COMMAND_LINE

__all__ = ["add_arguments", "run", "MAX_MODES", "MAX_PHASE_WEIGHT", "MAX_PHASE_WEIGHTS", "MAX_AVERAGES"]

#: Most base modes: each adds three parameters, and a swept sine over 0.1-40 Hz shows about three.
MAX_MODES = 10
#: Largest phase weight: at 100 one degree of phase error counts as 100 dB, and the magnitude no longer counts.
MAX_PHASE_WEIGHT = 100.0
#: Most fits of one ``--phase-weights`` sweep (chapter 9 swept 6).
MAX_PHASE_WEIGHTS = 20
#: Most averages behind a coherence (a swept sine has a few; a random test some hundreds).
MAX_AVERAGES = 10000
#: Seconds a fit runs before its progress is shown.
PROGRESS_DELAY_S = 1.0

_phase_weight = float_in(0.0, MAX_PHASE_WEIGHT)


def _phase_weights(text: str) -> list[float]:
    """Comma-separated phase weights, each in 0...MAX_PHASE_WEIGHT, no two writing the same file."""
    cells = [c.strip() for c in text.split(",") if c.strip()]
    if not cells:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers like 0,0.1,0.2, got {text!r}")
    if len(cells) > MAX_PHASE_WEIGHTS:
        raise argparse.ArgumentTypeError(f"expected at most {MAX_PHASE_WEIGHTS} weights (one fit each), got {len(cells)}")
    values = [_phase_weight(c) for c in cells]  # ArgumentTypeError names the bad one
    names = [f"{v:g}" for v in values]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"weight {', '.join(twice)} given twice; expected different weights (each writes fit_pw<W>.json)")
    return values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "frf",
        metavar="FRF",
        type=nonempty_path,
        help="frequency response: a CSV (DATA_FORMATS.md: freq_hz, act and/or base channels, optional coherence) "
        "or a rig-era MATLAB .mat (the notebook's mean_io_mr/_ph, mean_a2_j2a_mr/_ph)",
    )
    parser.add_argument(
        "--modes",
        type=int_in(1, MAX_MODES),
        default=3,
        metavar="N",
        help=f"number of base modes, 1-{MAX_MODES} (default 3, eq 9.2; 2 is eq 1.2 with B_k w_k^2 gains)",
    )
    parser.add_argument(
        "--numerator", choices=("s4", "s2"), default="s4", help="power of s in front of xdd/theta's modal sum (default s4, chapter 2)"
    )
    g = parser.add_mutually_exclusive_group()
    g.add_argument(
        "--phase-weight",
        type=_phase_weight,
        default=None,
        metavar="W",
        help=f"weight on the phase error in degrees, 0-{MAX_PHASE_WEIGHT:g} (default 0.1, the notebook's eq 9.4)",
    )
    g.add_argument(
        "--phase-weights",
        type=_phase_weights,
        default=None,
        metavar="W1,W2,...",
        help=f"one fit per weight, at most {MAX_PHASE_WEIGHTS} (chapter 9 swept 0,0.1,0.2,0.3,0.4,0.5)",
    )
    add_band(parser, "fit only LO <= f <= HI Hz (eq 1.4 used 1 12)")
    parser.add_argument(
        "--start",
        choices=("notebook", "auto"),
        default=None,
        help="notebook: frequencies/dampings of eq 9.4 (or eq 1.4 for 2 modes) with gains read off the data; "
        "auto: everything read off the data's peaks and notches. Default: both, plus two perturbed starts",
    )
    parser.add_argument(
        "--weighting",
        choices=("auto", "none", "coherence"),
        default="auto",
        help="none: the notebook's cost (every point counts alike); coherence: each point weighted by the inverse of "
        "the random error its coherence predicts (Bendat & Piersol), so badly measured points count less, needs *_coh columns; "
        "auto (default): coherence when the file has it for every fitted channel, else none",
    )
    parser.add_argument(
        "--profiles",
        choices=("auto", "on", "off"),
        default="auto",
        help="profile intervals of the frequencies (each held away from its estimate, the rest re-solved): "
        "auto (default) on data of at most 1000 points, where they cost about as much as the fit; "
        "on: also on larger data (an FFT's 10,000 lines: about 1 s more)",
    )
    parser.add_argument(
        "--averages",
        type=int_in(1, MAX_AVERAGES),
        default=None,
        metavar="N",
        help="averages behind the coherence, for the lack-of-fit test (default: the file's frf_records, else 3)",
    )
    parser.add_argument(
        "--mat-freq-name",
        metavar="NAME",
        default=None,
        help="name of the frequency vector in a .mat file (default: the first of freq_hz, freq, f, frequency, hz, fr, ...)",
    )
    parser.add_argument("--mat-freq-unit", choices=("hz", "rad/s"), default="hz", help="unit of that vector (default hz)")
    add_out(parser, "write fit.json (fit_pw<W>.json per weight), bode_fit.png and, for --phase-weights, parameters.png here")
    add_overwrite(parser, "replace files already in --out")
    add_json(
        parser,
        "print machine-readable results (one object, or a list for --phase-weights); numbers that are not "
        "defined (a parameter not fitted, the infinite standard error of one the data do not determine) are null",
    )
    add_no_progress(parser)


def run(args: argparse.Namespace) -> int:
    from samii.cli_progress import Bar
    from samii.identify.fit_file import FitRequest, fit_frf_file
    from samii.identify.report import json_text, summary_dict

    weights = args.phase_weights if args.phase_weights is not None else [0.1 if args.phase_weight is None else args.phase_weight]
    request = FitRequest(
        n_modes=args.modes,
        numerator=args.numerator,
        phase_weights=tuple(weights),
        band_hz=tuple(args.band_hz) if args.band_hz else None,
        weighting=args.weighting,
        start=args.start or "both",
        averages=args.averages,
        profiles=args.profiles,
        mat_freq_name=args.mat_freq_name,
        mat_freq_unit=args.mat_freq_unit,
    )
    bar = Bar(
        f"samii fit {args.frf}",
        unit="fit",
        total=len(weights),
        disable=args.no_progress or None,
        delay=PROGRESS_DELAY_S,
        leave=False,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}{postfix}",
    )
    with bar:
        fitted = fit_frf_file(args.frf, request, out=args.out, overwrite=args.overwrite, progress=bar)
    data, structure, results, written = fitted.data, fitted.structure, fitted.results, fitted.written
    if args.json:
        out = [summary_dict(r) for r in results]
        print(json_text(out[0] if len(out) == 1 else out))
        return 0
    r0 = results[0]
    weighting = {
        "coherence": "coherence (points weighted by their predicted random error)",
        "scatter": "the data's scatter (points weighted by the random error read off their roughness about the fit)",
    }.get(r0.weighting, "none (the notebook's cost)")
    if args.weighting == "auto":
        weighting += ", chosen by --weighting auto" + {
            "coherence": "",
            "scatter": " (the file has no coherence, and the notebook's cost gave a fit that was not sound)",
        }.get(r0.weighting, " (the file has no coherence for every fitted channel)")
    print(
        f"samii fit: {args.frf}: {structure.describe()}; band {r0.band_hz[0]:.3g}-{r0.band_hz[1]:.3g} Hz, {r0.n_points} points, channels {', '.join(r0.channels)}; weighting {weighting}"
    )
    missing = [c for c in ("act", "base") if c not in data.channels]
    if r0.not_fitted:
        print(f"samii fit: {args.frf} has no {' or '.join(missing)} channel: {', '.join(r0.not_fitted)} not fitted")
    for r in results:
        verdict = (
            "yes"
            if r.verdict == "sound"
            else "yes, a sound fit with caveats (below)"
            if r.verdict == "caveats"
            else "yes, BUT NOT A SOUND FIT (below)"
            if r.converged
            else "NO"
        )
        print(f"\nphase weight {r.phase_weight:g}: cost {r.cost:.6g}, converged {verdict}")
        print(r.table())
        rms = ", ".join(f"{c} {r.rms_mag_db[c]:.3g} dB / {r.rms_phase_deg[c]:.3g} deg" for c in r.channels)
        print(f"RMS error: {rms}")
        if r.lack_of_fit is not None:
            lof = r.lack_of_fit
            ratio = ", ".join(f"{c} {v:.3g}" for c, v in lof.noise_ratio.items() if v is not None)
            print(
                f"lack of fit: {lof.verdict()} (rule: {lof.rule}; averages: {lof.n_averages_source})"
                + (f"; RMS residual / random error: {ratio}" if ratio else "")
            )
        print(r.message)
        for w in r.warnings:
            print(f"warning: {w}")
        if not r.sound:
            print(
                f"NOT A SOUND FIT{'' if r.converged else ' (and not converged)'}: its parameters should not be used"
                + (":" if r.concerns else " (the solver stopped before a minimum)")
            )
            for c in r.concerns:
                print(f"  !! {c.words(COMMAND_LINE)}")
        if r.caveats:
            said = f" but {', '.join(r.undetermined)}, which the data do not determine" if r.undetermined else ""
            print(f"caveats (the parameters can be used{said}):")
            for c in r.caveats:
                print(f"  - {c.words(COMMAND_LINE)}")
    for p in written:
        print(f"wrote {p}")
    return 0
