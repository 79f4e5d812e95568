"""``samii fit FRF.csv``: fit the notebook's models to a frequency-response file.

Imports nothing heavy at module level (the ``samii`` command imports every
stage's cli module to build its help).
"""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["add_arguments", "run"]


def _weights(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers like 0,0.1,0.2, got {text!r}") from None
    if not values or any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected non-negative phase weights, got {text!r}")
    return values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("frf", metavar="FRF.csv", help="frequency-response CSV (DATA_FORMATS.md): act and/or base channels, optional coherence")
    parser.add_argument("--modes", type=int, default=3, metavar="N", help="number of base modes (default 3, eq 9.2; 2 is eq 1.2 with B_k w_k^2 gains)")
    parser.add_argument("--numerator", choices=("s4", "s2"), default="s4", help="power of s in front of xdd/theta's modal sum (default s4, chapter 2)")
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--phase-weight", type=float, default=None, metavar="W", help="weight on the phase error in degrees (default 0.1, the notebook's eq 9.4)")
    g.add_argument("--phase-weights", type=_weights, default=None, metavar="W1,W2,...", help="one fit per weight (chapter 9 swept 0,0.1,0.2,0.3,0.4,0.5)")
    parser.add_argument("--band-hz", type=float, nargs=2, metavar=("LO", "HI"), help="fit only LO <= f <= HI Hz (eq 1.4 used 1 12)")
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
    parser.add_argument("--averages", type=int, default=None, metavar="N", help="averages behind the coherence, for the lack-of-fit test (default: the file's frf_records, else 3)")
    parser.add_argument("--out", metavar="DIR", help="write fit JSON and overlay Bode plots here")
    parser.add_argument("--overwrite", action="store_true", help="replace files already in --out")
    parser.add_argument("--json", action="store_true", help="print machine-readable results (one object, or a list for --phase-weights)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from samii.identify.fit import fit
    from samii.identify.report import summary_dict, write_fit_outputs
    from samii.identify.structures import ModelStructure
    from samii.measure.io import read_frf_csv

    weights = args.phase_weights if args.phase_weights is not None else [0.1 if args.phase_weight is None else args.phase_weight]
    try:
        if args.phase_weight is not None and args.phase_weight < 0:
            raise ValueError(f"--phase-weight must be >= 0, got {args.phase_weight}")
        if args.averages is not None and args.averages < 1:
            raise ValueError(f"--averages must be >= 1, got {args.averages}")
        structure = ModelStructure(n_modes=args.modes, numerator=args.numerator)
        data = read_frf_csv(args.frf)
        if args.weighting == "coherence":
            lacking = [c for c in data.channels if data.coherence(c) is None]
            if lacking:
                raise ValueError(f"{args.frf}: --weighting coherence needs coherence, but channel(s) {', '.join(lacking)} have no *_coh column")
        rng = np.random.default_rng(0)
        band = tuple(args.band_hz) if args.band_hz else None
        results = [fit(data, structure, phase_weight=w, band_hz=band, weighting=args.weighting, start=args.start or "both", rng=rng, n_averages=args.averages) for w in weights]
        written = write_fit_outputs(data, results, args.out, overwrite=args.overwrite, note=f"data: {args.frf}") if args.out else []
    except (OSError, ValueError, KeyError) as exc:  # DataFormatError is a ValueError
        print(f"samii fit: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        out = [summary_dict(r) for r in results]
        print(json.dumps(out[0] if len(out) == 1 else out, indent=2))
        return 0
    r0 = results[0]
    weighting = "coherence (points weighted by their predicted random error)" if r0.weighting == "coherence" else "none (the notebook's cost)"
    if args.weighting == "auto":
        weighting += ", chosen by --weighting auto" + ("" if r0.weighting == "coherence" else " (the file has no coherence for every fitted channel)")
    print(f"samii fit: {args.frf}: {structure.describe()}; band {r0.band_hz[0]:.3g}-{r0.band_hz[1]:.3g} Hz, {r0.n_points} points, channels {', '.join(r0.channels)}; weighting {weighting}")
    missing = [c for c in ("act", "base") if c not in data.channels]
    if r0.not_fitted:
        print(f"samii fit: {args.frf} has no {' or '.join(missing)} channel: {', '.join(r0.not_fitted)} not fitted")
    for r in results:
        verdict = "yes" if r.sound else ("yes, BUT NOT A SOUND FIT (below)" if r.converged else "NO")
        print(f"\nphase weight {r.phase_weight:g}: cost {r.cost:.6g}, converged {verdict}")
        print(r.table())
        rms = ", ".join(f"{c} {r.rms_mag_db[c]:.3g} dB / {r.rms_phase_deg[c]:.3g} deg" for c in r.channels)
        print(f"RMS error: {rms}")
        if r.lack_of_fit is not None:
            lof = r.lack_of_fit
            ratio = ", ".join(f"{c} {v:.3g}" for c, v in lof.noise_ratio.items() if v is not None)
            print(f"lack of fit: {'FOUND' if lof.found else 'none'} (rule: {lof.rule}; averages: {lof.n_averages_source})" + (f"; RMS residual / random error: {ratio}" if ratio else ""))
        print(r.message)
        for w in r.warnings:
            print(f"warning: {w}")
        if r.concerns:
            print(f"NOT A SOUND FIT{'' if r.converged else ' (and not converged)'}: do not take these parameters at face value:")
            for c in r.concerns:
                print(f"  !! {c}")
    for p in written:
        print(f"wrote {p}")
    return 0
