"""The ``samii`` command: a thin layer over the library.

Each subcommand lives in its stage's ``cli`` module, which defines
``add_arguments(parser)`` and ``run(args) -> int`` and imports nothing heavy at
module level. With no subcommand, ``samii`` runs the main job on the embedded
default model.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# subcommand -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "modes": ("samii.sim.cli_modes", "linearise the simulator at the nominal pose and print its modes"),
    "simulate": ("samii.sim.cli_simulate", "run the simulator with a valve command and write the sensor signals"),
    "measure": ("samii.measure.cli", "swept- or stepped-sine Bode measurement in the simulator"),
    "fit": ("samii.identify.cli", "fit the notebook's transfer-function models to an FRF file"),
    "calibrate": ("samii.calibrate.cli", "calibrate the simulator's physical parameters to FRF data"),
    "design": ("samii.design.cli", "control design: root loci, pole placement, pole cancellation, seed report"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="samii",
        description="SAMII: a hydraulic arm on a flexible cantilevered beam, simulated in MuJoCo. "
        "With no subcommand, runs the main job on the embedded default model.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:  # stage not built yet
            if exc.name != module:
                raise
            continue
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        from samii.main_job import run_main_job

        return run_main_job()
    return int(args._run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
