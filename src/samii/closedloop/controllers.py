"""Controllers for the closed loop: the notebook's designs in SI, and saved controller files.

Units of the notebook's designs (issue 10, item 3). The notebook never states
them. Its models are fitted to the rig's Bode data, so comparing them with the
simulator's linearisation (SI) names them. For eq 9.4's base-acceleration
coefficients B_k (xdd/theta = s^4 sum B_k / (s^2 + 2 zeta_k w_k s + w_k^2)), the
ratio B_k(eq 9.4) / B_k(simulator, m/rad) converted with theta in degrees
(:func:`accel_unit_evidence`) is 3.85, 3.32 and 2.85 acceleration units per
m/s² for modes 1, 2 and 3 (geometric mean 3.32): within the spread of the
three modes, ft/s² (3.281 per m/s²) and no other common unit (g: 0.102,
m/s²: 1, in/s²: 39.4; with theta in radians the ratios would be 0.050 to
0.067, again no common unit). The spread between modes is the simulator's
mode shapes at the sensor against the rig's (not a unit). So the notebook's
designs read theta in degrees and the acceleration in ft/s²:
``input_scale = {"theta_ref": 180/pi, "theta": 180/pi, "accel": 1/0.3048}``
(:data:`NOTEBOOK_INPUT_SCALE`).

Saved controller files (``samii design place|cancel --save FILE``) are JSON::

    {"format": "samii-controller", "version": 1,
     "name": str, "method": str, "model_units": str,
     "sample_time_s": float, "inputs": [names], "input_scale": {name: float},
     "servo_loop": "replaced" | "kept",
     "A": [[...]], "B": [[...]], "C": [[...]], "D": [[...]],
     "provenance": {...}}

Numbers are written with every digit (Python's ``repr``), so a controller reads
back bit for bit.
"""

from __future__ import annotations

import datetime
import json
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from samii import __version__
from samii import notebook as nb
from samii.controller import MEASUREMENTS, LinearController
from samii.errors import InputError
from samii.formats import write_text
from samii.json_output import dumps

__all__ = [
    "FT_PER_M",
    "NOTEBOOK_INPUT_SCALE",
    "NOTEBOOK_UNITS_SI",
    "NotebookUnitEvidence",
    "SavedController",
    "accel_unit_evidence",
    "notebook_cancel",
    "notebook_place",
    "read_controller",
    "write_controller",
    "FORMAT",
]

FORMAT = "samii-controller"
VERSION = 1
FT_PER_M = 1.0 / 0.3048  #: international foot (exact definition)

#: SI -> the notebook's units: theta in degrees, acceleration in ft/s² (module docstring).
NOTEBOOK_INPUT_SCALE: Mapping[str, float] = {"theta_ref": 180.0 / math.pi, "theta": 180.0 / math.pi, "accel": FT_PER_M}
NOTEBOOK_UNITS_SI = ("notebook units: theta in degrees, acceleration in ft/s² (from eq 9.4's B_k against the simulator's, "
                     "samii.closedloop.controllers), v in volts")  # fmt: skip

_MAX_FILE_BYTES = 10_000_000
#: Largest magnitude of a controller matrix entry or input scale read from a file, as for any number in a
#: measurement file (samii.formats.MAX_ABS_VALUE): the product of two entries beyond it can overflow a double
#: in the controller's first step, so the run would end at t = 0 with nothing to show. No controller's gain comes
#: near it (the servo's is 57 V/rad, the notebook's compensators' entries are below 1e4).
MAX_ENTRY = 1e100


@dataclass(frozen=True)
class SavedController:
    """A runnable controller and how it connects to the servo amplifier."""

    controller: LinearController
    replaces_servo: bool  #: True: the controller is the whole position loop (the amplifier's Kp is off while it runs)
    provenance: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class NotebookUnitEvidence:
    freq_hz: tuple[float, ...]  #: the simulator's base modes
    b_notebook: tuple[float, ...]  #: eq 9.4's B_k [notebook accel unit * s^2 / deg]
    b_simulator: tuple[float, ...]  #: the simulator's B_k [m/rad]
    units_per_m_s2: tuple[float, ...]  #: B_nb / (B_sim * pi/180): notebook acceleration units per m/s², per mode

    @property
    def geometric_mean(self) -> float:
        return float(np.exp(np.mean(np.log(np.abs(self.units_per_m_s2)))))


def accel_unit_evidence(model=None) -> NotebookUnitEvidence:
    """Eq 9.4's B_k against the simulator's (``model``, default the embedded one), theta in degrees."""

    from samii.sim.linearize import linearize  # (lazy: imports mujoco, scipy, only when called)
    from samii.sim.model import load_model  # (lazy: imports mujoco, only when called)

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="logm result may be inaccurate")  # error ~1e-12, well below what is compared here
        lm = linearize(model if model is not None else load_model())
    coeffs = lm.base_coefficients()[:3]
    b_nb = (nb.EQ9_4["B1"], nb.EQ9_4["B2"], nb.EQ9_4["B3"])
    b_sim = tuple(c.B for c in coeffs)
    ratio = tuple(float(bn / (bs * math.pi / 180.0)) for bn, bs in zip(b_nb, b_sim))
    return NotebookUnitEvidence(tuple(c.freq_hz for c in coeffs), b_nb, b_sim, ratio)


def notebook_place(*, sample_time_s: float = 1e-3) -> SavedController:
    """Chapter 8: digital pole placement with a placement observer on eq 1.4, as the notebook built it.

    eq 1.4's 2-mode model, poles of eq 8.3 (zeta 1/sqrt 2), observer at twice
    the controller poles, plant discretised by ZOH at ``sample_time_s``; it
    reads theta_ref, theta and the base acceleration in the notebook's units
    and is the whole position loop.
    """
    from samii.design import canonical as cc  # (lazy: imports PIL, control, matplotlib, scipy, sympy, only when called)
    from samii.design import placement as pl  # (lazy: imports PIL, control, matplotlib, scipy, only when called)

    model = cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)
    d = pl.design_placement(model, sample_time_s=sample_time_s, zeta=nb.EQ8_3_ZETA, observer="placement")
    c = d.controller(input_scale=dict(NOTEBOOK_INPUT_SCALE), model_units=NOTEBOOK_UNITS_SI)
    return SavedController(c, True, {"designed_on": "eq 1.4 (notebook, 2 base modes)", "design": "samii design place (chapter 8)",
                                     "zeta": d.zeta, "observer": "placement"})  # fmt: skip


def notebook_cancel(*, sample_time_s: float = 1e-3, gain: float | None = None) -> SavedController:
    """Chapter 10: the pole-cancelling compensator on eq 9.4 with the notebook's gain (0.0666), theta loop.

    The reference is scaled for unit DC gain (the loop as drawn settles at
    0.14 of the step; the notebook's Figure 11.2 shows theta reaching the
    desired angle), discretised by pole-zero matching.
    """
    from samii.design.cancel import design_pole_cancel  # (lazy: imports PIL, control, matplotlib, scipy, only when called)

    k = nb.EQ10_GAIN if gain is None else gain
    d = design_pole_cancel(nb.EQ9_4, loop="theta", gain=k)
    scale = {k: NOTEBOOK_INPUT_SCALE[k] for k in ("theta_ref", "theta")}
    c = d.controller(sample_time_s=sample_time_s, input_scale=scale, model_units=NOTEBOOK_UNITS_SI)
    return SavedController(c, True, {"designed_on": "eq 9.4 (notebook, 3 base modes)", "design": "samii design cancel (chapter 10)",
                                     "gain": k, "loop": "theta"})  # fmt: skip


# ---- files ----


def _provenance_defaults() -> dict:
    return {"samii_version": __version__, "written_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")}


def controller_json(saved: SavedController) -> dict:
    c = saved.controller
    return {
        "format": FORMAT,
        "version": VERSION,
        "name": c.name,
        "method": c.method,
        "model_units": c.model_units,
        "sample_time_s": float(c.sample_time_s),
        "inputs": list(c.inputs),
        "input_scale": {k: float(v) for k, v in (c.input_scale or {}).items()},
        "servo_loop": "replaced" if saved.replaces_servo else "kept",
        "A": np.asarray(c.A, float).tolist(),
        "B": np.asarray(c.B, float).tolist(),
        "C": np.asarray(c.C, float).tolist(),
        "D": np.asarray(c.D, float).tolist(),
        "provenance": {**_provenance_defaults(), **dict(saved.provenance)},
    }


def write_controller(saved: SavedController, path: str | Path) -> Path:
    """Write ``saved`` as a controller file (strict JSON, every digit kept); all or nothing (a temporary file renamed;
    a full disk's error names ``path``)."""

    return write_text(path, dumps(controller_json(saved), indent=1) + "\n", overwrite=True)


def _finite_number(x) -> bool:
    """A JSON number that is a finite double (not a bool, not an integer beyond the double range)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(float(x))
    except OverflowError:
        return False


def _shown(x) -> str:
    """``x`` for a message: its repr, or its length for an integer too long to print usefully."""
    return repr(x) if not isinstance(x, int) or abs(x) < 10**20 else f"an integer of {len(str(abs(x)))} digits"


def _matrix(doc: dict, key: str, where: str) -> np.ndarray:
    if key not in doc:
        raise InputError(f"{where}: field {key!r} is missing (expected a list of rows of numbers)")
    value = doc[key]
    if not isinstance(value, list) or not all(isinstance(r, list) for r in value):
        raise InputError(f"{where}: field {key!r} must be a list of rows (lists of numbers), got {type(value).__name__}")
    if value and len({len(r) for r in value}) != 1:
        raise InputError(f"{where}: field {key!r} has rows of different lengths")
    for r in value:
        for x in r:
            if not _finite_number(x):
                raise InputError(f"{where}: field {key!r} has the entry {_shown(x)}; expected finite numbers")
            if abs(float(x)) > MAX_ENTRY:
                raise InputError(
                    f"{where}: field {key!r} has the entry {_shown(x)}, beyond +-{MAX_ENTRY:g}: a controller's "
                    "matrices that overflow in its first step (expected gains in V per SI unit of its inputs)"
                )
    return np.array(value, float) if value and value[0] else np.zeros((len(value), 0))


def _short_name(text: str) -> str:
    return text if len(text) <= 40 else text[:40] + "..."


def read_controller(path: str | Path) -> SavedController:
    """Read a controller file; :class:`InputError` naming the file and field for anything malformed."""
    p = Path(path)
    where = str(p)
    if not p.exists():
        raise InputError(f"controller file {where} does not exist")
    if not p.is_file():
        raise InputError(f"controller file {where} is not a regular file")
    if p.stat().st_size > _MAX_FILE_BYTES:
        raise InputError(f"controller file {where} is larger than {_MAX_FILE_BYTES // 1_000_000} MB; not a controller file")
    try:
        doc = json.loads(p.read_text(encoding="utf-8-sig"), parse_constant=float)
    except UnicodeDecodeError:
        raise InputError(f"{where}: not a text file (expected a samii controller JSON file)") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{where}: not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None
    except RecursionError:
        raise InputError(f"{where}: not a controller file (its JSON is nested too deeply)") from None
    except ValueError as exc:  # e.g. an integer longer than Python converts (4300 digits)
        raise InputError(f"{where}: not a controller file (a number in it cannot be read: {' '.join(str(exc).split()[:8])} ...)") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f"{where}: not a samii controller file (expected an object with \"format\": \"{FORMAT}\", "
                         "as written by samii design place|cancel --save)")  # fmt: skip
    if type(doc.get("version")) is not int or doc.get("version") != VERSION:
        raise InputError(f"{where}: field 'version' is {doc.get('version')!r}; this samii reads version {VERSION}")
    T = doc.get("sample_time_s")
    if not _finite_number(T) or not float(T) > 0:
        raise InputError(f"{where}: field 'sample_time_s' must be a positive number of seconds, got {_shown(T)}")
    inputs = doc.get("inputs")
    if not isinstance(inputs, list) or not inputs or not all(isinstance(s, str) for s in inputs):
        raise InputError(f"{where}: field 'inputs' must be a non-empty list of measurement names (theta_ref, theta, accel)")

    unknown = [s for s in inputs if s not in MEASUREMENTS]
    if unknown or len(set(inputs)) != len(inputs):
        what = (
            f"{', '.join(repr(_short_name(s)) for s in unknown)} {'is' if len(unknown) == 1 else 'are'} not a measurement"
            if unknown
            else "names repeat"
        )
        raise InputError(f"{where}: field 'inputs': {what}; expected distinct names among {', '.join(MEASUREMENTS)} (DATA_FORMATS.md)")
    scale = doc.get("input_scale", {})
    if not isinstance(scale, dict) or not all(_finite_number(v) and v != 0 and abs(float(v)) <= MAX_ENTRY for v in scale.values()):
        raise InputError(f"{where}: field 'input_scale' must map input names to finite nonzero factors of at most {MAX_ENTRY:g}")
    if extra := sorted(set(scale) - set(inputs)):
        raise InputError(
            f"{where}: field 'input_scale' names {', '.join(repr(_short_name(str(k))) for k in extra)}, which "
            f"{'is' if len(extra) == 1 else 'are'} not among the field 'inputs' ({', '.join(inputs)})"
        )
    servo = doc.get("servo_loop")
    if servo not in ("replaced", "kept"):
        raise InputError(
            f'{where}: field \'servo_loop\' must be "replaced" (the controller is the whole position loop) or "kept" (it adds to it), got {servo!r}'
        )
    A, B, C, D = (_matrix(doc, k, where) for k in ("A", "B", "C", "D"))
    n = A.shape[0]
    if n or B.size or C.size:
        if A.shape != (n, n) or B.shape != (n, len(inputs)) or C.shape != (1, n):
            raise InputError(f"{where}: matrix shapes A {A.shape}, B {B.shape}, C {C.shape} do not fit {n} states and "
                             f"{len(inputs)} inputs (expected A ({n}, {n}), B ({n}, {len(inputs)}), C (1, {n}))")  # fmt: skip
    else:
        A, B, C = np.zeros((0, 0)), np.zeros((0, len(inputs))), np.zeros((1, 0))
    if D.shape != (1, len(inputs)):
        raise InputError(f"{where}: field 'D' has shape {D.shape}; expected (1, {len(inputs)}) for inputs {inputs}")
    for key in ("name", "method", "model_units"):
        if not isinstance(doc.get(key, ""), str):
            raise InputError(f"{where}: field {key!r} must be a string")
    prov = doc.get("provenance", {})
    if not isinstance(prov, dict):
        raise InputError(f"{where}: field 'provenance' must be an object")
    try:
        c = LinearController(A, B, C, D, sample_time_s=float(T), inputs=tuple(inputs), input_scale={k: float(v) for k, v in scale.items()},
                             name=doc.get("name", ""), method=doc.get("method", ""), model_units=doc.get("model_units", ""))  # fmt: skip
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from None
    return SavedController(c, servo == "replaced", prov)
