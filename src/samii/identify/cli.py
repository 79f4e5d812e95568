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
import sys
from pathlib import Path

from samii.cli_args import add_band, add_json, add_no_progress, add_out, add_overwrite, float_in, int_in, nonempty_path
from samii.errors import InputError, input_error_of

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


# --------------------------------------------------------------------------- reading the file


def _csv_line_of_row(path: Path, row: int) -> int | None:
    """1-based file line of data row ``row`` (0-based) of a CSV read by ``read_frf_csv``."""
    seen_header = False
    k = -1
    with open(path, encoding="utf-8", errors="replace", newline=None) as fh:
        for number, line in enumerate(fh, start=1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            if not seen_header:
                seen_header = True
                continue
            k += 1
            if k == row:
                return number
    return None


def _read(args):
    """The file as a FrequencyResponse; InputError naming the file for anything a user can fix."""
    from samii.formats import DataFormatError, csv_header, is_mat_file, read_frf_csv, read_mat_bode
    from samii.identify.cost import frequency_out_of_range

    path = Path(args.frf)
    mat = is_mat_file(path)
    if mat:
        try:
            data = read_mat_bode(path, freq_name=args.mat_freq_name, freq_unit=args.mat_freq_unit)
        except DataFormatError as exc:  # the library names its arguments: name the options
            text = str(exc)
            if text.endswith("pass freq_name="):
                text = text[: -len("freq_name=")] + "--mat-freq-name NAME"
            elif "freq_unit" in text:
                text += " (samii fit: --mat-freq-unit rad/s)"
            raise InputError(text) from None
    else:
        given = [o for o, v in (("--mat-freq-name", args.mat_freq_name is not None), ("--mat-freq-unit", args.mat_freq_unit != "hz")) if v]
        if given:
            raise InputError(f"{' and '.join(given)}: only for a .mat file; {path} is read as an FRF CSV")
        try:
            data = read_frf_csv(path)
        except DataFormatError:
            header = csv_header(path)
            if "t" in header and "freq_hz" not in header:
                shown = ", ".join(header[:6]) + (", ..." if len(header) > 6 else "")
                raise InputError(
                    f"{path}: this is a time series (columns {shown}), not a frequency response; samii fit expects an FRF: "
                    "a CSV with freq_hz and <channel>_mag/<channel>_phase_deg columns (DATA_FORMATS.md, as samii measure "
                    "writes frf.csv) or a rig-era .mat"
                ) from None
            raise
    bad = frequency_out_of_range(data.freq_hz)
    if bad is not None:
        k, reason = bad
        if mat:
            where = f"{path}, variable {data.metadata.get('freq_vector', '?')!r}, element {k + 1}"
        else:
            line = _csv_line_of_row(path, k)
            where = f"{path}, line {line}, column 'freq_hz'" if line is not None else f"{path}, data row {k + 1}"
        raise InputError(f"{where}: {reason}")
    return data


# --------------------------------------------------------------------------- progress


class _Progress:
    """Progress of the whole command on stderr: a terminal only, and only once the run has taken PROGRESS_DELAY_S."""

    def __init__(self, label: str, n_fits: int, *, enabled: bool):
        import time

        from tqdm import tqdm

        self._clock = time.monotonic
        self._start = self._clock()
        self.fit_index = 0
        self.bar = tqdm(
            total=n_fits,
            desc=label,
            unit="fit",
            delay=PROGRESS_DELAY_S,
            leave=False,
            file=sys.stderr,
            dynamic_ncols=True,
            disable=None if enabled else True,
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}{postfix}",
        )

    def _show(self, what: str) -> None:
        self.bar.set_postfix_str(what, refresh=False)
        if self._clock() - self._start >= PROGRESS_DELAY_S:
            self.bar.refresh()

    def stage(self, what: str) -> None:
        self._show(what)

    def fit_step(self, done: int, total: int, what: str) -> None:
        """``fit``'s progress callback: stage ``done`` of ``total`` of the current fit (``done`` repeats within a long stage)."""
        self.bar.n = self.fit_index + done / total
        self._show(what)

    def next_fit(self) -> None:
        self.fit_index += 1

    def close(self) -> None:
        self.bar.close()


# --------------------------------------------------------------------------- the command


def run(args: argparse.Namespace) -> int:
    weights = args.phase_weights if args.phase_weights is not None else [0.1 if args.phase_weight is None else args.phase_weight]
    folder = None
    if args.out is not None:
        from samii.identify.report import fit_output_names
        from samii.outputs import OutputFolder

        folder = OutputFolder(args.out, fit_output_names(weights), overwrite=args.overwrite)

    import numpy as np

    from samii.identify.fit import check_not_noise, fit
    from samii.identify.report import json_text, summary_dict, write_fit_outputs
    from samii.identify.structures import ModelStructure

    progress = _Progress(f"samii fit {args.frf}", len(weights), enabled=not args.no_progress)
    try:
        progress.stage("reading")
        data = _read(args)
        structure = ModelStructure(n_modes=args.modes, numerator=args.numerator)
        if args.weighting == "coherence":
            lacking = [c for c in data.channels if data.coherence(c) is None]
            if lacking:
                raise InputError(f"{args.frf}: --weighting coherence needs coherence, but channel(s) {', '.join(lacking)} have no *_coh column")
        band = tuple(args.band_hz) if args.band_hz else None
        if band is not None and not np.any((data.freq_hz >= band[0]) & (data.freq_hz <= band[1])):
            raise InputError(
                f"{args.frf}: --band-hz {band[0]:g} {band[1]:g}: no frequency point in the band (the data span "
                f"{data.freq_hz[0]:g}-{data.freq_hz[-1]:g} Hz)"
            )
        rng = np.random.default_rng(0)
        try:  # noise: refused before any work, as calibrate and diagnose refuse it (a fit of it converged to "a sound fit")
            check_not_noise(data, structure, band_hz=band)
        except ValueError as exc:
            raise input_error_of(args.frf, exc) from None
        results = []
        for w in weights:
            try:
                results.append(
                    fit(
                        data,
                        structure,
                        phase_weight=w,
                        band_hz=band,
                        weighting=args.weighting,
                        start=args.start or "both",
                        rng=rng,
                        n_averages=args.averages,
                        progress=progress.fit_step,
                        profile={"auto": "auto", "on": True, "off": False}[args.profiles],
                    )
                )
            except np.linalg.LinAlgError:
                raise  # numerical trouble: a defect, reported as an internal error
            except (ValueError, KeyError) as exc:  # the data cannot be fitted as asked (InputError included)
                raise input_error_of(args.frf, exc) from None
            progress.next_fit()
        if folder is not None:
            progress.stage("writing plots")
            with folder:
                write_fit_outputs(data, results, folder, note=f"data: {args.frf}")
    finally:
        progress.close()
    written = folder.written if folder is not None else []
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
                print(f"  !! {c}")
        if r.caveats:
            said = f" but {', '.join(r.undetermined)}, which the data do not determine" if r.undetermined else ""
            print(f"caveats (the parameters can be used{said}):")
            for c in r.caveats:
                print(f"  - {c}")
    for p in written:
        print(f"wrote {p}")
    return 0
