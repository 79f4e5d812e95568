"""Writes the MJCF of SAMII on its flexible beam from physical parameters.

``models/samii/samii.xml`` is this module's output for the tuned parameters
(``experiments/tune_model/tune.py`` rewrites it); the convergence study and
``load_model(overrides=...)`` call it with other values. One source of
geometry, so the committed XML and every variant agree.

Beam: rigid-finite-element (RFE) discretisation of an Euler-Bernoulli
cantilever. The beam of length L is cut into ``n_segments`` elements of
length l = L/n; each element's bending stiffness is lumped in one hinge at the
element centre with stiffness EI/l (the spring that makes a uniform moment
produce the exact end rotation of the element). Rigid bodies sit between
hinges: two half-length end bodies and n-1 full-length bodies, each with the
mass and rotary inertia of its piece of beam. A clamp hinge with a torsional
spring and damper at x = 0 models the clamp (public TMM chain: clamp
torsional spring/damper -> beam -> l0 -> joint 1 spring/damper -> l1 -> joint 2 -> l2).
Optionally the clamp is a standard linear solid: a Maxwell arm (spring k2 in
series with damper c2) parallel to the clamp spring, built from a massless-ish
internal node (a hinge to the world with joint damping c2) and a fixed tendon
clamp - node with stiffness k2; see ``BeamParams`` and the model card.

Geometry (issue 8): the beam's own frame has it along +x, clamped at the origin, bending about
its y axis; ``BeamParams.pitch_deg`` tilts it up about world y (90: a vertical cantilever, the
default model; 0: horizontal). The arm stands upright on the beam's end: l0 is a post rigidly
fixed there, joints 1, 2 and 3 are hinges about y (joint 2 about -y, so theta is positive in the
beam's slope sense), so the nominal pose (-90, 90, 90, 0, 0, 0) deg has l1 and link 2 vertical
and link 3 pointing north (+x). ``ArmParams.heading_deg`` turns the arm about the vertical
(north across the beam) and makes the beam spatial (lateral bending and torsion hinges). The
base accelerometer (site and sensor ``base_accel``) reads the beam's transverse direction in
joint 2's plane; ``BeamParams.accel_body_fixed`` chooses the design's ideal sensor (world frame)
or a real, tilting one (``samii.sim.sensors``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

import mujoco
import numpy as np

from samii.notebook import TMM
from samii.sim.hydraulic_reference import ATTRIBUTES, VALVE_OPTIONS, HydraulicConfigError, HydraulicParams
from samii.sim.sensor_dynamics import FIELDS, NUMERIC, SensorDynamics

__all__ = ["BeamParams", "ArmParams", "HydraulicConfig", "SamiiParams", "NOMINAL_POSE_RAD", "samii_xml"]

#: Nominal pose of the notebook (chapter 9): joint 1 = -90 deg, joint 2 = 90 deg, joint 3 = 90 deg, joints 4-6 = 0.
NOMINAL_POSE_RAD = (-math.pi / 2, math.pi / 2, math.pi / 2, 0.0, 0.0, 0.0)


#: Most beam elements accepted: the base modes converge at 4 (experiments/convergence); each element
#: adds a body and a hinge, and linearisation cost grows with the cube of the state size.
MAX_BEAM_SEGMENTS = 40


@dataclass(frozen=True)
class BeamParams:
    """The flexible base. Public TMM values plus the tuned clamp and damping knobs."""

    length_m: float = TMM["beam"]["length_m"]
    EI_Nm2: float = TMM["beam"]["EI_Nm2"]
    mass_per_length_kg_m: float = TMM["beam"]["mass_per_length_kg_m"]
    n_segments: int = 4
    #: Square tube outer side for visuals and the minor inertias. A steel tube
    #: with EI = 339134.5 N m^2 and 5.7281 kg/m has I/A = a^2/6 (thin wall) =
    #: 1.70e-6/7.30e-4 -> a = 0.118 m.
    section_side_m: float = 0.118
    #: Relaxed (static) stiffness k1 of the clamp and a parallel viscous damper.
    clamp_stiffness_Nm_rad: float = 3.0e5
    clamp_damping_Nms_rad: float = 300.0
    #: Maxwell arm of a standard-linear-solid clamp (viscoelastic bolted clamp and
    #: foundation): spring k2 in series with a damper c2 = k2 * relaxation time,
    #: in parallel with k1. Its loss k2 w tau / (1 + (w tau)^2) peaks at w = 1/tau,
    #: so placed near mode 1 it damps mode 1 far more than mode 3. 0 = off (no
    #: Maxwell node in the MJCF: the plain spring-damper clamp).
    clamp_maxwell_stiffness_Nm_rad: float = 0.0
    clamp_relaxation_time_s: float = 1.0 / 10.886
    #: Stiffness-proportional damping of the beam hinges: c = beta * k [s].
    beam_damping_time_s: float = 2.0e-4
    #: Torsional stiffness GJ of the beam [N m^2]: the thin-walled square steel tube of
    #: ``section_side_m`` whose area is mass_per_length / 7850 kg/m^3 has wall t = A/(4a) =
    #: 1.55 mm and J = a^3 t = 2.54e-6 m^4 (its I = 2/3 a^3 t = 1.69e-6 m^4 gives back the
    #: public EI with E = 200 GPa); G = 79.3 GPa. Used only by the spatial beam (see ArmParams.heading_deg).
    GJ_Nm2: float = 79.3e9 * 0.118**2 * 5.7281 / (4 * 7850.0)
    #: Clamp stiffness in the beam's other bending plane (about z) and in torsion (about x);
    #: spatial beam only. No public figure: assumed as stiff as the vertical clamp, and rigid-ish in torsion.
    clamp_lateral_stiffness_Nm_rad: float = 1.331e5
    clamp_torsion_stiffness_Nm_rad: float = 1.0e6
    #: Inclination of the beam from horizontal [deg]: 0 a horizontal cantilever (the beam
    #: along +x), 90 a vertical mast (clamped at the foot, the beam along +z). The arm stands
    #: upright on the tip either way, so at 90 deg its links at the nominal pose continue the
    #: beam's axis (the planar, collinear chain of the public transfer-matrix model).
    pitch_deg: float = 0.0
    #: Where the base accelerometer sits along the beam's axis, from the beam's end [m]:
    #: 0 on the end, > 0 beyond it (rigid with the tip: on the post l0 when the beam is
    #: vertical, a point on the beam's axis line in mid-air when it is horizontal), < 0 inboard
    #: on the beam's last element (at most half an element).
    accel_offset_m: float = 0.0
    #: The base accelerometer. 0: the design's sensor, the tip's acceleration along the beam's
    #: transverse direction w in the world frame, gravity removed (MuJoCo framelinacc). 1: a real,
    #: body-fixed accelerometer (MuJoCo accelerometer: specific force along an axis that tilts
    #: with the tip), whose horizontal axis also reads g sin(tilt); see the model card.
    accel_body_fixed: float = 0.0
    #: A body on a compliant mount at the beam's end (a valve block, a cable carrier, an
    #: instrument box on a bracket): a mass on a slider along the accelerometer's direction, on a
    #: spring and a damper set by its own natural frequency and damping ratio on a rigid mount,
    #: k = m (2 pi f)^2, c = 2 zeta (2 pi f) m. It adds one structural mode near f that the
    #: modal model of modes 1-3 lacks, and a notch in the tip's response at f (the vibration
    #: absorber's antiresonance). Mass 0 = none: no body in the MJCF (the model as without it).
    #: ``samii diagnose --baseline sim`` carries an extra base mode into the simulator as this body.
    tip_body_mass_kg: float = 0.0
    tip_body_freq_hz: float = 15.0
    tip_body_damping_ratio: float = 0.02

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "n_segments":
                if not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_BEAM_SEGMENTS:
                    raise ValueError(
                        f"n_segments must be an integer in 1...{MAX_BEAM_SEGMENTS}, got {v!r} (4 converge the base modes: experiments/convergence)"
                    )
            elif f.name == "accel_body_fixed":
                if v not in (0.0, 1.0):
                    raise ValueError(f"beam parameter accel_body_fixed must be 0 (ideal, world frame) or 1 (body-fixed), got {v!r}")
            elif f.name == "accel_offset_m":
                if not math.isfinite(v):
                    raise ValueError(f"beam parameter accel_offset_m must be finite, got {v!r}")
            elif f.name == "pitch_deg":
                if not (math.isfinite(v) and 0 <= v <= 90):
                    raise ValueError(f"beam parameter pitch_deg must lie in 0...90 deg, got {v!r}")
            elif not (math.isfinite(v) and v >= 0) or (
                v == 0
                and f.name
                not in (
                    "clamp_damping_Nms_rad",
                    "beam_damping_time_s",
                    "clamp_maxwell_stiffness_Nm_rad",
                    "tip_body_mass_kg",
                    "tip_body_damping_ratio",
                )
            ):
                raise ValueError(f"beam parameter {f.name} must be finite and positive, got {v!r}")


@dataclass(frozen=True)
class ArmParams:
    """The arm: TMM links l0, l1, l2 plus a light wrist and the held-joint servos."""

    joint1_stiffness_Nm_rad: float = 2.0e4
    joint1_damping_Nms_rad: float = 20.0
    #: Joints 3-6 are held by stiff position servos, modelled as springs about
    #: the nominal angle; stiff enough that their modes lie far above 25 Hz.
    held_stiffness_Nm_rad: float = 2.0e3
    held_damping_Nms_rad: float = 2.0
    #: Reflected inertia of the held joints' servo drives. Without it the wrist
    #: joints that turn about a link's own axis (inertia ~1e-5 kg m^2) would have
    #: modes near 1.5e4 rad/s; with it the held-joint modes sit near 70 Hz.
    held_armature_kgm2: float = 0.01
    #: Joint-2 viscous friction (rod seals, bearings).
    joint2_damping_Nms_rad: float = 0.0
    #: Where "north" (the direction link 3 points at the nominal pose) lies, measured from the
    #: beam's axis (+x, clamp to tip) about +z [deg]. 0: north along the beam, link 2 swings in
    #: the beam's vertical bending plane (planar model). Any other value turns the arm on the tip
    #: and makes the beam spatial (bending about y and z, torsion about x, each hinge from EI or
    #: GJ); the accelerometer then measures along north, the direction joint 2 drives.
    heading_deg: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "heading_deg":
                if not (math.isfinite(v) and -360 <= v <= 360):
                    raise ValueError(f"arm parameter heading_deg must lie in -360...360 deg, got {v!r}")
            elif f.name in ("joint1_stiffness_Nm_rad", "held_stiffness_Nm_rad", "held_armature_kgm2"):
                if not (math.isfinite(v) and v > 0):
                    raise ValueError(f"arm parameter {f.name} must be finite and positive, got {v!r}")
            elif not (math.isfinite(v) and v >= 0):
                raise ValueError(f"arm parameter {f.name} must be finite and >= 0, got {v!r}")


@dataclass(frozen=True)
class HydraulicConfig:
    """Config attributes of the samii.hydraulic plugin (SI units; see sim/hydraulic.c); checked
    by the plugin's own rules (samii.sim.hydraulic_reference.ATTRIBUTES) when constructed."""

    supply_pressure: float = 7.0e6
    bulk_modulus: float = 0.7e9
    total_volume: float = 20e-6
    displacement: float = 1.7e-6
    leakage_coefficient: float = 1.1e-13
    valve_time_constant: float = 6.3e-3
    rated_flow: float = 8.3e-6
    rated_voltage: float = 10.0
    #: 1 V per degree: the rig's unity position feedback with theta in degrees.
    position_gain: float = 180.0 / math.pi
    reference_angle: float = math.pi / 2
    #: The valve between amplifier and spool (hydraulic_reference.VALVE_OPTIONS); 0 = none, the
    #: default, and then not written to the MJCF (the model is as it was without these options).
    command_delay: float = 0.0  #: [s] the spool follows the amplifier output this late
    valve_dead_band: float = 0.0  #: [V] dead band on the valve's input
    valve_saturation: float = 0.0  #: [V] the valve's input limited to +- this
    #: [1] then a negative input passes with gain 1 - this (unequal flow gains of the two directions)
    valve_asymmetry: float = 0.0

    def __post_init__(self) -> None:
        try:
            HydraulicParams.from_config({**{k: "1" for k in ATTRIBUTES}, **self.valve_config()}, source="hydraulic")
        except HydraulicConfigError as exc:
            raise ValueError(str(exc).replace("hydraulic: config attribute '", "hydraulic parameter '")) from None

        for name, (unit, rule) in ATTRIBUTES.items():
            v = getattr(self, name)
            ok = math.isfinite(v) and (v > 0 if rule == "positive" else v >= 0 if rule == "nonnegative" else True)
            if not ok:
                need = {"positive": "> 0", "nonnegative": ">= 0", "finite": "finite"}[rule]
                raise ValueError(
                    f"hydraulic parameter {name} must be a finite number {need if rule != 'finite' else ''} in {unit}, got {v!r}".replace("  ", " ")
                )

    def valve_config(self) -> dict[str, str]:
        """The valve options that are set (non-zero), as MJCF config text."""

        return {k: _fmt(getattr(self, k)) for k in VALVE_OPTIONS if getattr(self, k) != 0}


@dataclass(frozen=True)
class SamiiParams:
    beam: BeamParams = field(default_factory=BeamParams)
    arm: ArmParams = field(default_factory=ArmParams)
    hydraulic: HydraulicConfig = field(default_factory=HydraulicConfig)
    timestep_s: float = 1e-3
    #: The sensors' own dynamics (ideal by default; samii.sim.sensor_dynamics).
    sensor: SensorDynamics = field(default_factory=SensorDynamics)

    #: Largest physics step accepted [s]: about the 4.5 ms valve time constant; longer steps cannot
    #: resolve the valve or the 45 Hz held-joint-3 mode (a 3 ms step already diverges: the
    #: divergence tests use it, and a run that diverges is reported, not written).
    MAX_TIMESTEP_S = 5e-3

    def __post_init__(self) -> None:
        dt = self.timestep_s
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and 0 < dt <= self.MAX_TIMESTEP_S):
            raise ValueError(f"timestep_s must be a number in (0, {self.MAX_TIMESTEP_S:g}] s, got {dt!r}")
        b = self.beam
        if b.tip_body_mass_kg > 0 and 2 * math.pi * b.tip_body_freq_hz * dt > 1.0:  # its spring is explicit: w dt <= 1
            raise ValueError(
                f"beam.tip_body_freq_hz = {b.tip_body_freq_hz:g} Hz is too fast for the {dt:g} s physics step "
                f"(at most {1 / (2 * math.pi * dt):.4g} Hz)"
            )
        self.sensor.check_rate(1.0 / dt)  # (the sensors' filters run at the physics rate)

    def as_dict(self) -> dict:
        return asdict(self)


# --- wrist (links 3-6): not in the public TMM, which lumps everything outboard
# of joint 2 into l2. Light estimates; link 2's own mass properties are chosen so
# that the composite outboard of joint 2 keeps the TMM's l2 mass, centre of mass
# and inertia at the nominal pose.
_WRIST = (
    # name, mass [kg], length along +x [m]
    ("link3", 0.20, 0.15),
    ("link4", 0.08, 0.08),
    ("link5", 0.06, 0.05),
    ("link6", 0.06, 0.05),
)


#: Smallest rotary inertia [kg m^2] of the Maxwell node of the standard-linear-solid clamp
#: (joint armature; the body itself carries 1e-6 of it); the writer raises it to k2 dt^2
#: when the tendon spring is stiffer, so that the explicitly integrated spring stays
#: resolved (sqrt(k2/J) dt <= 1). The node is an internal state of the clamp material, not a
#: mass: J s^2 + c2 s + k2 has the relaxation root -k2/c2 (1 + J k2/c2^2 + ...) and a fast
#: root near -c2/J (-8.7e3 rad/s for the tuned clamp), far above every mode that matters. With
#: implicitfast the joint damping c2 is integrated implicitly.
MAXWELL_NODE_INERTIA_KGM2 = 0.01


_X, _Y, _Z = np.eye(3)


def _quat(axis: np.ndarray, angle: float) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation by ``angle`` about ``axis``."""
    q = np.zeros(4)
    mujoco.mju_axisAngle2Quat(q, axis, angle)
    return q


def _compose(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The rotation p q (q first, then p)."""
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, p, q)
    return out


def _fmt(x: float) -> str:
    return f"{x + 0.0:.10g}"  # + 0.0: no "-0"


def _vec(*xs: float) -> str:
    """Positions, quaternions, inertias: rounding residue of trigonometry (< 1e-12) written as 0."""
    return " ".join(_fmt(0.0 if abs(x) < 1e-12 else x) for x in xs)


def _box_inertia(m: float, a: float, b: float, c: float) -> tuple[float, float, float]:
    """Diagonal inertia of a solid box with side lengths a, b, c along x, y, z."""
    return (m * (b * b + c * c) / 12, m * (a * a + c * c) / 12, m * (a * a + b * b) / 12)


def _link2_properties() -> tuple[float, tuple[float, float, float], tuple[float, float, float]]:
    """Mass, CoM (link-2 frame) and diagonal inertia of link 2 itself, such that
    link 2 plus the wrist at the nominal pose has the TMM l2 figures."""
    l2 = TMM["link_l2"]
    m_tot, cg, I_tot = l2["mass_kg"], l2["cg_m"], l2["I_cg_kgm2"]
    z3 = l2["length_m"]
    parts = []  # (mass, x, z, Iyy about own CoM)
    x = 0.0
    for _, m, length in _WRIST:
        parts.append((m, x + length / 2, z3, m * length**2 / 12))
        x += length
    m_w = sum(p[0] for p in parts)
    m2 = m_tot - m_w
    x2 = -sum(p[0] * p[1] for p in parts) / m2
    z2 = (m_tot * cg - sum(p[0] * p[2] for p in parts)) / m2
    I_wrist = sum(p[3] + p[0] * ((p[1]) ** 2 + (p[2] - cg) ** 2) for p in parts)
    Iyy2 = I_tot - I_wrist - m2 * (x2**2 + (z2 - cg) ** 2)
    if Iyy2 <= 0:
        raise ValueError("wrist too heavy for the TMM l2 inertia")
    # about the link axis (z) and x: a 0.08 m wide body; x same as y (axisymmetric estimate)
    Izz2 = m2 * 0.08**2 / 8
    return m2, (x2, 0.0, z2), (Iyy2, Iyy2, Izz2)


def samii_xml(params: SamiiParams = SamiiParams(), *, keyframe_qpos=None, keyframe_act=None) -> str:
    """MJCF text of SAMII on its beam for ``params``.

    ``keyframe_qpos``/``keyframe_act`` give the ``home`` keyframe (static
    equilibrium); by default the undeformed beam at the nominal pose.
    """
    b, a, h = params.beam, params.arm, params.hydraulic
    n = b.n_segments
    L = b.length_m
    ell = L / n
    k_hinge = b.EI_Nm2 / ell
    c_hinge = b.beam_damping_time_s * k_hinge
    heading = math.radians(a.heading_deg)
    pitch = math.radians(b.pitch_deg)
    q_beam = _quat(_Y, -pitch)  # the beam's frame in the world: its +x turns up by the pitch
    spatial = abs(math.remainder(a.heading_deg, 360.0)) > 1e-9
    k_torsion = b.GJ_Nm2 / ell
    s = b.section_side_m
    mu = b.mass_per_length_kg_m

    lines: list[str] = []
    add = lines.append
    add('<mujoco model="samii">')
    add("  <!-- Generated by samii.sim.mjcf.samii_xml; rewrite with experiments/tune_model/tune.py. See README.md (model card). -->")
    add('  <compiler angle="radian" autolimits="true"/>')
    # no geom collides (contype 0 everywhere): skipping collision detection saves ~8 % of a step
    add(f'  <option timestep="{_fmt(params.timestep_s)}" integrator="implicitfast">')
    add('    <flag contact="disable"/>')
    add("  </option>")
    add("  <extension>")
    add('    <plugin plugin="samii.hydraulic"/>')
    add("  </extension>")
    add("  <default>")
    add('    <default class="samii">')
    add('      <joint type="hinge" axis="0 1 0" limited="false"/>')
    add('      <geom contype="0" conaffinity="0" group="2"/>')
    add('      <site group="4"/>')
    add(f'      <default class="clamp"><joint stiffness="{_fmt(b.clamp_stiffness_Nm_rad)}" damping="{_fmt(b.clamp_damping_Nms_rad)}"/></default>')
    add(f"      <!-- EI/l = {_fmt(b.EI_Nm2)}/{_fmt(ell)}; damping = beam_damping_time * stiffness -->")
    add(f'      <default class="beam_hinge"><joint stiffness="{_fmt(k_hinge)}" damping="{_fmt(c_hinge)}"/></default>')
    if spatial:
        beta = b.beam_damping_time_s
        add("      <!-- spatial beam: bending about z (EI/l), torsion about x (GJ/l); the same stiffness-proportional damping -->")
        add(f'      <default class="beam_lateral"><joint axis="0 0 1" stiffness="{_fmt(k_hinge)}" damping="{_fmt(c_hinge)}"/></default>')
        add(f'      <default class="beam_torsion"><joint axis="1 0 0" stiffness="{_fmt(k_torsion)}" damping="{_fmt(beta * k_torsion)}"/></default>')
        add(
            f'      <default class="clamp_lateral"><joint axis="0 0 1" stiffness="{_fmt(b.clamp_lateral_stiffness_Nm_rad)}" damping="{_fmt(beta * b.clamp_lateral_stiffness_Nm_rad)}"/></default>'
        )
        add(
            f'      <default class="clamp_torsion"><joint axis="1 0 0" stiffness="{_fmt(b.clamp_torsion_stiffness_Nm_rad)}" damping="{_fmt(beta * b.clamp_torsion_stiffness_Nm_rad)}"/></default>'
        )
    add(
        f'      <default class="joint1"><joint stiffness="{_fmt(a.joint1_stiffness_Nm_rad)}" damping="{_fmt(a.joint1_damping_Nms_rad)}" springref="{_fmt(NOMINAL_POSE_RAD[0])}"/></default>'
    )
    add(f'      <default class="joint2"><joint damping="{_fmt(a.joint2_damping_Nms_rad)}"/></default>')
    add(
        f'      <default class="held"><joint stiffness="{_fmt(a.held_stiffness_Nm_rad)}" damping="{_fmt(a.held_damping_Nms_rad)}" armature="{_fmt(a.held_armature_kgm2)}"/></default>'
    )
    add('      <default class="beam_visual"><geom type="box" rgba="0.62 0.64 0.68 1"/></default>')
    add('      <default class="link_visual"><geom type="capsule" rgba="0.95 0.55 0.15 1"/></default>')
    add('      <default class="hydraulic_visual"><geom type="cylinder" rgba="0.25 0.35 0.75 1"/></default>')
    add("    </default>")
    add("  </default>")
    add("")
    add("  <worldbody>")
    add('    <body name="wall" childclass="samii">')
    block = np.zeros(3)  # the clamp block behind the beam's root, along its axis
    mujoco.mju_rotVecQuat(block, -0.15 * _X, q_beam)
    block_quat = "" if pitch == 0 else f' quat="{_vec(*q_beam)}"'
    add(f'      <geom name="clamp_block" type="box" pos="{_vec(*block)}"{block_quat} size="0.15 0.25 0.3" rgba="0.3 0.3 0.3 1"/>')
    add("    </body>")

    indent = "    "
    # Beam bodies: body 0 [0, l/2] (clamp hinge at 0), bodies 1..n-1 of length l, body n [L-l/2, L].
    for i in range(n + 1):
        seg_len = ell / 2 if i in (0, n) else ell
        pos = 0.0 if i == 0 else (ell / 2 if i == 1 else ell)
        m = mu * seg_len
        Ixx = m * s * s / 6  # thin-walled square tube: polar moment m a^2/6 (torsion, unused in-plane)
        _, Iyy, Izz = _box_inertia(m, seg_len, s, s)
        name = f"beam_{i}"
        cls = ' childclass="samii"' if i == 0 else ""
        if i == 0 and pitch != 0:
            cls += f' quat="{_vec(*q_beam)}"'
        add(f'{indent}<body name="{name}" pos="{_vec(pos, 0, 0)}"{cls}>')
        ind = indent + "  "
        if i == 0:
            add(f'{ind}<joint name="clamp" class="clamp"/>')
            if spatial:
                add(f'{ind}<joint name="clamp_lateral" class="clamp_lateral"/>')
                add(f'{ind}<joint name="clamp_torsion" class="clamp_torsion"/>')
        else:
            add(f'{ind}<joint name="beam_hinge_{i}" class="beam_hinge"/>')
            if spatial:
                add(f'{ind}<joint name="beam_lateral_{i}" class="beam_lateral"/>')
                add(f'{ind}<joint name="beam_torsion_{i}" class="beam_torsion"/>')
        add(f'{ind}<inertial pos="{_vec(seg_len / 2, 0, 0)}" mass="{_fmt(m)}" diaginertia="{_vec(Ixx, Iyy, Izz)}"/>')
        add(f'{ind}<geom class="beam_visual" pos="{_vec(seg_len / 2, 0, 0)}" size="{_vec(seg_len / 2, s / 2, s / 2)}"/>')
        indent = ind

    # Tip of the beam: accelerometer site and the arm.
    tip = ell / 2
    l0, l1 = TMM["link_l0"], TMM["link_l1"]
    if not -tip <= b.accel_offset_m <= 1.0:
        raise ValueError(
            f"beam.accel_offset_m = {b.accel_offset_m} m: the accelerometer must sit on the last beam element "
            f"or the mount, {-tip:.3g} ... 1 m from the beam's end"
        )
    # the accelerometer: body-fixed, measuring along its site's x axis (samii.sim.sensors). Planar
    # beam: the beam's transverse direction w in joint 2's plane (local z of the beam: vertical
    # for the horizontal beam, horizontal for the vertical one); spatial beam: the horizontal
    # direction positive theta drives link 2's top, -north, R_y(pitch) R_z(heading + pi) here
    q_site = _compose(_quat(_Y, pitch), _quat(_Z, heading + math.pi)) if spatial else _quat(_Y, -math.pi / 2)  # x -> z
    add(f'{indent}<site name="base_accel" pos="{_vec(tip + b.accel_offset_m, 0, 0)}" quat="{_vec(*q_site)}" size="0.02"/>')
    # l0 upright in the world and turned to the heading: R_y(pitch) R_z(heading) in the tip's frame
    q_l0 = _compose(_quat(_Y, pitch), _quat(_Z, heading))
    l0_quat = "" if pitch == 0 and not spatial else f' quat="{_vec(*q_l0)}"'
    # l0's foot: on the beam's upper face when horizontal, on its end face when vertical
    foot = (tip + math.sin(pitch) * s / 2, 0.0, math.cos(pitch) * s / 2)
    add(f'{indent}<body name="l0" pos="{_vec(*foot)}"{l0_quat}>')
    ind = indent + "  "
    add(f"{ind}<!-- l0: TMM link l0 (mounting post), rigidly fixed on the beam tip -->")
    add(
        f'{ind}<inertial pos="{_vec(0, 0, l0["cg_m"])}" mass="{_fmt(l0["mass_kg"])}" diaginertia="{_vec(l0["I_cg_kgm2"], l0["I_cg_kgm2"], l0["mass_kg"] * 0.1**2 / 2)}"/>'
    )
    add(
        f'{ind}<geom class="link_visual" type="box" pos="{_vec(0, 0, l0["length_m"] / 2)}" size="0.09 0.09 {_fmt(l0["length_m"] / 2)}" rgba="0.35 0.35 0.38 1"/>'
    )
    # joint 1 at the top of l0; body quat R_y(+90deg) so that q1 = -90 deg leaves l1 vertical
    qy = lambda ang: _vec(*_quat(_Y, ang))  # noqa: E731
    add(f'{ind}<body name="link1" pos="{_vec(0, 0, l0["length_m"])}" quat="{qy(math.pi / 2)}">')
    ind2 = ind + "  "
    add(f'{ind2}<joint name="joint1" class="joint1"/>')
    # body frame = parent * quat * R_y(q1): identity at q1 = -90 deg, so l1 points up (+z)
    ind3 = ind2
    add(
        f'{ind3}<inertial pos="{_vec(0, 0, l1["cg_m"])}" mass="{_fmt(l1["mass_kg"])}" diaginertia="{_vec(l1["I_cg_kgm2"], l1["I_cg_kgm2"], l1["mass_kg"] * 0.06**2 / 2)}"/>'
    )
    add(f'{ind3}<geom class="link_visual" fromto="0 0 0 0 0 {_fmt(l1["length_m"])}" size="0.05"/>')
    add(f'{ind3}<geom class="hydraulic_visual" pos="0 0 {_fmt(l1["length_m"])}" euler="1.5707963 0 0" size="0.06 0.07"/>')
    # joint 2 at the top of l1, turning about -y: theta positive in the slope sense of the beam
    # (turning +x toward +z, as dw/dx > 0 with w up), the convention in which eq 9.4's B signs
    # hold; body quat R_y(+90deg) so that q2 = +90 deg (R_y(-90deg)) leaves link 2 vertical
    m2, c2, I2 = _link2_properties()
    add(f'{ind3}<body name="link2" pos="{_vec(0, 0, l1["length_m"])}" quat="{qy(math.pi / 2)}">')
    ind4 = ind3 + "  "
    add(f'{ind4}<joint name="joint2" class="joint2" axis="0 -1 0"/>')
    ind5 = ind4
    add(f"{ind5}<!-- link 2 plus links 3-6 at the nominal pose = TMM l2 (mass, cg, inertia); see README -->")
    add(f'{ind5}<inertial pos="{_vec(*c2)}" mass="{_fmt(m2)}" diaginertia="{_vec(*I2)}"/>')
    add(f'{ind5}<geom class="link_visual" fromto="0 0 0 0 0 {_fmt(TMM["link_l2"]["length_m"])}" size="0.04"/>')
    add(f'{ind5}<body name="link3" pos="0 0 {_fmt(TMM["link_l2"]["length_m"])}">')
    ind6 = ind5 + "  "
    add(f'{ind6}<joint name="joint3" class="held" springref="{_fmt(NOMINAL_POSE_RAD[2])}"/>')
    # links 3-6 along local z; R_y(q3 = 90deg) points them along +x
    x = 0.0
    body_ind = ind6
    opened = 1
    for j, (name, m, length) in enumerate(_WRIST):
        if j > 0:
            add(f'{body_ind}<body name="{name}" pos="0 0 {_fmt(x_prev_len)}">')  # noqa: F821
            body_ind += "  "
            opened += 1
            axis = {"link4": "0 0 1", "link5": "0 1 0", "link6": "0 0 1"}[name]
            add(f'{body_ind}<joint name="joint{j + 3}" class="held" axis="{axis}"/>')
        Ixx, Iyy, Izz = _box_inertia(m, 0.03, 0.03, length)
        add(f'{body_ind}<inertial pos="0 0 {_fmt(length / 2)}" mass="{_fmt(m)}" diaginertia="{_vec(Ixx, Iyy, Izz)}"/>')
        add(f'{body_ind}<geom class="link_visual" fromto="0 0 0 0 0 {_fmt(length)}" size="{_fmt(0.03 - 0.004 * j)}"/>')
        x_prev_len = length
        x += length
    add(f'{body_ind}<site name="end_effector" pos="0 0 {_fmt(x_prev_len)}" size="0.015"/>')
    for _ in range(opened - 1):
        body_ind = body_ind[:-2]
        add(f"{body_ind}</body>")
    add(f"{ind5}</body>")  # link3
    add(f"{ind3}</body>")  # link2
    add(f"{ind}</body>")  # link1
    add(f"{indent}</body>")  # l0
    tip_body = b.tip_body_mass_kg > 0
    if tip_body:
        mb, wb = b.tip_body_mass_kg, 2 * math.pi * b.tip_body_freq_hz
        axis = np.zeros(3)  # along the accelerometer's measuring direction, in the tip's frame
        mujoco.mju_rotVecQuat(axis, _X, q_site)
        side = 0.05  # a cube of this half-side beside the beam's end, clear of the post l0
        add(
            f"{indent}<!-- beam.tip_body: {_fmt(mb)} kg on a mount of {_fmt(b.tip_body_freq_hz)} Hz, damping ratio "
            f"{_fmt(b.tip_body_damping_ratio)} (k = m w^2, c = 2 zeta w m), sliding along the accelerometer's direction -->"
        )
        add(f'{indent}<body name="tip_body" pos="{_vec(tip, s / 2 + side, 0)}">')
        add(
            f'{indent}  <joint name="tip_body" type="slide" axis="{_vec(*axis)}" stiffness="{_fmt(mb * wb**2)}" '
            f'damping="{_fmt(2 * b.tip_body_damping_ratio * wb * mb)}"/>'
        )
        add(f'{indent}  <inertial pos="0 0 0" mass="{_fmt(mb)}" diaginertia="{_vec(*_box_inertia(mb, 2 * side, 2 * side, 2 * side))}"/>')
        add(f'{indent}  <geom type="box" size="{_vec(side, side, side)}" rgba="0.2 0.6 0.3 1"/>')
        add(f"{indent}</body>")
    for _ in range(n + 1):
        indent = indent[:-2]
        add(f"{indent}</body>")
    maxwell = b.clamp_maxwell_stiffness_Nm_rad > 0
    if maxwell:
        k2 = b.clamp_maxwell_stiffness_Nm_rad
        c2 = k2 * b.clamp_relaxation_time_s
        j_body = 1e-6
        add("    <!-- standard-linear-solid clamp: the Maxwell arm's internal node (damper c2 to the wall),")
        add("         joined to the clamp hinge by the tendon spring k2 below; no geom, not a physical mass -->")
        add('    <body name="clamp_maxwell_node" childclass="samii">')
        # the tendon spring k2 is integrated explicitly: J >= k2 dt^2 keeps the node's own
        # (overdamped) oscillator resolved, sqrt(k2/J) dt <= 1, so the energy never overshoots
        j_node = max(MAXWELL_NODE_INERTIA_KGM2, k2 * params.timestep_s**2)
        add(f'      <joint name="clamp_maxwell" damping="{_fmt(c2)}" armature="{_fmt(j_node - j_body)}"/>')
        add(f'      <inertial pos="0 0 0" mass="1e-3" diaginertia="{_vec(j_body, j_body, j_body)}"/>')
        add("    </body>")
    add("  </worldbody>")
    add("")
    if maxwell:
        add("  <tendon>")
        add(
            f"    <!-- Maxwell spring k2 between the clamp hinge and the node: length q_clamp - q_node; relaxation time c2/k2 = {_fmt(b.clamp_relaxation_time_s)} s -->"
        )
        add(f'    <fixed name="clamp_maxwell" stiffness="{_fmt(k2)}" springlength="0">')
        add('      <joint joint="clamp" coef="1"/>')
        add('      <joint joint="clamp_maxwell" coef="-1"/>')
        add("    </fixed>")
        add("  </tendon>")
        add("")
    add("  <actuator>")
    add('    <plugin name="joint2" joint="joint2" plugin="samii.hydraulic" actdim="2" ctrlrange="-10 10">')
    hyd_units = {
        "supply_pressure": "Pa",
        "bulk_modulus": "Pa",
        "total_volume": "m^3",
        "displacement": "m^3/rad",
        "leakage_coefficient": "m^3/(s Pa)",
        "valve_time_constant": "s",
        "rated_flow": "m^3/s",
        "rated_voltage": "V",
        "position_gain": "V/rad",
        "reference_angle": "rad",
    }
    for key, unit in hyd_units.items():
        add(f'      <config key="{key}" value="{_fmt(getattr(h, key))}"/>  <!-- {unit} -->')

    for key, value in h.valve_config().items():
        add(f'      <config key="{key}" value="{value}"/>  <!-- {VALVE_OPTIONS[key][0]} -->')
    add("    </plugin>")
    add("  </actuator>")
    add("")
    add("  <sensor>")
    add('    <jointpos name="theta" joint="joint2"/>')
    if b.accel_body_fixed:
        add("    <!-- body-fixed accelerometer on the tip (specific force a - g in the site frame; its x axis is read and")
        add("         its reading at rest removed in samii.sim.simulate: a tilt of a horizontal axis reads g sin(tilt)) -->")
        add('    <accelerometer name="base_accel" site="base_accel"/>')
    else:
        add(
            "    <!-- the tip's acceleration in the world frame (reads a - g), read along the direction w below, gravity removed in samii.sim.simulate -->"
        )
        add('    <framelinacc name="base_accel" objtype="site" objname="base_accel"/>')
    add("  </sensor>")
    add("")
    sensor = params.sensor
    if not b.accel_body_fixed or not sensor.ideal:
        add("  <custom>")
    if not b.accel_body_fixed:
        # w in the world frame at the nominal geometry: the site's x axis
        direction = np.zeros(3)
        mujoco.mju_rotVecQuat(direction, _X, _compose(q_beam, q_site))
        add("    <!-- measuring direction of the base accelerometer, world frame (samii.sim.sensors) -->")
        add(f'    <numeric name="samii_accel_direction" data="{_vec(*direction)}"/>')
    if not sensor.ideal:
        add(f"    <!-- the sensors' own dynamics (samii.sim.sensor_dynamics): {', '.join(f'{n} [{u}]' for n, u in FIELDS)} -->")
        add(f'    <numeric name="{NUMERIC}" data="{" ".join(_fmt(v) for v in sensor.values())}"/>')
    if not b.accel_body_fixed or not sensor.ideal:
        add("  </custom>")
        add("")
    per_body = 3 if spatial else 1
    nq = per_body * (n + 1) + 6 + (1 if tip_body else 0) + (1 if maxwell else 0)
    if keyframe_qpos is None:  # in the tree's order: beam, arm, the tip body (after l0 in the last element), the Maxwell node
        keyframe_qpos = [0.0] * (per_body * (n + 1)) + list(NOMINAL_POSE_RAD) + ([0.0] if tip_body else []) + ([0.0] if maxwell else [])
    if keyframe_act is None:
        keyframe_act = [0.0, 0.0]
    if len(keyframe_qpos) != nq:
        raise ValueError(f"keyframe_qpos has {len(keyframe_qpos)} values, the model has nq = {nq}")
    add("  <keyframe>")
    full = lambda xs: " ".join(repr(float(x)) for x in xs)  # noqa: E731  (full precision: exact equilibrium)
    add("    <!-- static equilibrium under gravity at the nominal pose (samii.sim.equilibrium) -->")
    add(f'    <key name="home" qpos="{full(keyframe_qpos)}" act="{full(keyframe_act)}"/>')
    add("  </keyframe>")
    add("</mujoco>")
    return "\n".join(lines) + "\n"
