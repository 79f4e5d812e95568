"""The units of the model's parameter names (SI), and the table of a model's parameters with them (``samii params``)."""

from __future__ import annotations

__all__ = ["unit", "parameter_table"]

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
    from samii.sim.model import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
        default_params,
        dotted,
        read_params_file,
    )

    params = read_params_file(model) if model else default_params()
    return [{"name": name, "value": v, "unit": unit(name)} for name, v in dotted(params).items()]
