// samii.hydraulic: servo-valve controlled rotary hydraulic actuator as a MuJoCo actuator plugin.
//
// Model: standard valve-controlled rotary actuator (H. E. Merritt, "Hydraulic Control Systems",
// Wiley 1967, chapters on control valves and valve-controlled motors: square-root orifice law of
// an ideal critical-centre valve, continuity of the two lines with oil compressibility and
// leakage; as specified in samii issue 2 and DESIGN.md):
//
//   servo amplifier   v     = clamp(u + Kp*(theta_ref - theta), -10 V, +10 V)
//   spool (1st order) x_dot = (v/V_rated - x)/tau_v,        |x| <= 1   (1 = full opening)
//   orifice flow      Q     = Kq * x * ssqrt((Ps - sign(x)*P)/Ps), ssqrt(u) = sign(u) sqrt(|u|)  [m^3/s]
//   continuity        P_dot = (4*beta_e/Vt) * (Q - Dm*theta_dot - Ctp*P)                [Pa/s]
//   torque            tau   = Dm * P                                                   [N m]
//
// with u = ctrl [V], theta/theta_dot = qpos/qvel of the actuator's hinge joint [rad, rad/s].
//
// States live in mjData.act (actdim="2"), so keyframes, resets, rollouts and mjd_transitionFD
// see them:
//   act[0] = x      spool position, normalised, -1..1
//   act[1] = P/Ps   load pressure over supply pressure (dimensionless, O(1), so a finite-difference
//                   step of ~1e-6 is well scaled; pressure in Pa would not be).
//
// MJCF (MuJoCo 4.0). The <extension> declaration is required. The config can be given directly on
// the actuator (implicit instance, one per actuator), or on an explicit <extension><plugin plugin="samii.hydraulic"><instance name=..>
// with <actuator><plugin instance=".." .../>; each instance must drive exactly one actuator:
//
//   <extension><plugin plugin="samii.hydraulic"/></extension>
//   <actuator>
//     <plugin name="joint2" joint="joint2" plugin="samii.hydraulic" actdim="2"
//             ctrlrange="-10 10" ctrllimited="true">
//       <config key="supply_pressure" value="7e6"/>  ... all ten attributes, SI units ...
//     </plugin>
//   </actuator>
//
// Integration. MuJoCo integrates act with explicit Euler from act_dot (state at t_n), then qvel,
// then qpos with the new qvel (semi-implicit Euler). The (theta_dot, P) pair is an oscillator (the
// oil column is a spring of stiffness 4*beta_e*Dm^2/Vt); explicit Euler on it adds energy at a rate
// that cancels a damping ratio of about h*omega_h/2 (0.027 at h = 1 ms: a fifth of the
// physical 0.14). The `advance` callback therefore re-evaluates the -Dm*theta_dot term of P_dot with
// the NEW velocity (symplectic Euler for the hydraulic spring, as MuJoCo does for qpos), for the
// Euler and implicit integrators. The spool lag is linear between steps (the amplifier output v is
// held over the step, as MuJoCo holds ctrl), so `advance` also replaces MuJoCo's explicit Euler
// x_{n+1} = x_n + h (v/V_rated - x_n)/tau_v by its exact solution
//   x_{n+1} = v/V_rated + (x_n - v/V_rated) exp(-h/tau_v):
// explicit Euler maps the valve pole -1/tau_v to log(1 - h/tau_v)/h, 171 rad/s instead of 159 at
// h = 1 ms (tau_v/h = 6.3); the exact step keeps it at -1/tau_v for any h. RK4 keeps MuJoCo's own
// integration (as does mj_step2 under RK4, which falls back to plain Euler). The spool position is
// clamped to the travel limit after integration.
//
// Errors. Invalid configuration is reported from `init` by mju_warning + return -1, as the plugin
// documentation asks (mju_error from a plugin would skip destructors in the Python bindings and the
// compiler). MuJoCo's compiler then fails; in Python (MuJoCo 4.0) the ValueError carries the
// warning text, which names the attribute, its value and what was expected. samii.sim.plugin
// checks the same rules on the MjSpec before compiling (HydraulicConfigError).
//
// No heap allocation per step: the parsed configuration is allocated once in `init`.

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <mujoco/mujoco.h>

#define SAMII_PLUGIN_NAME "samii.hydraulic"
#define SAMII_ACTDIM 2
#define SAMII_AMPLIFIER_LIMIT_V 10.0  // servo amplifier output saturation [V]

// Exported so that a loader can check which MuJoCo headers the library was compiled against.
#if defined(__GNUC__)
__attribute__((visibility("default")))
#endif
int samii_hydraulic_mujoco_version(void) { return mjVERSION_HEADER; }

// ------------------------------------------------------------------------------------------------
// configuration

// Attribute names, in the order MuJoCo stores them (mjModel.plugin_attr). Keep in sync with
// samii/sim/hydraulic_reference.py (ATTRIBUTES).
enum {
  ATTR_SUPPLY_PRESSURE = 0,   // Ps      [Pa]          > 0
  ATTR_BULK_MODULUS,          // beta_e  [Pa]          > 0
  ATTR_TOTAL_VOLUME,          // Vt      [m^3]         > 0
  ATTR_DISPLACEMENT,          // Dm      [m^3/rad]     > 0
  ATTR_LEAKAGE_COEFFICIENT,   // Ctp     [m^3/(s Pa)]  >= 0
  ATTR_VALVE_TIME_CONSTANT,   // tau_v   [s]           > 0
  ATTR_RATED_FLOW,            // Kq      [m^3/s]       > 0  (flow at x = 1, P = 0)
  ATTR_RATED_VOLTAGE,         // V_rated [V]           > 0  (command giving x = 1)
  ATTR_POSITION_GAIN,         // Kp      [V/rad]       >= 0 (0 = open loop)
  ATTR_REFERENCE_ANGLE,       // theta_ref [rad]       any finite value
  NATTR
};

static const char* const kAttributes[NATTR] = {
  "supply_pressure", "bulk_modulus", "total_volume", "displacement", "leakage_coefficient",
  "valve_time_constant", "rated_flow", "rated_voltage", "position_gain", "reference_angle",
};

// rule for each attribute: 1 = must be > 0, 0 = must be >= 0, -1 = any finite value
static const int kRule[NATTR] = {1, 1, 1, 1, 0, 1, 1, 1, 0, -1};

typedef struct {
  // where the instance acts
  int actuator;       // actuator id
  int actadr;         // first of the 2 act entries
  int qposadr;        // joint angle address
  int dofadr;         // joint velocity address

  // parameters, SI
  mjtNum value[NATTR];

  // derived constants
  mjtNum c_p;         // 4*beta_e/(Vt*Ps): d(P/Ps)/dt per unit of net flow [1/m^3]
  mjtNum torque_per;  // Dm*Ps: torque per unit of P/Ps [N m]
  mjtNum leak;        // Ctp*Ps: leakage flow per unit of P/Ps [m^3/s]
} Hydraulic;


// Parse one attribute; on failure write a message naming attribute, value and expectation.
static int parse_attribute(const mjModel* m, int instance, int i, mjtNum* out,
                           char* msg, size_t msgsz) {
  const char* text = mj_getPluginConfig(m, instance, kAttributes[i]);
  const char* expected = kRule[i] > 0 ? "a finite number > 0"
                         : kRule[i] == 0 ? "a finite number >= 0" : "a finite number";
  if (!text || !text[0]) {
    snprintf(msg, msgsz, "%s: missing config attribute '%s' (expected %s, SI units)",
             SAMII_PLUGIN_NAME, kAttributes[i], expected);
    return -1;
  }
  char* end = NULL;
  double value = strtod(text, &end);
  while (end && (*end == ' ' || *end == '\t' || *end == '\n' || *end == '\r')) {
    end++;
  }
  if (end == text || (end && *end) || !isfinite(value) ||
      (kRule[i] > 0 && !(value > 0)) || (kRule[i] == 0 && !(value >= 0))) {
    snprintf(msg, msgsz, "%s: config attribute '%s' = '%s' is invalid (expected %s, SI units)",
             SAMII_PLUGIN_NAME, kAttributes[i], text, expected);
    return -1;
  }
  *out = value;
  return 0;
}


// Build the instance from the model; NULL (after mju_warning) if anything is wrong.
static Hydraulic* hydraulic_create(const mjModel* m, int instance) {
  char msg[512];

  // exactly one actuator per instance
  int actuator = -1;
  for (int i = 0; i < m->nu; i++) {
    if (m->actuator_plugin[i] == instance) {
      if (actuator >= 0) {
        mju_warning("%s: plugin instance %d drives more than one actuator; "
                    "declare one instance per actuator", SAMII_PLUGIN_NAME, instance);
        return NULL;
      }
      actuator = i;
    }
  }
  if (actuator < 0) {
    mju_warning("%s: no actuator uses plugin instance %d", SAMII_PLUGIN_NAME, instance);
    return NULL;
  }
  const char* name = mj_id2name(m, mjOBJ_ACTUATOR, actuator);
  if (!name) name = "(unnamed)";

  // layout of act: exactly our two states, no extra dyntype state
  if (m->actuator_actnum[actuator] != SAMII_ACTDIM ||
      m->actuator_dyntype[actuator] != mjDYN_NONE) {
    mju_warning("%s: actuator '%s' must have actdim=\"%d\" and no dyntype (got actdim %d)",
                SAMII_PLUGIN_NAME, name, SAMII_ACTDIM, m->actuator_actnum[actuator]);
    return NULL;
  }
  if (m->actuator_delay[actuator] != 0) {
    mju_warning("%s: actuator '%s' must not have a delay (the plugin reads ctrl directly)",
                SAMII_PLUGIN_NAME, name);
    return NULL;
  }
  if (m->actuator_actlimited[actuator]) {
    mju_warning("%s: actuator '%s' must not be actlimited (the plugin limits its own states)",
                SAMII_PLUGIN_NAME, name);
    return NULL;
  }

  // transmission: a hinge joint with unit gear (theta, theta_dot are qpos, qvel; torque = Dm*P)
  int joint = m->actuator_trnid[2*actuator];
  if (m->actuator_trntype[actuator] != mjTRN_JOINT || joint < 0 ||
      m->jnt_type[joint] != mjJNT_HINGE) {
    mju_warning("%s: actuator '%s' must act on a hinge joint (joint=\"...\")",
                SAMII_PLUGIN_NAME, name);
    return NULL;
  }
  if (m->actuator_gear[6*actuator] != 1) {
    mju_warning("%s: actuator '%s' must have gear 1 (got %g); scale displacement instead",
                SAMII_PLUGIN_NAME, name, m->actuator_gear[6*actuator]);
    return NULL;
  }

  // parameters
  mjtNum value[NATTR];
  for (int i = 0; i < NATTR; i++) {
    if (parse_attribute(m, instance, i, value + i, msg, sizeof(msg))) {
      mju_warning("%s (actuator '%s')", msg, name);
      return NULL;
    }
  }

  Hydraulic* h = (Hydraulic*) malloc(sizeof(Hydraulic));
  if (!h) {
    mju_warning("%s: out of memory", SAMII_PLUGIN_NAME);
    return NULL;
  }
  h->actuator = actuator;
  h->actadr = m->actuator_actadr[actuator];
  h->qposadr = m->jnt_qposadr[joint];
  h->dofadr = m->jnt_dofadr[joint];
  memcpy(h->value, value, sizeof(value));
  mjtNum Ps = value[ATTR_SUPPLY_PRESSURE];
  h->c_p = 4 * value[ATTR_BULK_MODULUS] / (value[ATTR_TOTAL_VOLUME] * Ps);
  h->torque_per = value[ATTR_DISPLACEMENT] * Ps;
  h->leak = value[ATTR_LEAKAGE_COEFFICIENT] * Ps;
  return h;
}


// ------------------------------------------------------------------------------------------------
// dynamics

// servo amplifier output v [V]: command plus position loop, saturated at +-10 V
static mjtNum valve_voltage(const mjModel* m, const mjData* d, const Hydraulic* h) {
  int a = h->actuator;
  mjtNum u = d->ctrl[a];
  if (mju_isBad(u)) {
    u = 0;  // MuJoCo zeroes bad controls of native actuators (and warns); do the same
  }
  if (m->actuator_ctrllimited[a] && !mjDISABLED(mjDSBL_CLAMPCTRL)) {
    u = mju_clip(u, m->actuator_ctrlrange[2*a], m->actuator_ctrlrange[2*a+1]);
  }
  mjtNum theta = d->qpos[h->qposadr];
  mjtNum v = u + h->value[ATTR_POSITION_GAIN] * (h->value[ATTR_REFERENCE_ANGLE] - theta);
  return mju_clip(v, -SAMII_AMPLIFIER_LIMIT_V, SAMII_AMPLIFIER_LIMIT_V);
}

// orifice load flow Q [m^3/s] for spool x and pressure ratio p = P/Ps. The drop across the
// metering orifices is (Ps - sign(x) P)/Ps; when the motor pumps the load pressure past the
// supply (an inertial load braked through an open valve) it turns negative and the oil flows
// back to the supply through the open valve: the signed square-root law (Jelali & Kroll,
// "Hydraulic Servo-systems", Springer 2003, sec. 3.3), which bounds the load pressure near Ps.
static mjtNum load_flow(const Hydraulic* h, mjtNum x, mjtNum p) {
  x = mju_clip(x, -1, 1);
  mjtNum s = x > 0 ? 1 : (x < 0 ? -1 : 0);
  mjtNum drop = 1 - s*p;
  return h->value[ATTR_RATED_FLOW] * x * (drop >= 0 ? mju_sqrt(drop) : -mju_sqrt(-drop));
}

// actuator disabled through its group (opt.disableactuator)
static int disabled(const mjModel* m, const Hydraulic* h) {
  int group = m->actuator_group[h->actuator];
  return group >= 0 && group < 31 && (m->opt.disableactuator & (1 << group));
}

static void hydraulic_act_dot(const mjModel* m, mjData* d, int instance) {
  const Hydraulic* h = (const Hydraulic*) d->plugin_data[instance];
  const mjtNum* act = d->act + h->actadr;
  mjtNum* act_dot = d->act_dot + h->actadr;
  mjtNum x = act[0], p = act[1];

  // spool lag with travel limit: no motion further into the stop
  mjtNum v = valve_voltage(m, d, h);
  mjtNum x_dot = (v / h->value[ATTR_RATED_VOLTAGE] - x) / h->value[ATTR_VALVE_TIME_CONSTANT];
  if ((x >= 1 && x_dot > 0) || (x <= -1 && x_dot < 0)) {
    x_dot = 0;
  }

  // continuity in the two lines (Merritt): P_dot = 4 beta/Vt (Q - Dm theta_dot - Ctp P)
  mjtNum theta_dot = d->qvel[h->dofadr];
  mjtNum flow = load_flow(h, x, p) - h->value[ATTR_DISPLACEMENT] * theta_dot - h->leak * p;

  act_dot[0] = x_dot;
  act_dot[1] = h->c_p * flow;
}

static void hydraulic_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  const Hydraulic* h = (const Hydraulic*) d->plugin_data[instance];
  if (disabled(m, h)) {
    d->actuator_force[h->actuator] = 0;
    return;
  }
  d->actuator_force[h->actuator] = h->torque_per * d->act[h->actadr + 1];
}

// after MuJoCo's integration of act (explicit Euler), qvel and qpos (see the header comment)
static void hydraulic_advance(const mjModel* m, mjData* d, int instance) {
  const Hydraulic* h = (const Hydraulic*) d->plugin_data[instance];
  mjtNum* act = d->act + h->actadr;
  if (mjDISABLED(mjDSBL_ACTUATION)) {
    return;  // MuJoCo did not compute act_dot nor integrate act
  }

  if (m->opt.integrator != mjINT_RK4 && !disabled(m, h)) {
    // P_{n+1} used -Dm*qvel_n; replace it by -Dm*qvel_{n+1}. MuJoCo integrated
    // qvel_{n+1} = qvel_n + h*qacc_used, so qvel_n is recovered from the act_dot of this step:
    //   act_dot[1] = c_p*(Q_n - Dm*qvel_n - Ctp*P_n)  with Q_n, P_n from the pre-step act.
    mjtNum dt = m->opt.timestep;
    const mjtNum* act_dot = d->act_dot + h->actadr;
    mjtNum x_n = act[0] - dt * act_dot[0];
    mjtNum p_n = act[1] - dt * act_dot[1];
    mjtNum Dm = h->value[ATTR_DISPLACEMENT];
    mjtNum qvel_n = (load_flow(h, x_n, p_n) - h->leak * p_n - act_dot[1] / h->c_p) / Dm;
    act[1] -= dt * h->c_p * Dm * (d->qvel[h->dofadr] - qvel_n);

    // exact spool step: act_dot[0] = (target - x_n)/tau_v, or 0 against the stop
    if (act_dot[0] != 0) {
      mjtNum tau_v = h->value[ATTR_VALVE_TIME_CONSTANT];
      mjtNum target = x_n + tau_v * act_dot[0];
      act[0] = target + (x_n - target) * mju_exp(-dt / tau_v);
    }
  }

  // travel limit of the spool (explicit Euler may step past the stop)
  act[0] = mju_clip(act[0], -1, 1);
}


// ------------------------------------------------------------------------------------------------
// plugin callbacks

static int hydraulic_nstate(const mjModel* m, int instance) {
  return 0;  // all states are in mjData.act
}

static int hydraulic_init(const mjModel* m, mjData* d, int instance) {
  Hydraulic* h = hydraulic_create(m, instance);
  if (!h) {
    return -1;
  }
  d->plugin_data[instance] = (uintptr_t) h;
  return 0;
}

static void hydraulic_destroy(mjData* d, int instance) {
  free((void*) d->plugin_data[instance]);
  d->plugin_data[instance] = 0;
}

static void hydraulic_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data,
                            int instance) {
  // nothing: the states are in mjData.act, which mj_resetData zeroes (or a keyframe sets)
}

mjPLUGIN_LIB_INIT(samii_hydraulic) {
  // a library compiled against other headers must not register (struct layouts may differ)
  if (mj_version() != mjVERSION_HEADER) {
    mju_warning("%s: compiled against MuJoCo %d but running with %d; reinstall samii",
                SAMII_PLUGIN_NAME, mjVERSION_HEADER, mj_version());
    return;
  }
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = SAMII_PLUGIN_NAME;
  plugin.capabilityflags |= mjPLUGIN_ACTUATOR;
  plugin.nattribute = NATTR;
  plugin.attributes = kAttributes;
  plugin.nstate = hydraulic_nstate;
  plugin.init = hydraulic_init;
  plugin.destroy = hydraulic_destroy;
  plugin.reset = hydraulic_reset;
  plugin.compute = hydraulic_compute;
  plugin.advance = hydraulic_advance;
  plugin.actuator_act_dot = hydraulic_act_dot;
  // copy: not needed; plugin_data holds only what init derives from the model, and mj_copyData
  // keeps the destination's own plugin_data.
  mjp_registerPlugin(&plugin);
}
