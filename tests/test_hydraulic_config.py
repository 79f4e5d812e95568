"""Every missing or non-physical samii.hydraulic config attribute stops loading, naming it.

Two layers are checked: the C plugin's ``init`` (MuJoCo's compiler fails with a ``ValueError``
whose message carries the plugin's warning, which names the attribute) and
``samii.sim.plugin.validate_spec`` / ``HydraulicParams`` (a ``HydraulicConfigError`` naming
attribute, value and expectation, before MuJoCo compiles).
"""

from __future__ import annotations

import dataclasses

import mujoco
import pytest

from samii.sim import plugin
from samii.sim.hydraulic_reference import ATTRIBUTES, NOMINAL, HydraulicConfigError, HydraulicParams

BAD_VALUES = {
    # rule: values that break it (unparsable, non-finite, out of range)
    "positive": ["0", "-1", "nan", "inf", "7 MPa"],
    "nonnegative": ["-1e-15", "nan", "-inf", "abc"],
    "finite": ["nan", "inf", "1.5 rad"],
}
CASES = [(name, value) for name, (_, rule) in ATTRIBUTES.items() for value in BAD_VALUES[rule]]


@pytest.fixture(scope="module", autouse=True)
def _registered():
    plugin.load_plugin()


def config_with(name, value):
    config = NOMINAL.to_config()
    if value is None:
        del config[name]
    else:
        config[name] = value
    return config


def compile_raw(xml):
    """Compile with MuJoCo alone (C validation only); return the error message."""
    with pytest.raises(ValueError, match="plugin->init failed") as info:
        mujoco.MjModel.from_xml_string(xml)
    return str(info.value)


@pytest.mark.parametrize("name", list(ATTRIBUTES))
def test_missing_attribute(name):
    config = config_with(name, None)
    message = compile_raw(plugin.probe_xml(config=config))
    assert f"missing config attribute '{name}'" in message
    with pytest.raises(HydraulicConfigError, match=f"actuator 'joint2': missing config attribute '{name}'"):
        plugin.validate_spec(mujoco.MjSpec.from_string(plugin.probe_xml(config=config)))
    with pytest.raises(HydraulicConfigError, match=f"missing config attribute '{name}'"):
        plugin.compile_spec(mujoco.MjSpec.from_string(plugin.probe_xml(config=config)))


@pytest.mark.parametrize("name, value", CASES)
def test_non_physical_attribute(name, value):
    config = config_with(name, value)
    message = compile_raw(plugin.probe_xml(config=config))
    unit, rule = ATTRIBUTES[name]
    assert f"'{name}' = '{value}' is invalid" in message
    expected = {"positive": "> 0", "nonnegative": ">= 0", "finite": "a finite number"}[rule]
    with pytest.raises(HydraulicConfigError) as info:
        plugin.validate_spec(mujoco.MjSpec.from_string(plugin.probe_xml(config=config)))
    text = str(info.value)
    assert f"'{name}'" in text and repr(value) in text and expected in text and unit in text


@pytest.mark.parametrize("name", ["leakage_coefficient", "position_gain"])
def test_zero_allowed_where_documented(name):
    params = dataclasses.replace(NOMINAL, **{name: 0.0})
    model = plugin.compile_spec(mujoco.MjSpec.from_string(plugin.probe_xml(params)))
    assert getattr(plugin.hydraulic_params(model), name) == 0.0


def test_negative_reference_angle_allowed():
    params = dataclasses.replace(NOMINAL, reference_angle=-1.5708)
    model = plugin.compile_spec(mujoco.MjSpec.from_string(plugin.probe_xml(params)))
    assert plugin.hydraulic_params(model).reference_angle == -1.5708


def test_unknown_attribute():
    config = {**NOMINAL.to_config(), "bulk_modulus_pa": "1e9"}
    with pytest.raises(ValueError, match="unrecognized attribute 'plugin:bulk_modulus_pa'"):
        mujoco.MjModel.from_xml_string(plugin.probe_xml(config=config))
    with pytest.raises(HydraulicConfigError, match="unknown config attribute 'bulk_modulus_pa'"):
        HydraulicParams.from_config(config)


@pytest.mark.parametrize("name", list(ATTRIBUTES))
def test_params_dataclass_rejects_non_physical(name):
    bad = {"positive": -1.0, "nonnegative": -1.0, "finite": float("nan")}[ATTRIBUTES[name][1]]
    with pytest.raises(HydraulicConfigError, match=f"'{name}' = "):
        dataclasses.replace(NOMINAL, **{name: bad})


@pytest.mark.parametrize(
    "old, new, c_message, py_message",
    [
        ('actdim="2"', 'actdim="1"', 'must have actdim="2"', "actdim = 1"),
        ('ctrllimited="true"', 'ctrllimited="true" gear="2"', "must have gear 1", "gear = 2"),
        ('type="hinge"', 'type="slide"', "must act on a hinge joint", None),
        ('ctrllimited="true"', 'ctrllimited="true" delay="0.002" nsample="3"', "must not have a delay", None),
    ],
)
def test_actuator_form_is_checked(old, new, c_message, py_message):
    xml = plugin.probe_xml().replace(old, new)
    assert c_message in compile_raw(xml)
    if py_message:
        with pytest.raises(HydraulicConfigError, match=py_message):
            plugin.validate_spec(mujoco.MjSpec.from_string(xml))
