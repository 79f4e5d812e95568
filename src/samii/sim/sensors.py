"""The base accelerometer: which sensor row it is, how it is read, what it reads at rest.

SAMII's base acceleration is measured by an accelerometer fixed to the beam's tip (on the arm's
mount). A real accelerometer is body-fixed and measures specific force, a - g, along its axis:
when the tip tilts by psi, a horizontal axis picks up g sin(psi) (first order in psi) and a
vertical one g cos(psi) (second order). The rig's "gravity removed" is the reading at rest
subtracted (a DAQ offset or AC coupling); the dynamic tilt term stays, as on the rig.

Two sensors are read (``BeamParams.accel_body_fixed`` chooses which the writer emits):
``framelinacc`` of the site ``base_accel`` (DESIGN.md's sensor, the default: the tip's
acceleration in the world frame, no tilt), read along the custom numeric
``samii_accel_direction`` (world +z when absent, as in models written before issue 8); or
MuJoCo's ``accelerometer`` on that site (specific force in the site frame, body-fixed), read
along the site's x axis.
"""

from __future__ import annotations

import mujoco
import numpy as np

from samii.sim.model import make_data

__all__ = ["SENSOR", "accel_weights", "accel_offset", "accel_site", "accel_axis_world", "output_rows", "ACCEL_DIRECTION"]

SENSOR = "base_accel"
#: Custom numeric of legacy (framelinacc) models: measuring direction in the world frame.
ACCEL_DIRECTION = "samii_accel_direction"


def _sensor(model: mujoco.MjModel) -> int:
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, SENSOR)
    if i < 0:
        raise ValueError(f"the model needs a sensor named {SENSOR!r} (accelerometer on the beam's tip)")
    return i


def accel_weights(model: mujoco.MjModel) -> tuple[int, np.ndarray]:
    """(address in sensordata, weights of its 3 components) whose dot product is the reading."""
    i = _sensor(model)
    adr = int(model.sensor_adr[i])
    kind = model.sensor_type[i]
    if kind == mujoco.mjtSensor.mjSENS_ACCELEROMETER:
        return adr, np.array([1.0, 0.0, 0.0])  # the site's x axis, body-fixed
    if kind == mujoco.mjtSensor.mjSENS_FRAMELINACC:
        n = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, ACCEL_DIRECTION)
        if n < 0:
            return adr, np.array([0.0, 0.0, 1.0])
        a, size = int(model.numeric_adr[n]), int(model.numeric_size[n])
        d = np.asarray(model.numeric_data[a : a + size], float)
        if d.size != 3 or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ValueError(f"custom numeric {ACCEL_DIRECTION!r} must hold a non-zero 3-vector, got {d.tolist()}")
        return adr, d / np.linalg.norm(d)
    raise ValueError(f"sensor {SENSOR!r} must be an accelerometer (or a framelinacc), got type {int(kind)}")


def accel_site(model: mujoco.MjModel) -> int:
    """Id of the site the accelerometer sits on (the beam's tip)."""
    return int(model.sensor_objid[_sensor(model)])


def accel_axis_world(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """The accelerometer's measuring axis in the world frame in ``data``'s pose (a body-fixed axis turned by its site)."""
    _, direction = accel_weights(model)
    if model.sensor_type[_sensor(model)] == mujoco.mjtSensor.mjSENS_ACCELEROMETER:
        direction = data.site_xmat[accel_site(model)].reshape(3, 3) @ direction
    return direction


def accel_offset(model: mujoco.MjModel) -> float:
    """The reading at rest in the ``home`` keyframe (static equilibrium): what "gravity removed" subtracts."""
    data = make_data(model)
    adr, w = accel_weights(model)
    return float(w @ data.sensordata[adr : adr + 3])


def output_rows(model: mujoco.MjModel) -> tuple[int, np.ndarray]:
    """The sensor row of theta, and the weights over all sensor rows that make the accelerometer's reading."""
    theta = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, "theta")
    if theta < 0:
        raise ValueError("the model needs a sensor named 'theta' (jointpos of joint 2)")
    w = np.zeros(model.nsensordata)
    adr, weights = accel_weights(model)
    w[adr : adr + 3] = weights  # the accelerometer's reading
    return int(model.sensor_adr[theta]), w
