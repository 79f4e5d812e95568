"""The command line the experiment scripts share (``experiments/*/run.py``): ``[--data FRF.csv] [--out DIR]``."""

from __future__ import annotations

from samii.identify.studies import study_data

__all__ = ["study_setup"]


def study_setup(description: str, default_out) -> tuple:
    """Command line shared by the experiment scripts: ``[--data FRF.csv] [--out DIR]``.

    Returns (out folder, created; data; noise-free data or None; note for the figures).
    """
    import argparse
    from pathlib import Path

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--data", help="FRF CSV to use instead of the synthetic stand-in")
    ap.add_argument("--out", default=Path(default_out), type=Path, help=f"output folder (default {default_out})")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    return (args.out, *study_data(args.data))
