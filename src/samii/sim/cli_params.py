"""``samii params``: the model parameters ``--set NAME=VALUE`` accepts, with their values and units."""

from __future__ import annotations

import argparse
import json

from samii.cli_args import add_json, add_model
from samii.sim.param_units import parameter_table

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_model(p, "a parameter file (samii calibrate writes them; default: the embedded model's)", metavar="PARAMS.json")
    add_json(p, "print machine-readable JSON")


def run(args: argparse.Namespace) -> int:
    from samii.errors import InputError

    if args.model and not str(args.model).lower().endswith(".json"):
        raise InputError(f"--model {args.model}: samii params lists a parameter file (.json); an MJCF file holds its physics in the XML")
    rows = parameter_table(args.model)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"parameters of {args.model or 'the embedded default model'} (override any with --set NAME=VALUE):")
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        print(f"  {r['name']:<{width}}  {r['value']:<12.6g}  {r['unit']}")
    return 0
