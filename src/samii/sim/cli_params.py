"""``samii params``: the model parameters ``--set NAME=VALUE`` accepts, with their values and units."""

from __future__ import annotations

import argparse
import json

from samii.cli_args import add_json, add_model

__all__ = ["add_arguments", "run", "parameter_table", "unit"]

#: Units of the names that do not carry them in a suffix (SI; see samii.sim.mjcf and sim/hydraulic.c).
_UNITS = {
    "hydraulic.supply_pressure": "Pa",
    "hydraulic.bulk_modulus": "Pa",
    "hydraulic.total_volume": "m³",
    "hydraulic.displacement": "m³/rad",
    "hydraulic.leakage_coefficient": "m³/(s Pa)",
    "hydraulic.valve_time_constant": "s",
    "hydraulic.rated_flow": "m³/s",
    "hydraulic.rated_voltage": "V",
    "hydraulic.position_gain": "V/rad",
    "hydraulic.reference_angle": "rad",
    "hydraulic.command_delay": "s",
    "hydraulic.valve_dead_band": "V",
    "hydraulic.valve_saturation": "V",
    "hydraulic.valve_asymmetry": "1",
    "sensor.accel_gain": "1",
    "beam.n_segments": "-",
    "beam.accel_body_fixed": "0 or 1",
    "beam.section_side_m": "m",
    "beam.tip_body_damping_ratio": "1",
}
_SUFFIX_UNITS = {
    "_hz": "Hz",
    "_m": "m",
    "_Nm2": "N m²",
    "_kg_m": "kg/m",
    "_Nm_rad": "N m/rad",
    "_Nms_rad": "N m s/rad",
    "_s": "s",
    "_deg": "deg",
    "_kgm2": "kg m²",
    "_kg": "kg",
}


def unit(name: str) -> str:
    """The unit of a parameter name (SI; "" when it has none)."""
    if name in _UNITS:
        return _UNITS[name]
    for suffix, u in sorted(_SUFFIX_UNITS.items(), key=lambda kv: -len(kv[0])):
        if name.endswith(suffix):
            return u
    return ""


def parameter_table(model: str | None = None) -> list[dict]:
    """``[{"name", "value", "unit"}]`` for the embedded default (or a parameter file's) parameters."""
    from samii.sim.model import default_params, dotted, read_params_file

    params = read_params_file(model) if model else default_params()
    return [{"name": name, "value": v, "unit": unit(name)} for name, v in dotted(params).items()]


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
