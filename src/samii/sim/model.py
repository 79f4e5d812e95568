"""Load SAMII's MuJoCo model: the embedded default, a file, or the default with overrides.

The default model is ``models/samii/samii.xml`` (installed as ``samii/_model``),
written by :func:`samii.sim.mjcf.samii_xml` from the parameters in
``samii_params.json`` beside it. ``load_model(overrides=...)`` rebuilds the MJCF
from those parameters with some replaced (dotted names, e.g.
``{"beam.clamp_stiffness_Nm_rad": 2e5, "hydraulic.bulk_modulus": 1e9}``) and
puts the ``home`` keyframe at the new static equilibrium.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Mapping
from dataclasses import fields, is_dataclass, replace
from pathlib import Path

import mujoco
import numpy as np

from samii.errors import InputError
from samii.json_output import read_json
from samii.sim.hydraulic_reference import VALVE_OPTIONS
from samii.sim.mjcf import ArmParams, BeamParams, HydraulicConfig, SamiiParams, samii_xml
from samii.sim.one_step import one_step_poles
from samii.sim.plugin import MuJoCoWarning, compile_spec, load_plugin
from samii.sim.sensor_dynamics import SensorDynamics

__all__ = [
    "model_dir",
    "default_model_path",
    "default_params",
    "params_from_dict",
    "params_with_overrides",
    "dotted",
    "write_params",
    "read_params_file",
    "load_model",
    "load_spec",
    "compile_model",
    "make_data",
    "reset_home",
    "held_joint2_model",
    "ACTUATOR",
    "JOINT",
]

#: Parameters a complete parameter file may leave out: options whose default is "none" (the
#: valve's, the body on the beam's end and, as a whole section, the sensors'), which older files do not list.
OPTIONAL_PARAMETERS = frozenset(
    {f"hydraulic.{name}" for name in VALVE_OPTIONS} | {"beam.tip_body_mass_kg", "beam.tip_body_freq_hz", "beam.tip_body_damping_ratio"}
)

ACTUATOR = "joint2"  #: name of the hydraulic actuator
JOINT = "joint2"  #: the joint it drives
PARAMS_FILE = "samii_params.json"


def model_dir() -> Path:
    """Folder of the default model: the installed copy, else the source tree's models/samii."""
    here = Path(__file__).resolve().parent.parent
    for candidate in (here / "_model", here.parent.parent / "models" / "samii"):
        if (candidate / "samii.xml").is_file():
            return candidate
    raise FileNotFoundError(
        f"samii's default model was not found in {here / '_model'} (installed package) "
        f"nor in {here.parent.parent / 'models' / 'samii'} (source checkout); reinstall samii"
    )


def default_model_path() -> Path:
    return model_dir() / "samii.xml"


def params_from_dict(d: Mapping, *, complete: bool = False) -> SamiiParams:
    """Inverse of ``SamiiParams.as_dict``; unknown keys are an error, and with ``complete`` so is a
    missing one (a parameter file lists every parameter: nothing is silently taken from the defaults)."""
    sections = {"beam": BeamParams, "arm": ArmParams, "hydraulic": HydraulicConfig, "sensor": SensorDynamics}
    kw = {}
    for key, value in d.items():
        if key in sections:
            cls = sections[key]
            names = {f.name for f in fields(cls)}
            if not isinstance(value, Mapping):
                raise ValueError(f"section {key!r} must be an object of name: number, got {type(value).__name__}")
            unknown = set(value) - names
            if unknown:
                raise ValueError(f"unknown {key} parameter(s) {sorted(unknown)}; expected some of {sorted(names)}")
            for name, v in value.items():
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ValueError(f"{key}.{name} must be a finite number, got {v!r}")
            kw[key] = cls(**value)
        elif key == "timestep_s":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"timestep_s must be a number, got {value!r}")
            kw[key] = float(value)
        else:
            raise ValueError(f"unknown parameter section {key!r}; expected beam, arm, hydraulic, sensor, timestep_s")
    if complete:
        # the options added with issue 11 default to "none" and files written before them lack them
        expected = {"beam": BeamParams, "arm": ArmParams, "hydraulic": HydraulicConfig}
        missing = [k for k in (*expected, "timestep_s") if k not in d]
        missing += [
            f"{k}.{f.name}"
            for k, cls in expected.items()
            if isinstance(d.get(k), Mapping)
            for f in fields(cls)
            if f.name not in d[k] and f"{k}.{f.name}" not in OPTIONAL_PARAMETERS
        ]
        if missing:
            raise ValueError(
                f"missing {', '.join(missing[:4])}{', ...' if len(missing) > 4 else ''}: a parameter file lists every "
                "parameter (samii params --json shows them; samii calibrate writes complete files)"
            )
    return SamiiParams(**kw)


def default_params() -> SamiiParams:
    """The tuned parameters of the default model (``samii_params.json``)."""
    path = model_dir() / PARAMS_FILE
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path} is missing: it holds the parameters samii.xml was written from") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    return params_from_dict(data["params"])


def write_params(params: SamiiParams, path: Path, *, note: str = "") -> None:
    path.write_text(json.dumps({"note": note, "params": params.as_dict()}, indent=2) + "\n")


def dotted(params: SamiiParams | Mapping) -> dict[str, float]:
    """Every parameter by the name ``--set`` takes (``beam.length_m``, ``timestep_s``), from parameters or their ``as_dict``."""
    d = params.as_dict() if isinstance(params, SamiiParams) else params
    out = {}
    for section, values in d.items():
        if isinstance(values, Mapping):
            out.update({f"{section}.{k}": v for k, v in values.items()})
        else:
            out[section] = values
    return out


def params_with_overrides(params: SamiiParams, overrides: Mapping[str, float]) -> SamiiParams:
    """Replace dotted fields (``section.name`` or ``timestep_s``) of ``params``."""
    out = params
    # the step first: other values are checked against it (a tip body's mount frequency)
    for dotted, value in sorted(overrides.items(), key=lambda kv: kv[0] != "timestep_s"):
        parts = dotted.split(".")
        if len(parts) == 1 and parts[0] == "timestep_s":
            try:
                out = replace(out, timestep_s=float(value))
            except ValueError as exc:
                raise InputError(f"override timestep_s={float(value):g}: {exc}") from None
            continue
        if len(parts) != 2 or not hasattr(out, parts[0]) or not is_dataclass(getattr(out, parts[0])):
            raise InputError(f"override {dotted!r}: expected 'beam.<name>', 'arm.<name>', 'hydraulic.<name>', 'sensor.<name>' or 'timestep_s'")
        section = getattr(out, parts[0])
        names = {f.name for f in fields(section)}
        if parts[1] not in names:
            raise InputError(f"override {dotted!r}: {parts[0]} has no parameter {parts[1]!r}; expected one of {sorted(names)}")
        value = float(value)
        if parts[1] == "n_segments":
            if not (math.isfinite(value) and value == int(value)):
                raise InputError(f"override {dotted!r}: expected a whole number of beam elements, got {value:g}")
            value = int(value)
        try:
            out = replace(out, **{parts[0]: replace(section, **{parts[1]: value})})
        except ValueError as exc:
            raise InputError(f"override {dotted}={value:g}: {exc}") from None
    return out


def _load_plugin() -> None:
    load_plugin()


def read_params_file(path: str | Path) -> SamiiParams:
    """Parameters from a parameter file (``{"params": {...}}``, as :func:`write_params` and
    ``samii calibrate`` write it; ``samii_params.json`` is one)."""

    path = Path(path)
    data = read_json(path, "parameter file")
    if not isinstance(data, dict) or not isinstance(data.get("params"), dict):
        raise InputError(f"{path}: a parameter file is a JSON object with a 'params' object (sections beam, arm, hydraulic, timestep_s)")
    try:
        return params_from_dict(data["params"], complete=True)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from None


def load_spec(
    path: str | Path | None = None, *, params: SamiiParams | None = None, overrides: Mapping[str, float] | None = None
) -> tuple[mujoco.MjSpec, bool]:
    """The MjSpec of a model and whether it was generated (so needs its equilibrium computed).

    ``path`` is an MJCF file, or a parameter file (``.json``: the model is written from its
    parameters, and ``overrides`` apply on top of them)."""
    _load_plugin()
    if path is not None and Path(path).suffix.lower() == ".json":
        if params is not None:
            raise ValueError("give either a parameter file or params, not both")
        params, path = read_params_file(path), None
        if not overrides:
            return mujoco.MjSpec.from_string(samii_xml(params)), True
    if path is not None and (params is not None or overrides):
        raise ValueError("give either a model file or params/overrides, not both")
    if path is not None:
        path = Path(path)
        if not path.exists():
            raise InputError(f"model file {path} does not exist")
        if not path.is_file():
            raise InputError(f"model file {path} is not a regular file (a folder or a device); expected an MJCF .xml or a parameter .json")
        try:
            return mujoco.MjSpec.from_file(str(path)), False
        except ValueError as exc:  # MuJoCo's XML parser: names the line
            raise InputError(f"model file {path}: not a valid MJCF model ({' '.join(str(exc).split())})") from None
    if params is None and not overrides:
        return mujoco.MjSpec.from_file(str(default_model_path())), False
    base = params if params is not None else default_params()
    if overrides:
        base = params_with_overrides(base, overrides)
    return mujoco.MjSpec.from_string(samii_xml(base)), True


def load_model(
    path: str | Path | None = None, *, params: SamiiParams | None = None, overrides: Mapping[str, float] | None = None, check_step: bool = True
) -> mujoco.MjModel:
    """Compile SAMII's model, with its ``home`` keyframe at static equilibrium.

    Parameters
    ----------
    path : path, optional
        An MJCF file, or a parameter file (``.json``, e.g. written by ``samii calibrate``);
        default the embedded model.
    params : SamiiParams, optional
        Build the MJCF from these parameters instead.
    overrides : mapping of dotted name to value, optional
        Replace some of the default (or given) parameters, e.g.
        ``{"beam.clamp_stiffness_Nm_rad": 2e5}``.
    check_step : bool
        Refuse (InputError) a model its own physics step cannot integrate, a mode too stiff for it (default); False
        compiles it anyway, and a simulation of it diverges (``SimulationUnstable``).
    """

    spec, generated = load_spec(path, params=params, overrides=overrides)
    return compile_model(spec, generated, path=path, params=params, overrides=overrides, check_step=check_step)


def compile_model(
    spec: mujoco.MjSpec,
    generated: bool,
    *,
    path: str | Path | None = None,
    params: SamiiParams | None = None,
    overrides: Mapping[str, float] | None = None,
    check_step: bool = True,
) -> mujoco.MjModel:
    """:func:`load_model` of a spec :func:`load_spec` returned (``generated``) for ``path``, ``params`` and
    ``overrides``: a caller that needs the spec as well (to build a controller card on it) builds it once."""

    try:
        model = compile_spec(spec)  # validates the hydraulic config, naming any bad attribute
    except InputError:
        raise
    except ValueError as exc:  # MuJoCo's compiler ("Error: unknown transmission target 'joint2' ..."): the file is the user's
        if path is None or Path(path).suffix.lower() == ".json":
            raise
        text = " ".join(str(exc).split())
        text = text[len("Error: ") :] if text.startswith("Error: ") else text
        raise InputError(f"model file {path}: MuJoCo cannot compile it: {text}") from None
    _check_model(model, path)
    if check_step:
        _check_integrable(model, path, params, overrides)
    if generated:
        from samii.sim.equilibrium import static_equilibrium  # (lazy: imports scipy, only when called)

        try:
            eq = static_equilibrium(model)
        except RuntimeError as exc:  # no rest state: the parameters describe no usable rig
            raise InputError(
                f"the model with these parameters does not come to rest near its nominal pose ({exc}); "
                "check the overridden values (samii params lists the defaults)"
            ) from None
        model.key_qpos[0] = eq.qpos
        model.key_act[0] = eq.act
    return model


def _check_model(model: mujoco.MjModel, path) -> None:
    where = str(path) if path is not None else "samii model"
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, ACTUATOR) < 0:
        raise InputError(f"{where}: no actuator named {ACTUATOR!r} (the hydraulic actuator of joint 2)")
    for sensor in ("theta", "base_accel"):
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, sensor) < 0:
            raise InputError(f"{where}: no sensor named {sensor!r}")
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home") < 0:
        raise InputError(f"{where}: no keyframe named 'home' (the nominal pose)")


def _unresolved(model: mujoco.MjModel) -> np.ndarray:
    """Eigenvalues of ``model``'s one-step map (about its ``home`` keyframe) outside the unit circle above a quarter of
    the step rate (Re z < 0): modes too stiff for the step, which grow in the simulator whatever the physics."""

    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", MuJoCoWarning)  # (the one-step map of such a model overflows: said by the caller)
        z = one_step_poles(model, make_data(model))
    return z[(z.real < 0) & ~(np.abs(z) <= 1.0 + 1e-9)]  # (a nan counts: the step itself overflowed)


def _check_integrable(model: mujoco.MjModel, path, params, overrides: Mapping[str, float] | None) -> None:
    """Refuse a model its own physics step cannot integrate (:func:`_unresolved`). A spring too stiff for the step
    (beam.clamp_stiffness_Nm_rad = 1e10 gives z = -1.2e4; a 3 m beam's elements z = -6.8) was reported as the plant's
    instability at the step's Nyquist frequency (500 Hz), or ran with joint speeds of 1e5 rad/s and no word, or MuJoCo
    printed its own warnings and the modes came out nan. For a model built from parameters, the step that would
    integrate it (halved up to four times) is named."""
    bad = _unresolved(model)
    if not bad.size:
        return
    worst = bad[np.argmax(np.where(np.isfinite(bad), np.abs(bad), np.inf))]
    dt = float(model.opt.timestep)
    given = ", ".join(f"{k}={v:g}" for k, v in (overrides or {}).items())
    where = f" with {given}" if given else (f" {path}" if path is not None else "")
    fix = "check the values (samii params lists the defaults)"
    if path is None or str(path).lower().endswith(".json"):
        for k in range(1, 5):
            try:
                spec, _ = load_spec(path, params=params, overrides={**(overrides or {}), "timestep_s": dt / 2**k})
                if not _unresolved(compile_spec(spec)).size:
                    fix = f"a shorter physics step integrates it (--set timestep_s={dt / 2**k:g}), or check the values"
                    break
            except ValueError:  # (InputError included: the halved step is refused for another reason)
                break
    raise InputError(
        f"the model{where} cannot be simulated at its {dt * 1e3:g} ms physics step: its one-step map has an "
        f"eigenvalue z = {worst:.3g} (|z| > 1 beyond a quarter of the step rate), a mode too stiff for the step "
        f"that would grow whatever the physics; {fix}"
    )


def make_data(model: mujoco.MjModel) -> mujoco.MjData:
    """MjData at the ``home`` keyframe (static equilibrium), forward-computed."""
    return reset_home(model, mujoco.MjData(model))


def reset_home(model: mujoco.MjModel, data: mujoco.MjData) -> mujoco.MjData:
    """``data`` reset to the ``home`` keyframe and forward-computed (a new MjData costs 0.4 ms, a reset microseconds)."""
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    mujoco.mj_resetDataKeyframe(model, data, key)
    mujoco.mj_forward(model, data)
    return data


def held_joint2_model(spec: mujoco.MjSpec, theta2_rad: float) -> mujoco.MjModel:
    """The model with joint 2 held at ``theta2_rad``: the joint, its actuator and
    sensor removed and link 2 welded to link 1 at that angle. The ``home``
    keyframe keeps the other joints' values."""
    full = spec.copy().compile()
    key = mujoco.mj_name2id(full, mujoco.mjtObj.mjOBJ_KEY, "home")
    home = {full.joint(j).name: float(full.key_qpos[key][full.jnt_qposadr[j]]) for j in range(full.njnt)} if key >= 0 else {}

    spec = spec.copy()
    joint = spec.joint(JOINT)
    body = joint.parent
    axis = np.asarray(joint.axis, float)
    axis = axis / np.linalg.norm(axis)
    rot = np.zeros(4)
    mujoco.mju_axisAngle2Quat(rot, axis, theta2_rad)
    q = np.zeros(4)
    mujoco.mju_mulQuat(q, np.asarray(body.quat, float), rot)
    body.quat = q
    for act in list(spec.actuators):
        if act.target == JOINT:
            spec.delete(act)
    for sensor in list(spec.sensors):
        if sensor.objname == JOINT:
            spec.delete(sensor)
    for k in list(spec.keys):
        spec.delete(k)
    spec.delete(joint)
    for plugin in list(spec.plugins):
        spec.delete(plugin)
    held = spec.compile()
    if home:
        qpos = np.array([home.get(held.joint(j).name, 0.0) for j in range(held.njnt)])
        spec.add_key(name="home", qpos=qpos)
        held = spec.compile()
    return held
