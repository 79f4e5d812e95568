"""Loading, configuration checks and state access for the ``samii.hydraulic`` MuJoCo plugin.

The plugin (``hydraulic.c``) is compiled by the package's build into ``libsamii_hydraulic.so`` next
to this module, against the MuJoCo version recorded in ``_plugin_build.json``. :func:`load_plugin`
checks that version against the running ``mujoco`` and registers the plugin once per process.

Declaring the actuator in MJCF (MuJoCo 4.0)::

    <extension><plugin plugin="samii.hydraulic"/></extension>
    <actuator>
      <plugin name="joint2" joint="joint2" plugin="samii.hydraulic" actdim="2"
              ctrlrange="-10 10" ctrllimited="true">
        <config key="supply_pressure" value="7e6"/>
        ... (all ten attributes of samii.sim.hydraulic_reference.ATTRIBUTES)
      </plugin>
    </actuator>

or, equivalently, the config on an explicit ``<extension><plugin><instance name="...">`` and
``<actuator><plugin instance="..." .../>`` (one instance per actuator).

Invalid configuration: the plugin's ``init`` issues a MuJoCo warning naming the attribute and
returns -1 (the plugin API's documented way; ``mju_error`` from a plugin would skip C++
destructors under the Python bindings). Compilation then fails: ``MjModel.from_xml_string`` or
``MjSpec.compile`` raise ``ValueError("Error: engine error: plugin->init failed for plugin id 0\n
samii.hydraulic: missing config attribute 'rated_flow' ...")`` (MuJoCo 4.0 appends the warning).
:func:`validate_spec` (called by :func:`compile_spec`) checks the same rules on the
:class:`mujoco.MjSpec` before compiling and raises :class:`HydraulicConfigError` (a ValueError)
naming the actuator, the attribute, its value and what was expected.
"""

from __future__ import annotations

import copy
import json
import math
import re
import threading
import warnings
from collections.abc import Mapping
from pathlib import Path

import mujoco
import numpy as np

from samii.sim.hydraulic_reference import (
    ATTRIBUTES,
    NOMINAL,
    OPTIONAL_ATTRIBUTES,
    VALVE_OPTIONS,
    HydraulicConfigError,
    HydraulicParams,
)
from samii.sim.hydraulic_reference import (
    valve_voltage as _valve_voltage,
)

__all__ = [
    "ACTDIM",
    "PLUGIN_NAME",
    "HydraulicConfigError",
    "PluginBuildError",
    "build_info",
    "command_ring_entries",
    "compile_spec",
    "hydraulic_actuators",
    "hydraulic_params",
    "hydraulic_state",
    "ideal_valve_model",
    "load_plugin",
    "plugin_library_path",
    "probe_xml",
    "spec_hydraulic_params",
    "validate_spec",
    "valve_options",
    "valve_voltage",
]

PLUGIN_NAME = "samii.hydraulic"
ACTDIM = 2  # act[0] = spool x (-1..1), act[1] = P/Ps
_LIBRARY = "libsamii_hydraulic.so"
_BUILD_INFO = "_plugin_build.json"

_lock = threading.Lock()
_loaded: Path | None = None
_slot: int | None = None  # MuJoCo's registration slot of the plugin (mjModel.plugin entries)


class PluginBuildError(RuntimeError):
    """The plugin library is missing or was built for another MuJoCo version."""


def plugin_library_path() -> Path:
    """Path of the compiled plugin library (``samii/sim/libsamii_hydraulic.so``)."""
    return Path(__file__).resolve().with_name(_LIBRARY)


def build_info() -> dict:
    """What the build recorded: library name, ``mujoco_version``, ``mjVERSION_HEADER``.

    Raises
    ------
    PluginBuildError
        If the library or its build record is missing.
    """
    library = plugin_library_path()
    info_path = library.with_name(_BUILD_INFO)
    if not library.exists() or not info_path.exists():
        raise PluginBuildError(
            f"the hydraulic actuator plugin is not built ({library} or {info_path.name} missing); "
            "install samii with `pip install .` or `pip install -e .` so its build compiles hydraulic.c"
        )
    return json.loads(info_path.read_text())


def load_plugin() -> Path:
    """Register the ``samii.hydraulic`` plugin with MuJoCo (once per process; idempotent).

    Returns
    -------
    Path
        The loaded library.

    Raises
    ------
    PluginBuildError
        If the library is missing or was compiled against a MuJoCo other than the running one.
    """
    global _loaded, _slot
    with _lock:
        if _loaded is not None:
            return _loaded
        info = build_info()
        built, running = info.get("mujoco_version"), mujoco.__version__
        if built != running or info.get("mjVERSION_HEADER") != mujoco.mj_version():
            raise PluginBuildError(
                f"the hydraulic actuator plugin was built against MuJoCo {built} "
                f"(header {info.get('mjVERSION_HEADER')}) but MuJoCo {running} "
                f"({mujoco.mj_version()}) is running; reinstall samii (pip install .) so it is rebuilt"
            )
        library = plugin_library_path()
        mujoco.mj_loadPluginLibrary(str(library))
        try:
            probe = mujoco.MjModel.from_xml_string(probe_xml())
        except ValueError as exc:
            raise PluginBuildError(f"{library} did not register the {PLUGIN_NAME} plugin: {exc}") from exc
        _slot = int(probe.plugin[0])
        _loaded = library
        _route_mujoco_warnings()
        return library


class MuJoCoWarning(RuntimeWarning):
    """A warning of MuJoCo itself (a simulation that produced nan, a full constraint buffer), as a Python warning."""


def _route_mujoco_warnings() -> None:
    """MuJoCo's warnings as Python warnings (:class:`MuJoCoWarning`; the commands print each once, on one line), unless
    the process set its own handler: by default MuJoCo prints them from C and appends them to MUJOCO_LOG.TXT in the
    working folder, a file a command must not leave behind."""
    if mujoco.get_mju_user_warning() is not None:
        return

    def warn(message: str) -> None:
        text = re.sub(r"\s*Time = [-+0-9.eE]+\.?\s*$", "", str(message)).strip()  # (one message, whenever it came)
        warnings.warn(text, MuJoCoWarning, stacklevel=2)

    mujoco.set_mju_user_warning(warn)


def probe_xml(
    params: HydraulicParams = NOMINAL,
    *,
    inertia: float = 0.14,
    damping: float = 0.0,
    timestep: float = 1e-4,
    integrator: str = "Euler",
    config: Mapping[str, str] | None = None,
) -> str:
    """MJCF of the plain-inertia test model: one hinge ``joint2`` driven by the plugin, gravity off.

    Parameters
    ----------
    params : HydraulicParams
        Actuator parameters (ignored if ``config`` is given).
    inertia : float
        Moment of inertia about the hinge [kg m^2] (0.14: link 2 about joint 2, DESIGN.md).
    damping : float
        Joint viscous damping [N m s/rad].
    timestep : float
        [s]
    integrator : str
        MuJoCo integrator name.
    config : mapping of str to str, optional
        Raw config strings (may be incomplete or invalid, for tests of the validation).
    """
    config = params.to_config() if config is None else config
    lines = "".join(f'\n      <config key="{k}" value="{v}"/>' for k, v in config.items())
    return f"""<mujoco model="samii_hydraulic_probe">
  <option gravity="0 0 0" timestep="{timestep!r}" integrator="{integrator}"/>
  <extension><plugin plugin="{PLUGIN_NAME}"/></extension>
  <worldbody>
    <body name="link2">
      <joint name="joint2" type="hinge" axis="0 1 0" damping="{damping!r}"/>
      <inertial pos="0 0 0" mass="1" diaginertia="{inertia!r} {inertia!r} {inertia!r}"/>
    </body>
  </worldbody>
  <actuator>
    <plugin name="joint2" joint="joint2" plugin="{PLUGIN_NAME}" actdim="{ACTDIM}" ctrlrange="-10 10" ctrllimited="true">{lines}
    </plugin>
  </actuator>
</mujoco>
"""


# ------------------------------------------------------------------------------------------------
# configuration on an MjSpec (before compilation)


def _spec_config(spec: mujoco.MjSpec, actuator) -> dict[str, str] | None:
    """Config of ``actuator`` if it is a samii.hydraulic plugin actuator, else None."""
    ref = actuator.plugin
    if ref.plugin_name == PLUGIN_NAME and not ref.name:
        return dict(ref.config)  # implicit instance: config on the actuator element
    if ref.name:
        # explicit instance. Do not read ref.config here: in the MuJoCo 4.0 bindings that
        # segfaults for an actuator that references an instance by name.
        for instance in spec.plugins:
            if instance.name == ref.name and instance.plugin_name == PLUGIN_NAME:
                return dict(instance.config)
    return None


def spec_hydraulic_params(spec: mujoco.MjSpec) -> dict[str, HydraulicParams]:
    """Validated parameters of every samii.hydraulic actuator of ``spec``, by actuator name.

    Raises
    ------
    HydraulicConfigError
        Naming the actuator, the attribute, its value and what was expected.
    """
    params = {}
    for i, actuator in enumerate(spec.actuators):
        config = _spec_config(spec, actuator)
        if config is None:
            continue
        name = actuator.name or f"#{i}"
        source = f"{PLUGIN_NAME} actuator '{name}'"
        params[name] = HydraulicParams.from_config(config, source=source)
        if actuator.actdim != ACTDIM:
            raise HydraulicConfigError(f'{source}: actdim = {actuator.actdim} (expected actdim="{ACTDIM}")')
        if actuator.trntype != mujoco.mjtTrn.mjTRN_JOINT or not actuator.target:
            raise HydraulicConfigError(f'{source}: must act on a hinge joint (expected joint="...")')
        if actuator.gear[0] != 1:
            raise HydraulicConfigError(f"{source}: gear = {actuator.gear[0]} (expected 1)")
    return params


def validate_spec(spec: mujoco.MjSpec) -> None:
    """Check every samii.hydraulic actuator's config; raise :class:`HydraulicConfigError` if bad."""
    spec_hydraulic_params(spec)


def compile_spec(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """Load the plugin, validate its config on ``spec`` and compile it."""
    load_plugin()
    validate_spec(spec)
    return spec.compile()


# ------------------------------------------------------------------------------------------------
# compiled model and data


def hydraulic_actuators(model: mujoco.MjModel) -> list[int]:
    """Ids of the actuators driven by samii.hydraulic in ``model``."""
    load_plugin()
    return [i for i in range(model.nu) if model.actuator_plugin[i] >= 0 and int(model.plugin[model.actuator_plugin[i]]) == _slot]


def _instance_attributes(model: mujoco.MjModel, instance: int) -> dict[str, str]:
    return {name: raw.decode() for name, _, raw in _instance_fields(model, instance) if name in ATTRIBUTES}


def valve_options(model: mujoco.MjModel, actuator: str | int = "joint2") -> dict[str, float]:
    """The valve options of a compiled samii.hydraulic actuator (``VALVE_OPTIONS``; 0 = none)."""
    instance = int(model.actuator_plugin[_actuator_id(model, actuator)])
    out = dict.fromkeys(VALVE_OPTIONS, 0.0)
    for name, _, raw in _instance_fields(model, instance):
        if name in VALVE_OPTIONS and raw.strip():
            out[name] = float(raw)
    return out


def command_ring_entries(delay_s: float, timestep_s: float) -> int:
    """plugin_state entries of a command delay ``delay_s`` at physics step ``timestep_s``, after
    the card's (hydraulic.c, delay_size and the command-ring block): 0 without a delay."""
    if not delay_s > 0:
        return 0
    steps = delay_s / timestep_s
    if abs(steps - round(steps)) < 1e-9 * (1 + steps):
        steps = round(steps)
    return 2 + 2 * (math.floor(steps) + 2)


def ideal_valve_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """``model`` with an ideal valve in every samii.hydraulic actuator: no command delay, dead band,
    saturation or asymmetry (a copy; ``model`` itself when none is set). The small-signal plant a
    linearisation takes: a delay line in the plugin's state is invisible to MuJoCo's
    finite-difference derivatives (they perturb qpos, qvel and act, not the plugin's state), and a
    dead band has no slope at rest. The values are overwritten in place in ``plugin_attr`` by
    "0" padded with spaces to the same length, which the plugin's parser reads as 0."""

    edits = [
        (offset, len(raw))
        for i in hydraulic_actuators(model)
        for name, offset, raw in _instance_fields(model, int(model.actuator_plugin[i]))
        if name in VALVE_OPTIONS and raw.strip() and float(raw) != 0
    ]
    if not edits:
        return model
    out = copy.copy(model)
    for offset, size in edits:
        out.plugin_attr[offset : offset + size] = np.frombuffer(b"0" + b" " * (size - 1), dtype=np.int8)
    return out


def _instance_fields(model: mujoco.MjModel, instance: int) -> list[tuple[str, int, bytes]]:
    """(attribute name, offset in ``plugin_attr``, raw value) of each config attribute of an
    instance. ``plugin_attr`` holds each instance's values NUL-separated, in the plugin's attribute
    order (mj_getPluginConfig, which the Python bindings do not expose, reads it the same way)."""
    start = int(model.plugin_attradr[instance])
    end = int(model.plugin_attradr[instance + 1]) if instance + 1 < model.nplugin else len(model.plugin_attr)
    values = bytes(np.asarray(model.plugin_attr[start:end], dtype=np.uint8)).split(b"\0")
    out, offset = [], start
    for name, raw in zip((*ATTRIBUTES, *OPTIONAL_ATTRIBUTES), values):
        out.append((name, offset, raw))
        offset += len(raw) + 1
    return out


def _actuator_id(model: mujoco.MjModel, actuator: str | int) -> int:
    if isinstance(actuator, str):
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator)
        if i < 0:
            raise KeyError(f"model has no actuator named '{actuator}'")
    else:
        i = int(actuator)
    if i not in hydraulic_actuators(model):
        raise KeyError(f"actuator '{actuator}' is not a {PLUGIN_NAME} actuator")
    return i


def hydraulic_params(model: mujoco.MjModel, actuator: str | int = "joint2") -> HydraulicParams:
    """Parameters of a compiled samii.hydraulic actuator."""
    i = _actuator_id(model, actuator)
    config = _instance_attributes(model, int(model.actuator_plugin[i]))
    return HydraulicParams.from_config(config, source=f"{PLUGIN_NAME} actuator '{actuator}'")


def hydraulic_state(model: mujoco.MjModel, data: mujoco.MjData, actuator: str | int = "joint2") -> tuple[float, float]:
    """``(spool, p_load_pa)``: spool position (-1..1) and load pressure [Pa] of the actuator."""
    i = _actuator_id(model, actuator)
    adr = int(model.actuator_actadr[i])
    params = hydraulic_params(model, i)
    return float(data.act[adr]), float(data.act[adr + 1] * params.supply_pressure)


def valve_voltage(model: mujoco.MjModel, data: mujoco.MjData, actuator: str | int = "joint2") -> float:
    """Servo amplifier output v [V] the plugin applies now (from ctrl, the joint angle and config)."""
    i = _actuator_id(model, actuator)
    params = hydraulic_params(model, i)
    joint = int(model.actuator_trnid[i, 0])
    theta = float(data.qpos[model.jnt_qposadr[joint]])
    limited = bool(model.actuator_ctrllimited[i]) and not (model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL)
    ctrlrange = tuple(model.actuator_ctrlrange[i]) if limited else None
    return float(_valve_voltage(params, data.ctrl[i], theta, ctrlrange=ctrlrange))
