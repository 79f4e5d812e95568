"""``samii`` and ``samii run``: the whole pipeline on one model, into one output folder, with a short summary.

``samii`` with no arguments runs it on the embedded default model into ``./samii_run``;
``samii run [--out DIR] [--model XML] [--set NAME=VALUE ...] [--seed S]`` on a user's model. The pipeline
is :func:`samii.pipeline.run` (its stages and the folder it writes are described there); this module parses the
options, shows the stages' progress and prints the summary.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from samii.cli_args import add_model, add_no_progress, add_out, add_overwrite, add_seed, add_set

__all__ = ["add_arguments", "run", "run_main_job", "DEFAULT_OUT"]

#: Where ``samii`` with no arguments writes.
DEFAULT_OUT = "samii_run"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_out(parser, f"output folder (default ./{DEFAULT_OUT}); replaced whole at the end", default=DEFAULT_OUT)
    add_model(
        parser,
        "MJCF or parameter .json file (samii calibrate --out writes one, samii diagnose --baseline sim --out its simulator_params.json; default: the embedded model)",
    )
    add_set(parser, "override a model parameter (samii params lists them); repeatable")
    add_seed(parser, "seed of the measurement's sensor noise (default 0): the same seed gives the same outputs")
    add_overwrite(parser, "replace --out if it exists (a previous main job's output is replaced anyway)")
    add_no_progress(parser)


def run(args: argparse.Namespace) -> int:
    from samii.cli_progress import Bar
    from samii.pipeline import run as run_pipeline
    from samii.run_summary import summary_lines

    bar = Bar("samii", unit="stage", leave=False, disable=args.no_progress or None, bar_format="{desc}: {n}/{total} stages {elapsed} {postfix}")
    with bar:
        result = run_pipeline(
            args.out,
            model=args.model,
            overrides=args.set,
            seed=args.seed,
            overwrite=args.overwrite,
            progress=bar,
            argv=sys.argv[1:],
            note=lambda text: print(f"samii run: {text}", file=sys.stderr),
        )
    print("\n".join(summary_lines(result.summary, Path(args.out))))
    return 0


def run_main_job() -> int:
    """``samii`` with no arguments: the pipeline on the embedded model into ``./samii_run``."""
    return run(argparse.Namespace(out=DEFAULT_OUT, model=None, set=[], seed=0, overwrite=False, no_progress=False))
