"""``samii calibrate``'s library call: the simulator's physics fitted to an FRF file (or the notebook's eq 9.4 curves),
its outputs written into a folder all or nothing.

:func:`load_target` reads what a calibration is fitted to; :func:`calibrate_file` checks a :class:`CalibrateRequest`
(the parameter names against the model, the channels against the data, before the fit), runs
:func:`samii.calibrate.calibrate.calibrate` and, with ``out``, writes ``calibration.json``, ``calibrated_params.json``
(a parameter file for ``--model``) and ``calibration_bode.png``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from samii import notebook as nb
from samii.calibrate.calibrate import calibrate
from samii.calibrate.simulator import SimulatorFRF, check_parameter_name
from samii.errors import InputError, input_error_of
from samii.formats import is_mat_file, read_frf_csv, read_mat_bode, write_text
from samii.frequency_response import CHANNELS, FrequencyResponse
from samii.identify.structures import ModelStructure
from samii.measure.excitation import SweptSine
from samii.outputs import OutputFolder
from samii.sim.model import default_params, params_with_overrides, read_params_file
from samii.sim.overrides import as_overrides
from samii.viz.figures import pyplot, save_figure
from samii.viz.fit_plot import plot_fit_overlay

__all__ = ["CalibrateRequest", "Calibrated", "calibrate_file", "load_target", "OUTPUTS", "NOTEBOOK_TARGETS"]

#: Output files written into ``out``.
OUTPUTS = ("calibration.json", "calibrated_params.json", "calibration_bode.png")
#: Named model curves that can stand in for data.
NOTEBOOK_TARGETS = ("eq9.4",)


@dataclass(frozen=True)
class CalibrateRequest:
    """What ``samii calibrate`` is asked (its options, by the same names)."""

    params: Sequence[str]  #: dotted names to calibrate (gain.base / gain.act for a sensor of unknown unit)
    start: Mapping[str, float] = field(default_factory=dict)
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    phase_weight: float = 0.1
    band_hz: tuple[float, float] | None = None
    channels: str | Sequence[str] | None = None  #: "act,base" or names; None: act and base where the data have them
    weighting: str = "auto"  #: auto, none or coherence
    model: str | Path | None = None  #: a parameter file (.json) to start from; None: the embedded model
    overrides: Sequence[str] | Mapping[str, float] = ()  #: NAME=VALUE texts or a mapping, on the model, before calibrating
    max_iterations: int = 60
    confirm: bool = False  #: also measure the calibrated model with a swept sine in the nonlinear simulator


@dataclass(frozen=True)
class Calibrated:
    result: object  #: samii.calibrate.calibrate.CalibrationResult
    data: object  #: the FrequencyResponse it was fitted to
    written: tuple[Path, ...] = ()  #: the files written (with ``out``)


def load_target(source: str):
    """The FRF to calibrate to: a file, or the notebook's eq 9.4 curves in SI with theta in degrees.

    eq 9.4 was fitted to theta in degrees (unity feedback 1 V/deg gives its K1 = 27.9/s), so its
    theta/v is converted from deg/V to rad/V and its xdd/theta from per degree to per radian; its
    acceleration unit is not stated, so the base channel keeps that unknown factor.
    """

    if source.lower() in NOTEBOOK_TARGETS:
        from samii.measure.frf import log_frequency_grid  # (lazy: imports scipy, only when called)

        st = ModelStructure.notebook_3mode("s4")
        f = log_frequency_grid(0.1, 40.0, 100)
        deg = 180.0 / np.pi
        act = st.response(nb.EQ9_4, f, "act") / deg  # theta_deg / v -> theta_rad / v
        base = st.response(nb.EQ9_4, f, "base") * deg  # xdd / theta_deg -> xdd / theta_rad (xdd in the notebook's unit)
        return FrequencyResponse(
            f, act=act, base=base, metadata={"source": "notebook eq 9.4 over 0.1-40 Hz; theta in degrees converted to rad; acceleration unit unknown"}
        )
    path = Path(source)
    if not path.is_file():
        raise InputError(f"DATA {source!r}: no such file (DATA is an FRF CSV, a rig-era .mat, or one of {', '.join(NOTEBOOK_TARGETS)})")
    if path.suffix.lower() not in (".csv", ".mat", ".txt"):
        raise InputError(f"DATA {source}: expected an FRF CSV (docs/DATA_FORMATS.md) or a rig-era .mat, not a {path.suffix or 'suffix-less'} file")

    if is_mat_file(path):  # (the content decides: a text file named .mat is read as the CSV it is)
        return read_mat_bode(path)

    return read_frf_csv(path)


def _channels(asked: str | Sequence[str], data) -> tuple[str, ...]:
    """The channels asked for ("act,base" or names), checked against those a calibration can use and the data hold."""
    text = asked if isinstance(asked, str) else ",".join(asked)
    names = tuple(c.strip() for c in text.split(","))
    if not names or any(n not in CHANNELS for n in names) or len(set(names)) != len(names):
        raise InputError(f"--channels {text!r}: expected distinct names from {', '.join(CHANNELS)}, comma-separated")
    missing = [n for n in names if n not in data.channels]
    if missing:
        raise InputError(f"--channels {text!r}: the data have no {', '.join(missing)} channel (they hold {', '.join(data.channels)})")
    return names


def calibrate_file(source: str, request: CalibrateRequest, *, out=None, overwrite: bool = False) -> Calibrated:
    """Calibrate ``request.params`` to the FRF in ``source`` (a file, or ``eq9.4``); with ``out`` (a folder, checked
    before any work) its outputs written there. Every refusal an InputError naming the option or the file."""

    req = request
    folder = OutputFolder(out, OUTPUTS, overwrite=overwrite) if out else None
    if req.model is not None and Path(req.model).suffix.lower() != ".json":
        raise InputError(
            f"--model {req.model}: calibrate needs a parameter file (.json, e.g. samii_params.json or a calibrated_params.json), "
            "not an MJCF file, whose physics is not parametrised"
        )

    overrides = as_overrides(req.overrides)
    base = read_params_file(req.model) if req.model else default_params()
    if overrides:
        base = params_with_overrides(base, overrides)
    for name in req.params:  # before the data are read: the name is the request's, not the file's
        try:
            check_parameter_name(base, name)
        except ValueError as exc:
            raise InputError(f"--param {name}: {str(exc).split(': ', 1)[-1]}") from None
    for option, given in (("--start", req.start), ("--bound", req.bounds)):
        unknown = sorted(set(given) - set(req.params))
        if unknown:
            raise InputError(f"{option} {', '.join(unknown)}: not calibrated; {option} applies to the --param names ({', '.join(req.params)})")
    data = load_target(source)
    channels = _channels(req.channels, data) if req.channels is not None else None
    confirm = None
    if req.confirm:
        lo, hi = max(0.1, float(data.freq_hz[0])), min(40.0, float(data.freq_hz[-1]))
        if not lo < hi:
            raise InputError(f"--confirm: the data's band {data.freq_hz[0]:g}-{data.freq_hz[-1]:g} Hz leaves nothing of 0.1-40 Hz to sweep")
        confirm = SweptSine(start_hz=lo, stop_hz=hi)
    try:
        result = calibrate(
            data,
            list(req.params),
            base=base,
            start=dict(req.start),
            bounds=dict(req.bounds),
            phase_weight=req.phase_weight,
            band_hz=tuple(req.band_hz) if req.band_hz else None,
            channels=channels,
            weighting=req.weighting,
            max_nfev=req.max_iterations,
            confirm=confirm,
            data_source=source,
        )
    except InputError:
        raise
    except (KeyError, ValueError) as exc:  # the data's validation (too few frequencies, a zero response, ...): name the file
        raise input_error_of(source, exc) from None
    if folder is None:
        return Calibrated(result, data)
    with folder:
        _write_outputs(result, data, folder)
    return Calibrated(result, data, tuple(folder.written))


def _write_outputs(result, data, folder) -> None:
    """Report JSON, parameter file and overlay Bode plot, staged in ``folder`` (:class:`samii.outputs.OutputFolder`)."""

    pyplot()  # on Agg: the figure below goes to a file
    structure = SimulatorFRF(result.params, result.names)
    models = {"start": (structure, dict(result.start)), "calibrated": (structure, dict(result.values))}
    note = (
        f"data: {result.data_source}; calibrated: "
        + ", ".join(f"{n} = {result.values[n]:.4g}" for n in result.names)
        + f"; phase weight {result.phase_weight:g}"
    )
    if "gain.base" in result.names:
        note += "; xdd in the data's own unit: the model curves are multiplied by gain.base"
    fig = plot_fit_overlay(
        data,
        models,
        channels=result.channels,
        band_hz=result.band_hz,
        title="samii calibrate: linearised simulator against the data",
        note=note,
        n_model_points=300,
    )
    save_figure(fig, folder.path("calibration_bode.png"))
    write_text(folder.path("calibration.json"), result.to_json(indent=2) + "\n")
    result.write_params(folder.path("calibrated_params.json"))
