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
// Controller card (optional; samii/closedloop/card.py writes its config). The rig's digital
// controller, run inside the step so that a closed loop costs what mj_step costs:
//   - every `controller_steps` physics steps it samples w = (theta_r, theta, accel) at t_n from
//     sensordata (valid in `advance`: mj_forward computed the sensors of t_n; accel does not depend
//     on the valve command of the step, which only moves the spool), adds the ctrl of two force-free
//     noise actuators and quantises to the ADC steps;
//   - theta and accel reach it through the sensors' own dynamics when configured
//     (`controller_theta_filter`, `controller_accel_filter`: FIR taps at the physics rate, a delay;
//     `controller_theta_sos`, `controller_accel_sos`: second-order sections after the FIR, a
//     roll-off, an anti-alias filter, an AC coupling; samii.closedloop.card computes them as
//     samii.sim.sensor_dynamics does for a measurement, with the card's own anti-alias filter).
//     They run every physics step, card on or off, from rest after a reset (theta's rest reading
//     `controller_theta_rest`, accel's 0); the servo amplifier still reads the joint directly;
//   - it computes c = C z + D w and z <- A z + B w (SI inputs; the caller folds unit scales in);
//   - the command is held (ZOH) and reaches the valve `controller_delay_steps` later through a ring
//     of held commands; a fractional delay splits the step: the spool is integrated exactly for the
//     older command over the first fraction, then for the newer one;
//   - the valve sees clamp(u + c [+ Kp (theta_0 + theta_r - theta)], +-10 V): the position loop is
//     kept (`controller_replaces_servo` 0) or dropped while the card runs (1).
// theta_r, the reference offset, is the ctrl of the actuator named by `reference_actuator` and also
// feeds the position loop. The card's state lives in mjData.plugin_state (part of
// mjSTATE_FULLPHYSICS, so rollouts carry it): [enabled, step counter, valve voltage of the last step,
// held command, ring (delay_whole + 2, newest first), z, and with sensor filters their block:
// steps since the reset, the rings of theta's and accel's deviations from rest, two states per
// section]. `enabled` is 1 after a reset; the caller
// sets it (0: the servo amplifier alone, the ring recording its command) to switch the card on
// mid-run. The card needs the Euler or implicit integrators (RK4 does not call `advance` per step).
//
// The valve (optional attributes, all absent or 0 by default: an ideal valve, the model as it was
// before these options existed). Between the amplifier and the spool:
//   command_delay    T [s]: the spool follows the amplifier output T late (transport or
//                    computation delay on the valve command); whole physics steps through a ring
//                    of held outputs, a fraction by splitting the step (the held signal shifted
//                    exactly by T, as the card's delay); the recorded v is the amplifier output;
//   valve_dead_band  d [V]: the valve's input is v - d sign(v) outside |v| <= d, 0 inside (spool
//                    overlap referred to the command);
//   valve_saturation s [V]: then limited to +-s (a drive current limit);
//   valve_asymmetry  a [1]: then a negative input passes with gain 1 - a (-1 <= a < 1: the two
//                    directions' flow gains differ, unequal ports or piston areas, a worn edge).
// The ring lives in mjData.plugin_state after the card's state: [primed, amplifier output at the
// latest act_dot, (a, b) per step, newest first]. A command delay needs Euler or implicit.
// Linearisations (samii.sim.linearize) take the plant without the delay and the valve's law and
// apply the delay as exp(-s T) to the responses to v.
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

// Optional attributes (empty = absent): the reference input and the digital controller card.
// Keep in sync with samii/sim/hydraulic_reference.py (OPTIONAL_ATTRIBUTES).
enum {
  OPT_REFERENCE_ACTUATOR = NATTR,  // name of an actuator whose ctrl is the servo loop's reference
                                   // offset theta_r [rad] (added to reference_angle)
  OPT_CONTROLLER_STATES,           // n, states of the discrete controller (0...CTRL_MAX_STATES)
  OPT_CONTROLLER_A,                // n*n numbers, row-major
  OPT_CONTROLLER_B,                // n*3 numbers, row-major; inputs (theta_r, theta, accel), SI
  OPT_CONTROLLER_C,                // n numbers
  OPT_CONTROLLER_D,                // 3 numbers
  OPT_CONTROLLER_STEPS,            // sample period in physics steps (integer >= 1)
  OPT_CONTROLLER_DELAY,            // computation delay in physics steps (0...CTRL_MAX_DELAY_STEPS, any real)
  OPT_CONTROLLER_REPLACES_SERVO,   // 1: while enabled the controller replaces Kp*(...); 0: adds to it
  OPT_CONTROLLER_THETA_SENSOR,     // name of the jointpos sensor of the actuator's joint
  OPT_CONTROLLER_ACCEL_SENSOR,     // name of the 3-axis accelerometer
  OPT_CONTROLLER_ACCEL_DIRECTION,  // 3 numbers: accel = direction . sensor - offset
  OPT_CONTROLLER_ACCEL_OFFSET,     // [m/s^2]
  OPT_CONTROLLER_THETA_NOISE,      // name of an actuator whose ctrl is added to the sampled theta [rad]
  OPT_CONTROLLER_ACCEL_NOISE,      // ... to the sampled accel [m/s^2]
  OPT_CONTROLLER_THETA_LSB,        // ADC step of theta [rad], 0 = no quantisation
  OPT_CONTROLLER_ACCEL_LSB,        // ADC step of accel [m/s^2], 0 = no quantisation
  OPT_COMMAND_DELAY,               // [s] the valve acts on the amplifier output this late (0...1 s)
  OPT_VALVE_DEAD_BAND,             // [V] dead band of the valve on its input (0 = none, < 10)
  OPT_VALVE_SATURATION,            // [V] the valve's input is limited to +-this (0 = none, <= 10)
  OPT_VALVE_ASYMMETRY,             // [1] a negative input passes with gain 1 - this (0 = none, -1...<1)
  OPT_CONTROLLER_THETA_FILTER,     // FIR taps on the card's theta at the physics rate (the angle
                                   // sensor's delay), newest sample first; absent = 1
  OPT_CONTROLLER_THETA_SOS,        // second-order sections after it, 6 numbers each (b0 b1 b2 a0 a1 a2)
  OPT_CONTROLLER_THETA_REST,       // [rad] the card's theta at rest (the home keyframe): the theta
                                   // filter works on the deviation from it
  OPT_CONTROLLER_ACCEL_FILTER,     // FIR taps on the card's accel (the accelerometer's delay, and its
                                   // gain when there are no sections); absent = 1
  OPT_CONTROLLER_ACCEL_SOS,        // second-order sections after it, 6 numbers each
  NATTR_ALL
};

static const char* const kAttributes[NATTR_ALL] = {
  "supply_pressure", "bulk_modulus", "total_volume", "displacement", "leakage_coefficient",
  "valve_time_constant", "rated_flow", "rated_voltage", "position_gain", "reference_angle",
  "reference_actuator", "controller_states", "controller_a", "controller_b", "controller_c",
  "controller_d", "controller_steps", "controller_delay_steps", "controller_replaces_servo",
  "controller_theta_sensor", "controller_accel_sensor", "controller_accel_direction",
  "controller_accel_offset", "controller_theta_noise", "controller_accel_noise",
  "controller_theta_lsb", "controller_accel_lsb", "command_delay", "valve_dead_band",
  "valve_saturation", "valve_asymmetry", "controller_theta_filter", "controller_theta_sos",
  "controller_theta_rest", "controller_accel_filter", "controller_accel_sos",
};

#define CTRL_NIN 3                 // controller inputs: theta_r [rad], theta [rad], accel [m/s^2]
#define CTRL_MAX_STATES 64
#define CTRL_MAX_DELAY_STEPS 200
#define CMD_MAX_DELAY_S 1.0        // longest command delay [s]
#define SENSOR_MAX_TAPS 1000004    // longest sensor FIR (a 1 s delay at 1 us, with its 4 fraction taps)
#define SENSOR_MAX_SECTIONS 8      // most second-order sections on each of the card's inputs

// Plugin state of an instance with a controller (mjData.plugin_state, part of
// mjSTATE_FULLPHYSICS, so rollouts carry it): see the header comment.
enum {
  ST_ENABLED = 0,  // 1: the controller runs; 0: the servo amplifier alone (set from outside)
  ST_COUNTER,      // physics steps since the controller was enabled (sample when % steps == 0)
  ST_VALVE,        // valve voltage applied at the end of the last step [V]
  ST_COMMAND,      // the controller's latest command (held, zero-order) [V]
  ST_BUFFER        // ring of held commands, newest first (delay_whole + 2), then the n states
};

// The sensors' block after the controller's states (only when a sensor filter is configured):
// the physics steps since the reset, then the rings of theta's and accel's deviations from rest
// (entry k % size holds step k), then the sections' states, theta's then accel's (two each, direct
// form II transposed, as scipy's sosfilt). All zero: the sensors at rest since long before.
enum { SN_COUNT = 0, SN_RINGS };

// One sensor's filter: an FIR, then second-order sections, on the deviation from its rest reading
// (the output is the filtered deviation plus the filter's DC gain times the rest reading).
typedef struct {
  int ntaps, nsos;
  mjtNum* taps;                 // ntaps
  mjtNum* sos;                  // 6 nsos, each normalised to a0 = 1
  mjtNum rest;                  // the reading at rest
  mjtNum gain_dc;               // the filter's gain at 0 Hz
} SensorPath;

enum { PATH_THETA = 0, PATH_ACCEL, NPATH };
static const int kPathTaps[NPATH] = {OPT_CONTROLLER_THETA_FILTER, OPT_CONTROLLER_ACCEL_FILTER};
static const int kPathSos[NPATH] = {OPT_CONTROLLER_THETA_SOS, OPT_CONTROLLER_ACCEL_SOS};

typedef struct {
  int n;                        // states
  mjtNum* A;                    // n x n
  mjtNum* B;                    // n x 3
  mjtNum* C;                    // n
  mjtNum D[CTRL_NIN];
  int steps;                    // sample period [physics steps]
  int delay_whole;              // delay = delay_whole + delay_frac [physics steps]
  mjtNum delay_frac;
  int replaces;
  int theta_adr, accel_adr;     // sensordata addresses
  mjtNum direction[3], accel_offset;
  int theta_noise, accel_noise; // actuator ids or -1
  mjtNum theta_lsb, accel_lsb;
  int nbuf;                     // delay_whole + 2
  mjtNum* z_scratch;            // n
  // the sensors' dynamics before sampling (samii.sim.sensor_dynamics; all absent: ideal sensors)
  int sensors;                  // 1: the sensors' block is in plugin_state after z
  SensorPath path[NPATH];       // theta's, accel's
} Card;

// rule for each attribute: 1 = must be > 0, 0 = must be >= 0, -1 = any finite value
static const int kRule[NATTR] = {1, 1, 1, 1, 0, 1, 1, 1, 0, -1};

typedef struct {
  const mjModel* model;  // the model this was parsed from (see for_model)
  int broken;            // another model's configuration could not be taken: forces are NaN

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

  int reference;      // actuator id of the reference input theta_r, or -1
  Card* card;         // the digital controller, or NULL

  // the valve between the amplifier and the spool (all 0: an ideal valve, as before these options)
  mjtNum dead_band;   // [V], 0 = none
  mjtNum saturation;  // [V], 0 = none
  mjtNum asymmetry;   // [1], 0 = none: a negative input's gain is 1 - asymmetry
  int delay_whole;    // command delay = (delay_whole + delay_frac) physics steps
  mjtNum delay_frac;
  int nring;          // entries of the command ring (delay_whole + 2), 0 = no delay
  int ring_adr;       // offset of the command ring's block in the instance's plugin_state
} Hydraulic;

// Command-ring block of plugin_state (after the card's): a flag set once the ring holds history,
// the amplifier output at the latest act_dot (t_n, before integration moved qpos), then per
// physics step, newest first, the amplifier output over the step in two pieces (a over [0, s),
// b over [s, 1) of the step, s = the card's fractional delay, 0 without a card).
enum { VR_PRIMED = 0, VR_VNOW, VR_RING };


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



// Optional attribute text, or NULL when absent or empty.
static const char* optional_text(const mjModel* m, int instance, int i) {
  const char* text = mj_getPluginConfig(m, instance, kAttributes[i]);
  return (text && text[0]) ? text : NULL;
}

// Parse exactly `count` finite numbers from an optional attribute; -1 with a message if wrong.
static int parse_numbers(const mjModel* m, int instance, int i, mjtNum* out, int count,
                         const char* name) {
  const char* text = optional_text(m, instance, i);
  if (!text) {
    mju_warning("%s (actuator '%s'): config attribute '%s' is required with a controller "
                "(%d numbers)", SAMII_PLUGIN_NAME, name, kAttributes[i], count);
    return -1;
  }
  const char* p = text;
  for (int k = 0; k < count; k++) {
    char* end = NULL;
    double value = strtod(p, &end);
    if (end == p || !isfinite(value)) {
      mju_warning("%s (actuator '%s'): config attribute '%s' has %d valid numbers "
                  "(expected %d finite numbers)", SAMII_PLUGIN_NAME, name, kAttributes[i], k, count);
      return -1;
    }
    out[k] = value;
    p = end;
  }
  while (*p == ' ' || *p == '\t' || *p == '\n' || *p == '\r') p++;
  if (*p) {
    mju_warning("%s (actuator '%s'): config attribute '%s' has more than %d numbers or text "
                "after them", SAMII_PLUGIN_NAME, name, kAttributes[i], count);
    return -1;
  }
  return 0;
}

// One optional number in [lo, hi] (default when absent); -1 with a message if wrong.
static int parse_optional(const mjModel* m, int instance, int i, mjtNum lo, mjtNum hi,
                          mjtNum fallback, mjtNum* out, const char* name) {
  if (!optional_text(m, instance, i)) {
    *out = fallback;
    return 0;
  }
  if (parse_numbers(m, instance, i, out, 1, name)) return -1;
  if (!(*out >= lo && *out <= hi)) {
    mju_warning("%s (actuator '%s'): config attribute '%s' = %g is out of range "
                "(expected %g...%g)", SAMII_PLUGIN_NAME, name, kAttributes[i], *out, lo, hi);
    return -1;
  }
  return 0;
}

// Id of the object named by an optional attribute (-1 when absent), -2 with a message if unknown.
static int named_id(const mjModel* m, int instance, int i, int type, const char* what,
                    const char* name) {
  const char* text = optional_text(m, instance, i);
  if (!text) return -1;
  int id = mj_name2id(m, type, text);
  if (id < 0) {
    mju_warning("%s (actuator '%s'): config attribute '%s' = '%s' names no %s",
                SAMII_PLUGIN_NAME, name, kAttributes[i], text, what);
    return -2;
  }
  return id;
}

static void card_free(Card* c) {
  if (c) {
    free(c->A);
    free(c->B);
    free(c->C);
    free(c->z_scratch);
    for (int i = 0; i < NPATH; i++) {
      free(c->path[i].taps);
      free(c->path[i].sos);
    }
    free(c);
  }
}

// How many numbers an optional attribute holds (0 when absent; counted as parse_numbers reads them).
static int count_numbers(const mjModel* m, int instance, int i) {
  const char* p = optional_text(m, instance, i);
  int count = 0;
  while (p) {
    char* end = NULL;
    strtod(p, &end);
    if (end == p) break;
    count++;
    p = end;
  }
  return count;
}

// Sizes of the sensors' filters a config asks for (used by nstate before init): FIR taps and
// sections per path; returns the block's plugin_state entries, 0 when no filter is configured.
static int sensor_size(const mjModel* m, int instance, int ntaps[NPATH], int nsos[NPATH]) {
  int any = 0, size = SN_RINGS;
  for (int i = 0; i < NPATH; i++) {
    int taps = count_numbers(m, instance, kPathTaps[i]);
    int sos = count_numbers(m, instance, kPathSos[i]) / 6;
    ntaps[i] = taps > 0 && taps <= SENSOR_MAX_TAPS ? taps : 1;  // (init reports a bad count)
    nsos[i] = sos <= SENSOR_MAX_SECTIONS ? sos : 0;
    any |= optional_text(m, instance, kPathTaps[i]) || optional_text(m, instance, kPathSos[i]);
    size += ntaps[i] + 2 * nsos[i];
  }
  return any ? size : 0;
}

// The states and delay a config asks for (used by nstate before init); 0 = no controller.
static int card_size(const mjModel* m, int instance, int* n, int* nbuf) {
  const char* text = optional_text(m, instance, OPT_CONTROLLER_STATES);
  *n = 0;
  *nbuf = 0;
  if (!text) return 0;
  double states = strtod(text, NULL);  // parsed as card_create parses it (which reports a bad value)
  *n = (states >= 0 && states <= CTRL_MAX_STATES && states == floor(states)) ? (int) states : 0;
  const char* delay = optional_text(m, instance, OPT_CONTROLLER_DELAY);
  double dl = delay ? strtod(delay, NULL) : 0;
  if (!(dl >= 0 && dl <= CTRL_MAX_DELAY_STEPS)) dl = 0;  // init reports it
  *nbuf = (int) floor(dl) + 2;
  return 1;
}

// plugin_state entries of the card (0 without one)
static int card_nstate(const mjModel* m, int instance) {
  int n, nbuf;
  if (!card_size(m, instance, &n, &nbuf)) return 0;
  if (n < 0 || n > CTRL_MAX_STATES) n = 0;  // init reports it
  int ntaps[NPATH], nsos[NPATH];
  return ST_BUFFER + nbuf + n + sensor_size(m, instance, ntaps, nsos);
}

// The command delay a config asks for, in physics steps (whole + fraction); returns the ring's
// entries (0 = no delay; an invalid value also gives 0 here, and init reports it).
static int delay_size(const mjModel* m, int instance, int* whole, mjtNum* frac) {
  const char* text = optional_text(m, instance, OPT_COMMAND_DELAY);
  *whole = 0;
  *frac = 0;
  double dl = text ? strtod(text, NULL) : 0;
  if (!(dl > 0 && dl <= CMD_MAX_DELAY_S) || !(m->opt.timestep > 0)) return 0;
  double steps = dl / m->opt.timestep;
  double nearest = floor(steps + 0.5);
  if (fabs(steps - nearest) < 1e-9 * (1 + steps)) steps = nearest;  // 4 ms / 1 ms is 4 steps
  *whole = (int) floor(steps);
  *frac = steps - *whole;
  return *whole + 2;
}

// FIR taps of a sensor filter (attribute i): absent = the single tap 1; -1 with a message if wrong.
static int parse_taps(const mjModel* m, int instance, int i, int count, mjtNum** out,
                      const char* name) {
  int given = count_numbers(m, instance, i);
  if (optional_text(m, instance, i) && (given < 1 || given > SENSOR_MAX_TAPS)) {
    mju_warning("%s (actuator '%s'): config attribute '%s' must hold 1...%d FIR taps (got %d)",
                SAMII_PLUGIN_NAME, name, kAttributes[i], SENSOR_MAX_TAPS, given);
    return -1;
  }
  *out = (mjtNum*) calloc(count, sizeof(mjtNum));
  if (!*out) {
    mju_warning("%s: out of memory", SAMII_PLUGIN_NAME);
    return -1;
  }
  if (!optional_text(m, instance, i)) {
    (*out)[0] = 1;
    return 0;
  }
  return parse_numbers(m, instance, i, *out, count, name);
}

// The sections of a sensor path (attribute i), normalised to a0 = 1; -1 with a message if wrong.
static int parse_sections(const mjModel* m, int instance, int i, SensorPath* p, const char* name) {
  int numbers = count_numbers(m, instance, i);
  if (optional_text(m, instance, i) &&
      (numbers < 6 || numbers % 6 || numbers > 6 * SENSOR_MAX_SECTIONS)) {
    mju_warning("%s (actuator '%s'): config attribute '%s' must hold 6 numbers per section, "
                "1...%d sections (got %d numbers)", SAMII_PLUGIN_NAME, name, kAttributes[i],
                SENSOR_MAX_SECTIONS, numbers);
    return -1;
  }
  p->sos = (mjtNum*) calloc(6 * p->nsos + 1, sizeof(mjtNum));
  if (!p->sos) {
    mju_warning("%s: out of memory", SAMII_PLUGIN_NAME);
    return -1;
  }
  if (p->nsos && parse_numbers(m, instance, i, p->sos, 6 * p->nsos, name)) return -1;
  for (int k = 0; k < p->nsos; k++) {
    mjtNum* q = p->sos + 6*k;
    if (q[3] == 0) {
      mju_warning("%s (actuator '%s'): section %d of '%s' has a0 = 0", SAMII_PLUGIN_NAME, name, k,
                  kAttributes[i]);
      return -1;
    }
    mjtNum a0 = q[3];
    for (int j = 0; j < 6; j++) q[j] /= a0;
  }
  return 0;
}

// The sensors' filters of the card (none configured: ideal sensors); -1 with a message if wrong.
static int sensors_create(const mjModel* m, int instance, Card* c, const char* name) {
  int ntaps[NPATH], nsos[NPATH];
  c->sensors = sensor_size(m, instance, ntaps, nsos) > 0;
  if (!c->sensors) {
    if (optional_text(m, instance, OPT_CONTROLLER_THETA_REST)) {
      mju_warning("%s (actuator '%s'): config attribute 'controller_theta_rest' given without a "
                  "sensor filter", SAMII_PLUGIN_NAME, name);
      return -1;
    }
    return 0;
  }
  for (int i = 0; i < NPATH; i++) {
    SensorPath* p = &c->path[i];
    p->ntaps = ntaps[i];
    p->nsos = nsos[i];
    if (parse_taps(m, instance, kPathTaps[i], p->ntaps, &p->taps, name) ||
        parse_sections(m, instance, kPathSos[i], p, name)) {
      return -1;
    }
    p->gain_dc = 0;
    for (int k = 0; k < p->ntaps; k++) p->gain_dc += p->taps[k];
    for (int k = 0; k < p->nsos; k++) {
      const mjtNum* q = p->sos + 6*k;
      mjtNum den = q[3] + q[4] + q[5];
      p->gain_dc *= den != 0 ? (q[0] + q[1] + q[2]) / den : 0;  // (a pole at z = 1: no rest level)
    }
  }
  // the accelerometer reads 0 at rest (its rest reading is the card's offset)
  return parse_optional(m, instance, OPT_CONTROLLER_THETA_REST, -1e3, 1e3, 0,
                        &c->path[PATH_THETA].rest, name);
}

// Build the controller card from the config; NULL (card_ok = 1) when none is configured,
// NULL with card_ok = 0 (after mju_warning) when the config is wrong.
static Card* card_create(const mjModel* m, int instance, int actuator, const char* name,
                         int* card_ok) {
  *card_ok = 0;
  if (!optional_text(m, instance, OPT_CONTROLLER_STATES)) {
    static const int kCardOnly[] = {
      OPT_CONTROLLER_A, OPT_CONTROLLER_B, OPT_CONTROLLER_C, OPT_CONTROLLER_D, OPT_CONTROLLER_STEPS,
      OPT_CONTROLLER_DELAY, OPT_CONTROLLER_REPLACES_SERVO, OPT_CONTROLLER_THETA_SENSOR,
      OPT_CONTROLLER_ACCEL_SENSOR, OPT_CONTROLLER_ACCEL_DIRECTION, OPT_CONTROLLER_ACCEL_OFFSET,
      OPT_CONTROLLER_THETA_NOISE, OPT_CONTROLLER_ACCEL_NOISE, OPT_CONTROLLER_THETA_LSB,
      OPT_CONTROLLER_ACCEL_LSB, OPT_CONTROLLER_THETA_FILTER, OPT_CONTROLLER_ACCEL_FILTER,
      OPT_CONTROLLER_ACCEL_SOS, OPT_CONTROLLER_THETA_REST, OPT_CONTROLLER_THETA_SOS,
    };
    for (size_t j = 0; j < sizeof(kCardOnly) / sizeof(kCardOnly[0]); j++) {
      int i = kCardOnly[j];
      if (optional_text(m, instance, i)) {
        mju_warning("%s (actuator '%s'): config attribute '%s' given without controller_states",
                    SAMII_PLUGIN_NAME, name, kAttributes[i]);
        return NULL;
      }
    }
    *card_ok = 1;
    return NULL;
  }
  if (m->opt.integrator == mjINT_RK4) {
    mju_warning("%s (actuator '%s'): the controller card needs the Euler or implicit "
                "integrators (it runs in the advance callback), not RK4", SAMII_PLUGIN_NAME, name);
    return NULL;
  }
  mjtNum value;
  if (parse_optional(m, instance, OPT_CONTROLLER_STATES, 0, CTRL_MAX_STATES, 0, &value, name)) {
    return NULL;
  }
  if (value != floor(value)) {
    mju_warning("%s (actuator '%s'): controller_states = %g is not an integer",
                SAMII_PLUGIN_NAME, name, value);
    return NULL;
  }
  Card* c = (Card*) calloc(1, sizeof(Card));
  if (!c) {
    mju_warning("%s: out of memory", SAMII_PLUGIN_NAME);
    return NULL;
  }
  int n = c->n = (int) value;
  c->A = (mjtNum*) calloc(n * n + 1, sizeof(mjtNum));
  c->B = (mjtNum*) calloc(n * CTRL_NIN + 1, sizeof(mjtNum));
  c->C = (mjtNum*) calloc(n + 1, sizeof(mjtNum));
  c->z_scratch = (mjtNum*) calloc(n + 1, sizeof(mjtNum));
  if (!c->A || !c->B || !c->C || !c->z_scratch) {
    mju_warning("%s: out of memory", SAMII_PLUGIN_NAME);
    card_free(c);
    return NULL;
  }
  mjtNum steps, delay, replaces;
  if ((n && parse_numbers(m, instance, OPT_CONTROLLER_A, c->A, n * n, name)) ||
      (n && parse_numbers(m, instance, OPT_CONTROLLER_B, c->B, n * CTRL_NIN, name)) ||
      (n && parse_numbers(m, instance, OPT_CONTROLLER_C, c->C, n, name)) ||
      parse_numbers(m, instance, OPT_CONTROLLER_D, c->D, CTRL_NIN, name) ||
      parse_optional(m, instance, OPT_CONTROLLER_STEPS, 1, 1e6, 1, &steps, name) ||
      parse_optional(m, instance, OPT_CONTROLLER_DELAY, 0, CTRL_MAX_DELAY_STEPS, 0, &delay, name) ||
      parse_optional(m, instance, OPT_CONTROLLER_REPLACES_SERVO, 0, 1, 0, &replaces, name) ||
      parse_optional(m, instance, OPT_CONTROLLER_ACCEL_OFFSET, -1e6, 1e6, 0, &c->accel_offset, name) ||
      parse_optional(m, instance, OPT_CONTROLLER_THETA_LSB, 0, 1, 0, &c->theta_lsb, name) ||
      parse_optional(m, instance, OPT_CONTROLLER_ACCEL_LSB, 0, 1e3, 0, &c->accel_lsb, name)) {
    card_free(c);
    return NULL;
  }
  if (!n) {
    for (int i = OPT_CONTROLLER_A; i <= OPT_CONTROLLER_C; i++) {
      if (optional_text(m, instance, i)) {
        mju_warning("%s (actuator '%s'): config attribute '%s' given for a controller without "
                    "states", SAMII_PLUGIN_NAME, name, kAttributes[i]);
        card_free(c);
        return NULL;
      }
    }
  }
  if (steps != floor(steps) || replaces != floor(replaces)) {
    mju_warning("%s (actuator '%s'): controller_steps and controller_replaces_servo must be "
                "integers (got %g, %g)", SAMII_PLUGIN_NAME, name, steps, replaces);
    card_free(c);
    return NULL;
  }
  c->steps = (int) steps;
  c->delay_whole = (int) floor(delay);
  c->delay_frac = delay - c->delay_whole;
  c->replaces = (int) replaces;
  c->nbuf = c->delay_whole + 2;

  // measurements: the joint's angle sensor and the accelerometer, by name
  int theta = named_id(m, instance, OPT_CONTROLLER_THETA_SENSOR, mjOBJ_SENSOR, "sensor", name);
  int accel = named_id(m, instance, OPT_CONTROLLER_ACCEL_SENSOR, mjOBJ_SENSOR, "sensor", name);
  if (theta == -1 || accel == -1) {
    mju_warning("%s (actuator '%s'): a controller needs controller_theta_sensor and "
                "controller_accel_sensor", SAMII_PLUGIN_NAME, name);
    card_free(c);
    return NULL;
  }
  if (theta < 0 || accel < 0) {
    card_free(c);
    return NULL;
  }
  int joint = m->actuator_trnid[2*actuator];
  if (m->sensor_type[theta] != mjSENS_JOINTPOS || m->sensor_objid[theta] != joint ||
      (m->sensor_type[accel] != mjSENS_ACCELEROMETER && m->sensor_type[accel] != mjSENS_FRAMELINACC) ||
      m->sensor_dim[accel] != 3) {
    mju_warning("%s (actuator '%s'): controller_theta_sensor must be a jointpos sensor of the "
                "actuator's joint and controller_accel_sensor an accelerometer or framelinacc",
                SAMII_PLUGIN_NAME, name);
    card_free(c);
    return NULL;
  }
  c->theta_adr = m->sensor_adr[theta];
  c->accel_adr = m->sensor_adr[accel];
  if (parse_numbers(m, instance, OPT_CONTROLLER_ACCEL_DIRECTION, c->direction, 3, name)) {
    card_free(c);
    return NULL;
  }
  c->theta_noise = named_id(m, instance, OPT_CONTROLLER_THETA_NOISE, mjOBJ_ACTUATOR, "actuator", name);
  c->accel_noise = named_id(m, instance, OPT_CONTROLLER_ACCEL_NOISE, mjOBJ_ACTUATOR, "actuator", name);
  if (c->theta_noise < -1 || c->accel_noise < -1 || sensors_create(m, instance, c, name)) {
    card_free(c);
    return NULL;
  }
  *card_ok = 1;
  return c;
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

  Hydraulic* h = (Hydraulic*) calloc(1, sizeof(Hydraulic));
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

  h->reference = named_id(m, instance, OPT_REFERENCE_ACTUATOR, mjOBJ_ACTUATOR, "actuator", name);
  if (h->reference < -1) {
    free(h);
    return NULL;
  }
  int card_ok;
  h->card = card_create(m, instance, actuator, name, &card_ok);
  if (!card_ok) {
    free(h);
    return NULL;
  }

  // the valve: dead band, saturation, command delay
  mjtNum delay;
  if (parse_optional(m, instance, OPT_VALVE_DEAD_BAND, 0, SAMII_AMPLIFIER_LIMIT_V, 0, &h->dead_band, name) ||
      parse_optional(m, instance, OPT_VALVE_SATURATION, 0, SAMII_AMPLIFIER_LIMIT_V, 0, &h->saturation, name) ||
      parse_optional(m, instance, OPT_VALVE_ASYMMETRY, -1, 1, 0, &h->asymmetry, name) ||
      parse_optional(m, instance, OPT_COMMAND_DELAY, 0, CMD_MAX_DELAY_S, 0, &delay, name)) {
    card_free(h->card);
    free(h);
    return NULL;
  }
  if (h->asymmetry >= 1) {
    mju_warning("%s (actuator '%s'): valve_asymmetry = %g passes nothing in the negative direction "
                "(expected -1 <= asymmetry < 1)", SAMII_PLUGIN_NAME, name, h->asymmetry);
    card_free(h->card);
    free(h);
    return NULL;
  }
  if (h->dead_band >= SAMII_AMPLIFIER_LIMIT_V) {
    mju_warning("%s (actuator '%s'): valve_dead_band = %g V leaves no command through (expected "
                "0 <= dead band < %g V)", SAMII_PLUGIN_NAME, name, h->dead_band, SAMII_AMPLIFIER_LIMIT_V);
    card_free(h->card);
    free(h);
    return NULL;
  }
  h->nring = delay_size(m, instance, &h->delay_whole, &h->delay_frac);
  h->ring_adr = card_nstate(m, instance);
  // plugin_state was sized when the model was compiled; a timestep shortened since (the ring's
  // length in steps depends on it) would make the ring read and write past it. More than needed is
  // harmless (samii.sim.plugin.ideal_valve_model zeroes the delay of a copy and keeps the size).
  int nstate = h->ring_adr + (h->nring ? VR_RING + 2*h->nring : 0);
  if (nstate > m->plugin_statenum[instance]) {
    mju_warning("%s (actuator '%s'): the plugin state has %d entries but its configuration at "
                "timestep %g s needs %d: the timestep was shortened after compiling (command_delay "
                "is counted in physics steps); recompile the model", SAMII_PLUGIN_NAME, name,
                m->plugin_statenum[instance], m->opt.timestep, nstate);
    card_free(h->card);
    free(h);
    return NULL;
  }
  if (h->nring && m->opt.integrator == mjINT_RK4) {
    mju_warning("%s (actuator '%s'): command_delay needs the Euler or implicit integrators (the "
                "delay line runs in the advance callback), not RK4", SAMII_PLUGIN_NAME, name);
    card_free(h->card);
    free(h);
    return NULL;
  }
  h->model = m;
  return h;
}

static void hydraulic_free(Hydraulic* h) {
  if (h) card_free(h->card);
  free(h);
}

// The instance's configuration for model m. An mjData is parsed once, in init, for the model it
// was made with; mujoco.rollout with a list of models (and mujoco.batch) steps one mjData with
// several models, which differ in their valve and oil parameters. So when the model stepping this
// data is not the one its configuration came from, the configuration is parsed again from m
// (once per switch: a rollout runs each model's steps in a row; the same model costs a pointer
// comparison). Models batched together share the state's size, the plugin's included (rollout
// checks), so the command ring and the card fit. Should m's configuration be refused (it cannot,
// for a model that compiled), the forces turn NaN, which MuJoCo reports as an unstable
// simulation, rather than going on with another model's parameters.
static const Hydraulic* for_model(const mjModel* m, mjData* d, int instance) {
  Hydraulic* h = (Hydraulic*) d->plugin_data[instance];
  if (h && h->model == m) {
    return h;
  }
  Hydraulic* fresh = hydraulic_create(m, instance);
  if (!fresh) {
    mju_warning("%s: plugin instance %d: the model stepping this data has a configuration that "
                "cannot be used (above); its forces are NaN", SAMII_PLUGIN_NAME, instance);
    if (h) {
      h->model = m;
      h->broken = 1;
    }
    return h;
  }
  hydraulic_free(h);
  d->plugin_data[instance] = (uintptr_t) fresh;
  return fresh;
}


// ------------------------------------------------------------------------------------------------
// dynamics

// the servo loop's reference angle [rad]: reference_angle plus the reference input, if any
static mjtNum reference(const mjData* d, const Hydraulic* h) {
  mjtNum r = h->reference >= 0 ? d->ctrl[h->reference] : 0;
  return h->value[ATTR_REFERENCE_ANGLE] + (mju_isBad(r) ? 0 : r);
}

// the excitation u [V]: ctrl, zeroed if bad, clamped to ctrlrange
static mjtNum excitation(const mjModel* m, const mjData* d, const Hydraulic* h) {
  int a = h->actuator;
  mjtNum u = d->ctrl[a];
  if (mju_isBad(u)) {
    u = 0;  // MuJoCo zeroes bad controls of native actuators (and warns); do the same
  }
  if (m->actuator_ctrllimited[a] && !mjDISABLED(mjDSBL_CLAMPCTRL)) {
    u = mju_clip(u, m->actuator_ctrlrange[2*a], m->actuator_ctrlrange[2*a+1]);
  }
  return u;
}

// servo amplifier output v [V]: command plus position loop, saturated at +-10 V
static mjtNum valve_voltage(const mjModel* m, const mjData* d, const Hydraulic* h) {
  mjtNum theta = d->qpos[h->qposadr];
  mjtNum v = excitation(m, d, h) + h->value[ATTR_POSITION_GAIN] * (reference(d, h) - theta);
  return mju_clip(v, -SAMII_AMPLIFIER_LIMIT_V, SAMII_AMPLIFIER_LIMIT_V);
}

// the valve's own law on its input [V]: dead band (slope 1 outside it), then saturation, then the
// negative direction's gain
static mjtNum valve_law(const Hydraulic* h, mjtNum v) {
  mjtNum d = h->dead_band;
  if (d > 0) v = v > d ? v - d : (v < -d ? v + d : 0);
  if (h->saturation > 0) v = mju_clip(v, -h->saturation, h->saturation);
  if (v < 0) v *= 1 - h->asymmetry;
  return v;
}

// the command ring block of this instance (only with a command delay)
static mjtNum* command_ring(const mjModel* m, mjData* d, int instance, const Hydraulic* h) {
  return d->plugin_state + m->plugin_stateadr[instance] + h->ring_adr;
}

// amplifier output stored for ring entry e at fraction `at` of its step
static mjtNum ring_piece(const mjtNum* e, mjtNum at, mjtNum split) {
  return at < split ? e[0] : e[1];
}

// the voltage the valve acts on at t_n (before its law): the amplifier output now, or
// command_delay earlier from the ring (which holds steps n-1, n-2, ... until advance adds step n)
static mjtNum delayed_voltage(const mjModel* m, mjData* d, int instance, const Hydraulic* h) {
  mjtNum v = valve_voltage(m, d, h);
  if (!h->nring) return v;
  mjtNum* r = command_ring(m, d, instance, h);
  r[VR_VNOW] = v;
  if (r[VR_PRIMED] == 0) return v;  // no history yet: at rest since the reset
  mjtNum split = h->card ? h->card->delay_frac : 0;
  const mjtNum* ring = r + VR_RING;
  if (h->delay_frac > 0) return ring_piece(ring + 2*h->delay_whole, 1 - h->delay_frac, split);
  if (h->delay_whole > 0) return ring_piece(ring + 2*(h->delay_whole - 1), 0, split);
  return v;
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
  const Hydraulic* h = for_model(m, d, instance);
  const mjtNum* act = d->act + h->actadr;
  mjtNum* act_dot = d->act_dot + h->actadr;
  if (h->broken) {
    act_dot[0] = act_dot[1] = NAN;
    return;
  }
  mjtNum x = act[0], p = act[1];

  // spool lag with travel limit: no motion further into the stop
  mjtNum v = valve_law(h, delayed_voltage(m, d, instance, h));
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
  const Hydraulic* h = for_model(m, d, instance);
  if (h->broken) {
    d->actuator_force[h->actuator] = NAN;
    return;
  }
  if (disabled(m, h)) {
    d->actuator_force[h->actuator] = 0;
    return;
  }
  d->actuator_force[h->actuator] = h->torque_per * d->act[h->actadr + 1];
}


// spool position after holding the valve voltage v for dt (exact solution of the linear lag)
static mjtNum spool_after(const Hydraulic* h, mjtNum x, mjtNum v, mjtNum dt) {
  mjtNum target = v / h->value[ATTR_RATED_VOLTAGE];
  return target + (x - target) * mju_exp(-dt / h->value[ATTR_VALVE_TIME_CONSTANT]);
}

static mjtNum quantise(mjtNum x, mjtNum lsb) {
  return lsb > 0 ? lsb * round(x / lsb) : x;
}

// A sensor path over one physics step k: the reading x of t_n in, what the sensor gives out (the
// newest sample weighs in: taps[0], b0). `ring` holds the past deviations from rest, `st` the
// sections' states.
static mjtNum path_step(const SensorPath* p, mjtNum* ring, mjtNum* st, long long k, mjtNum x) {
  ring[k % p->ntaps] = x - p->rest;
  mjtNum y = 0;
  for (int j = 0; j < p->ntaps; j++) {
    if (p->taps[j] != 0) y += p->taps[j] * ring[(k - j + p->ntaps) % p->ntaps];
  }
  for (int i = 0; i < p->nsos; i++) {  // direct form II transposed
    const mjtNum* q = p->sos + 6*i;
    mjtNum* z = st + 2*i;
    mjtNum u = y;
    y = q[0]*u + z[0];
    z[0] = q[1]*u - q[4]*y + z[1];
    z[1] = q[2]*u - q[5]*y;
  }
  return y + p->gain_dc * p->rest;
}

// The sensors' filters over one physics step: raw *theta and *accel of t_n in, what the sensors
// give the card at t_n out.
static void sensors_step(const Card* c, mjtNum* card_state, mjtNum* theta, mjtNum* accel) {
  mjtNum* block = card_state + ST_BUFFER + c->nbuf + c->n;
  long long k = (long long) block[SN_COUNT];
  const SensorPath* pt = &c->path[PATH_THETA];
  const SensorPath* pa = &c->path[PATH_ACCEL];
  mjtNum* ring_theta = block + SN_RINGS;
  mjtNum* ring_accel = ring_theta + pt->ntaps;
  mjtNum* st_theta = ring_accel + pa->ntaps;
  mjtNum* st_accel = st_theta + 2 * pt->nsos;
  *theta = path_step(pt, ring_theta, st_theta, k, *theta);
  *accel = path_step(pa, ring_accel, st_accel, k, *accel);
  block[SN_COUNT] = (mjtNum) (k + 1);
}

// One physics step of the controller card (from advance, after MuJoCo's integration): sample the
// measurements of t_n (sensordata still holds them), update the controller every `steps` steps,
// and return the amplifier output over [t_n, t_n + h) in two pieces, *a over the first
// delay_frac of the step and *b over the rest: the held, delayed command, plus the excitation
// and, unless the controller replaces it, the position loop, saturated at +-10 V.
static void card_step(const mjModel* m, mjData* d, int instance, const Hydraulic* h,
                      mjtNum* a, mjtNum* b) {
  Card* c = h->card;
  mjtNum* s = d->plugin_state + m->plugin_stateadr[instance];
  mjtNum* buf = s + ST_BUFFER;
  mjtNum* z = buf + c->nbuf;
  mjtNum theta_r = reference(d, h) - h->value[ATTR_REFERENCE_ANGLE];
  mjtNum theta = d->sensordata[c->theta_adr] - h->value[ATTR_REFERENCE_ANGLE];
  mjtNum servo = h->value[ATTR_POSITION_GAIN] * (theta_r - theta);
  mjtNum u = excitation(m, d, h);
  int enabled = s[ST_ENABLED] != 0;
  // what the sensors give the card at t_n: the joint and the base (the servo amplifier reads the
  // joint directly), through the sensors' dynamics when configured (run every step, card on or off)
  const mjtNum* acc = d->sensordata + c->accel_adr;
  mjtNum read_theta = theta;
  mjtNum read_accel = c->direction[0]*acc[0] + c->direction[1]*acc[1] + c->direction[2]*acc[2]
                      - c->accel_offset;
  if (c->sensors) sensors_step(c, s, &read_theta, &read_accel);

  memmove(buf + 1, buf, (c->nbuf - 1) * sizeof(mjtNum));
  if (enabled) {
    if (((long long) s[ST_COUNTER]) % c->steps == 0) {
      mjtNum w[CTRL_NIN] = {
        theta_r,
        quantise(read_theta + (c->theta_noise >= 0 ? d->ctrl[c->theta_noise] : 0), c->theta_lsb),
        quantise(read_accel + (c->accel_noise >= 0 ? d->ctrl[c->accel_noise] : 0), c->accel_lsb),
      };
      int n = c->n;
      mjtNum v = c->D[0]*w[0] + c->D[1]*w[1] + c->D[2]*w[2];
      for (int i = 0; i < n; i++) v += c->C[i] * z[i];
      for (int i = 0; i < n; i++) {
        mjtNum zi = c->B[CTRL_NIN*i]*w[0] + c->B[CTRL_NIN*i+1]*w[1] + c->B[CTRL_NIN*i+2]*w[2];
        const mjtNum* Ai = c->A + n*i;
        for (int j = 0; j < n; j++) zi += Ai[j] * z[j];
        c->z_scratch[i] = zi;
      }
      mju_copy(z, c->z_scratch, n);
      s[ST_COMMAND] = v;
    }
    s[ST_COUNTER] += 1;
  } else {
    // the servo amplifier alone; the ring records what the position loop commands, so that a
    // controller replacing it takes over its history through the delay (no jump at switch-on)
    s[ST_COMMAND] = c->replaces ? servo : 0;
  }
  buf[0] = s[ST_COMMAND];

  mjtNum v;
  if (!enabled) {
    v = mju_clip(u + servo, -SAMII_AMPLIFIER_LIMIT_V, SAMII_AMPLIFIER_LIMIT_V);
    *a = v;
  } else {
    mjtNum base = u + (c->replaces ? 0 : servo);
    v = mju_clip(base + buf[c->delay_whole], -SAMII_AMPLIFIER_LIMIT_V, SAMII_AMPLIFIER_LIMIT_V);
    *a = c->delay_frac > 0 ? mju_clip(base + buf[c->delay_whole + 1], -SAMII_AMPLIFIER_LIMIT_V,
                                      SAMII_AMPLIFIER_LIMIT_V) : v;
  }
  *b = v;
  s[ST_VALVE] = v;
}

// the spool after holding ring entry e's amplifier output from fraction `from` to `to` of its
// step (the two pieces split at `split`), each through the valve's law
static mjtNum spool_over(const Hydraulic* h, mjtNum x, const mjtNum* e, mjtNum from, mjtNum to,
                         mjtNum split, mjtNum dt) {
  if (from < split) {
    mjtNum end = to < split ? to : split;
    x = mju_clip(spool_after(h, x, valve_law(h, e[0]), (end - from) * dt), -1, 1);
  }
  if (to > split) {
    mjtNum start = from > split ? from : split;
    x = mju_clip(spool_after(h, x, valve_law(h, e[1]), (to - start) * dt), -1, 1);
  }
  return x;
}

// The spool at t_n + h from x_n, given the amplifier output over this step (a over its first
// `split`, b over the rest): through the command delay (the ring) and the valve's law.
static mjtNum valve_step(const mjModel* m, mjData* d, int instance, const Hydraulic* h,
                         mjtNum x_n, mjtNum a, mjtNum b, mjtNum split) {
  mjtNum dt = m->opt.timestep;
  mjtNum now[2] = {a, b};
  if (!h->nring) return spool_over(h, x_n, now, 0, 1, split, dt);
  mjtNum* r = command_ring(m, d, instance, h);
  mjtNum* ring = r + VR_RING;
  if (r[VR_PRIMED] == 0) {  // first step since the reset: the amplifier held this output before
    for (int i = 0; i < h->nring; i++) {
      ring[2*i] = a;
      ring[2*i + 1] = a;
    }
    r[VR_PRIMED] = 1;
  } else {
    memmove(ring + 2, ring, 2 * (h->nring - 1) * sizeof(mjtNum));
  }
  ring[0] = a;
  ring[1] = b;
  // this step [n, n+1) sees the amplifier output of [n - K - f, n + 1 - K - f), in steps
  int K = h->delay_whole;
  mjtNum f = h->delay_frac;
  if (f > 0) {
    mjtNum x = spool_over(h, x_n, ring + 2*(K + 1), 1 - f, 1, split, dt);
    return spool_over(h, x, ring + 2*K, 0, 1 - f, split, dt);
  }
  return spool_over(h, x_n, ring + 2*K, 0, 1, split, dt);
}

// after MuJoCo's integration of act (explicit Euler), qvel and qpos (see the header comment)
static void hydraulic_advance(const mjModel* m, mjData* d, int instance) {
  const Hydraulic* h = for_model(m, d, instance);
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

    if (h->card) {
      mjtNum a, b;
      card_step(m, d, instance, h, &a, &b);
      act[0] = valve_step(m, d, instance, h, x_n, a, b, h->card->delay_frac);
    } else if (h->nring) {
      // the amplifier output of t_n, which act_dot saw before integration moved qpos
      mjtNum v = command_ring(m, d, instance, h)[VR_VNOW];
      act[0] = valve_step(m, d, instance, h, x_n, v, v, 0);
    } else if (act_dot[0] != 0) {
      // exact spool step: act_dot[0] = (target - x_n)/tau_v, or 0 against the stop
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
  // the actuator's states are in mjData.act; a controller card and a command delay keep their
  // own here
  int whole;
  mjtNum frac;
  int nring = delay_size(m, instance, &whole, &frac);
  return card_nstate(m, instance) + (nring ? VR_RING + 2*nring : 0);
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
  hydraulic_free((Hydraulic*) d->plugin_data[instance]);
  d->plugin_data[instance] = 0;
}

static void hydraulic_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data,
                            int instance) {
  // the actuator's states are in mjData.act, which mj_resetData zeroes (or a keyframe sets);
  // a controller card starts enabled, at rest; the command ring empty (primed by the first step)
  int n = m->plugin_statenum[instance];  // as compiled (init refuses a configuration that disagrees)
  if (n) mju_zero(plugin_state, n);
  if (card_nstate(m, instance)) plugin_state[ST_ENABLED] = 1;
  // (the sensors' block all zero: at rest since long before)
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
  plugin.nattribute = NATTR_ALL;
  plugin.attributes = kAttributes;
  plugin.nstate = hydraulic_nstate;
  plugin.init = hydraulic_init;
  plugin.destroy = hydraulic_destroy;
  plugin.reset = hydraulic_reset;
  plugin.compute = hydraulic_compute;
  plugin.advance = hydraulic_advance;
  plugin.actuator_act_dot = hydraulic_act_dot;
  // copy: not needed; plugin_data holds only what init derives from the model (parsed again when
  // another model steps the data: for_model), and mj_copyData keeps the destination's own plugin_data.
  mjp_registerPlugin(&plugin);
}
