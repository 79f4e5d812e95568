"""Calibrate SAMII's physical knobs to the notebook's eq 9.4 and write them into the MJCF.

Rerun with ``python experiments/tune_model/tune.py`` (about a minute). It rewrites
``models/samii/samii.xml`` and ``models/samii/samii_params.json`` and writes
``experiments/tune_model/out/tuning.json`` and ``calibration_bode.png``.

The rig was measured with a swept sine and fitted with the notebook's procedure (eq 9.1/9.2,
3 modes, s^4, phase weight 0.1); eq 9.4 is what came out. So the simulator is calibrated
when ITS swept-sine data, fitted the same way, give eq 9.4 back (issue 8). Stages:

0. Structure, fixed: public beam (L, EI, mass per length) and TMM links; the arm upright on a
   vertical cantilever (``beam.pitch_deg = 90``: the reading of the notebook's geometry whose
   physics reproduces eq 9.4's B ratios, see the model card); valve time constant 1/158.87 s
   (eq 9.4 tau); displacement, bulk modulus, supply pressure from DESIGN.md.
1. A start: clamp stiffness, joint-1 stiffness and the beam's free length put the three base
   modes that joint 2 drives at eq 9.4's 1.73, 9.88 and 24.96 Hz (modal coefficients of the
   linearisation, ``LinearModel.base_coefficients``).
2. ``samii calibrate`` (``samii.calibrate.calibrate``) of the base, xdd/theta, against eq 9.4's
   xdd/theta curve over 0.1-40 Hz in the notebook's cost (phase weight 0.1): clamp stiffness,
   Maxwell-arm stiffness (the clamp's viscoelastic loss), joint-1 stiffness and damping, beam
   hinge damping, free length, the accelerometer's position on the mount, and the
   accelerometer's unknown unit (``gain.base``). xdd/theta does not depend on the actuator.
3. The actuator, theta/v: eq 9.1 cannot follow the simulator's theta/v everywhere (it has one
   pole pair where the simulator has the arm's every mode), so instead of matching eq 9.4's
   curve, the oil volume, leakage and rated flow are set so that the notebook's fit of the
   simulator's (linearised, noise-free) data gives eq 9.4's wp, zp and K1: the target itself,
   by indirect inference.
4. Check: ``samii measure`` (default swept sine) then the notebook's fit, against every target
   of issue 8 (``samii.calibrate.targets``).
"""

from __future__ import annotations

import json
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from samii import notebook as nb
from samii.calibrate import calibrate
from samii.calibrate.calibrate_file import load_target
from samii.calibrate.targets import check_fit_against_eq9_4
from samii.identify.fit import fit
from samii.identify.structures import ModelStructure
from samii.measure.campaign import linearised_frf, measure_swept
from samii.measure.excitation import SweptSine
from samii.sim.equilibrium import static_equilibrium
from samii.sim.linearize import base_modes, linearize
from samii.sim.mjcf import NOMINAL_POSE_RAD, SamiiParams, samii_xml
from samii.sim.model import load_model, load_spec, params_with_overrides, write_params

ROOT = Path(__file__).resolve().parents[2]
MODEL_DIR = ROOT / "models" / "samii"
OUT = Path(__file__).resolve().parent / "out"

TARGET_HZ = np.array(nb.BASE_MODES_HZ)
E = nb.EQ9_4
K1_RAD = E["K1"] * math.pi / 180  # (rad/s)/V: the notebook's theta is in degrees

BASE_KNOBS = (
    "gain.base",
    "beam.clamp_stiffness_Nm_rad",
    "beam.clamp_maxwell_stiffness_Nm_rad",
    "arm.joint1_stiffness_Nm_rad",
    "arm.joint1_damping_Nms_rad",
    "beam.beam_damping_time_s",
    "beam.length_m",
    "beam.accel_offset_m",
)
HYDRAULIC_KNOBS = ("hydraulic.total_volume", "hydraulic.leakage_coefficient", "hydraulic.rated_flow", "hydraulic.valve_time_constant")
DAMPING_KNOBS = ("beam.clamp_maxwell_stiffness_Nm_rad", "beam.clamp_relaxation_time_s", "arm.joint1_damping_Nms_rad", "beam.beam_damping_time_s")
#: Weight (as a tolerance) of the joint-2-held modal damping ratios against eq 9.4's in stage 3.
MODAL_ZETA_TOL = (0.25, 0.25, 0.25)
FREQUENCY_KNOBS = ("beam.clamp_stiffness_Nm_rad", "arm.joint1_stiffness_Nm_rad", "beam.length_m")


def structure() -> SamiiParams:
    """Stage 0: public values, the vertical-cantilever reading, the valve lag of eq 9.4."""
    p = params_with_overrides(
        SamiiParams(),
        {
            "beam.pitch_deg": 90.0,
            "beam.clamp_damping_Nms_rad": 0.0,
            "beam.clamp_maxwell_stiffness_Nm_rad": 2.0e4,
            "beam.clamp_relaxation_time_s": 1.0 / E["w1"],
            "beam.beam_damping_time_s": 5.0e-4,
            "arm.joint1_damping_Nms_rad": 4.0,
            "hydraulic.valve_time_constant": 1.0 / E["tau"],
            "hydraulic.total_volume": 5.0e-6,
            "hydraulic.leakage_coefficient": 9.3e-14,
        },
    )
    h = p.hydraulic
    return replace(p, hydraulic=replace(h, rated_flow=K1_RAD * h.rated_voltage * h.displacement))


def driven_modes(p: SamiiParams, max_hz: float = 40.0):
    """The base modes joint 2 drives (xdd/theta's modal terms), by frequency."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        cs = linearize(load_model(params=p)).base_coefficients(max_freq_hz=max_hz)
    big = max(abs(c.B) for c in cs)
    return [c for c in cs if abs(c.B) > 1e-3 * big]


def stage1_frequencies(p: SamiiParams) -> SamiiParams:
    names = ("beam.clamp_stiffness_Nm_rad", "arm.joint1_stiffness_Nm_rad", "beam.length_m")

    def with_x(x):
        return params_with_overrides(p, dict(zip(names, np.exp(x))))

    def r(x):
        f = np.array([c.freq_hz for c in driven_modes(with_x(x))[:3]])
        return np.log(f / TARGET_HZ)

    x0 = np.log([1.3e5, 2.0e3, 4.3])
    s = least_squares(r, x0, diff_step=1e-4, xtol=1e-10, bounds=(np.log([1e4, 2e2, 3.0]), np.log([1e7, 2e4, p.beam.length_m])))
    return with_x(s.x)


def held_modes(p: SamiiParams):
    """The base modes with joint 2 held (``samii modes``), first three."""
    spec, _ = load_spec(params=p)
    return base_modes(spec, NOMINAL_POSE_RAD[1], max_freq_hz=45.0)[:3]


def fitted_eq9(p: SamiiParams, f_hz: np.ndarray):
    """The notebook's fit (3 modes, s^4, pw 0.1) of the simulator's linearised FRF."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        frf = linearised_frf(load_model(params=p), f_hz)
    return fit(frf, ModelStructure(n_modes=3, numerator="s4"), phase_weight=0.1, start="notebook", n_perturbed=0)


def stage3_indirect(p: SamiiParams, f_hz: np.ndarray) -> SamiiParams:
    """Knobs set so that the notebook's fit of the simulator's data gives eq 9.4: the hydraulic
    ones for wp, zp, K1, tau; the dampers for z1, zz, z3 (which the fit sees through both
    channels, with the arm's other modes nearby, not as the modal dampings of stage 2)."""
    knobs = HYDRAULIC_KNOBS + DAMPING_KNOBS + FREQUENCY_KNOBS

    def with_x(x):
        return params_with_overrides(p, dict(zip(knobs, np.exp(x))))

    def r(x):
        try:
            return residuals(with_x(x))
        except (ValueError, RuntimeError, ZeroDivisionError):  # a trial point the simulator cannot run
            return np.full(n_residuals, 1e3)

    def residuals(q):
        fp = fitted_eq9(q, f_hz).params
        # each residual in units of its tolerance (issue 8): frequencies and gain tightly
        out = [math.log(fp["wp"] / E["wp"]) / 0.05, math.log(fp["K1"] / K1_RAD) / 0.10, math.log(fp["tau"] / E["tau"]) / 0.15]
        # the closed servo loop (unity feedback, 1 V/deg): eq 10.1's pair, within 10 %
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            cl = linearize(load_model(params=q)).poles
        target = nb.EQ10_1[1]
        out.append(abs(cl[np.argmin(np.abs(cl - target))] - target) / abs(target) / 0.10)
        out += [math.log(fp[z] / E[z]) / 0.30 for z in ("zp", "z1", "zz", "z3")]
        out += [math.log(fp[w] / E[w]) / 0.03 for w in ("w1", "wz", "w3")]
        # and the physical modes (samii modes, joint 2 held: +-2 % in frequency, +-25 % in damping)
        held = held_modes(q)
        out += [math.log(m.zeta / z) / tol for m, z, tol in zip(held, nb.BASE_ZETAS, MODAL_ZETA_TOL)]
        out += [math.log(m.freq_hz / f) / 0.02 for m, f in zip(held, nb.BASE_MODES_HZ)]
        return np.array(out)

    x0 = np.log([getattr(getattr(p, n.split(".")[0]), n.split(".")[1]) for n in knobs])
    n_residuals = residuals(with_x(x0)).size
    lo = x0 - np.log(20.0)  # a factor 20 either way; the free length at most the beam's
    hi = x0 + np.log(20.0)
    hi[list(knobs).index("beam.length_m")] = math.log(nb.TMM["beam"]["length_m"])
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
    s = least_squares(r, x0, bounds=(lo, hi), diff_step=1e-3, xtol=1e-8, ftol=1e-10)
    print(f"stage 3: residuals in tolerances: {np.round(s.fun, 3).tolist()}")
    return with_x(s.x)


def main() -> int:
    t0 = time.perf_counter()
    OUT.mkdir(parents=True, exist_ok=True)
    p = structure()
    p = stage1_frequencies(p)
    print("stage 1 (mode frequencies):", [round(c.freq_hz, 3) for c in driven_modes(p)[:3]], "Hz")

    target = load_target("eq9.4")
    base_fit = calibrate(target, BASE_KNOBS, base=p, channels=("base",), phase_weight=0.1, max_nfev=100, data_source="eq 9.4 (xdd/theta)")
    p = base_fit.params
    print("stage 2 (calibrate xdd/theta):")
    print(base_fit.table())
    print(
        f"  cost {base_fit.cost_start:.4g} -> {base_fit.cost:.4g}, RMS {base_fit.rms['base'][0]:.2f} dB / {base_fit.rms['base'][1]:.2f} deg; {base_fit.status}"
    )
    for w in base_fit.warnings:
        print("  warning:", w)

    # the frequencies samii measure's default swept sine reports (FFT bins nearest a log grid):
    # the notebook's fit of damping ratios depends on the points near each peak, so the
    # linearised proxy is fitted on exactly the grid the check in stage 4 uses
    f_hz = measure_swept(load_model(params=p), SweptSine()).frf.freq_hz
    p = stage3_indirect(p, f_hz)
    lin_fit = fitted_eq9(p, f_hz)
    print(
        "stage 3 (indirect): fitted wp {wp:.2f} zp {zp:.4f} K1 {K1:.3f} (deg: {K1d:.2f}) tau {tau:.1f} z1 {z1:.4f} zz {zz:.4f} z3 {z3:.4f}".format(
            K1d=lin_fit.params["K1"] * 180 / math.pi, **lin_fit.params
        )
    )
    for n in HYDRAULIC_KNOBS + DAMPING_KNOBS + FREQUENCY_KNOBS:
        sec, name = n.split(".")
        print(f"  {n} = {getattr(getattr(p, sec), name):.6g}")

    # the home keyframe at static equilibrium; the committed model
    model = load_model(params=p)
    eq = static_equilibrium(model)
    (MODEL_DIR / "samii.xml").write_text(samii_xml(p, keyframe_qpos=eq.qpos, keyframe_act=eq.act))
    write_params(p, MODEL_DIR / "samii_params.json", note="written by experiments/tune_model/tune.py; samii.xml is samii_xml() of these")

    # stage 4: the rig's procedure on the committed model
    model = load_model(MODEL_DIR / "samii.xml")
    meas = measure_swept(model, SweptSine())
    measured_fit = fit(meas.frf, ModelStructure(n_modes=3, numerator="s4"), phase_weight=0.1)
    checks = check_fit_against_eq9_4(measured_fit.params)
    print("stage 4: samii measure (default) + samii fit --modes 3 --numerator s4 --phase-weight 0.1, against eq 9.4:")
    for c in checks:
        print("  " + c.row())

    spec, _ = load_spec(MODEL_DIR / "samii.xml")
    held = base_modes(spec, NOMINAL_POSE_RAD[1], max_freq_hz=45.0)
    driven = driven_modes(p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lin = linearize(model)
    ol = lin.open_loop().poles
    valve = ol[(np.abs(ol.imag) < 1e-6) & (np.abs(ol) > 100) & (np.abs(ol) < 250)]
    cl_pair = lin.poles[np.argmin(np.abs(lin.poles - nb.EQ10_1[1]))]
    result = {
        "params": p.as_dict(),
        "stage2_calibration": base_fit.to_dict(),
        "stage3_linearised_fit": {k: float(v) for k, v in lin_fit.params.items()},
        "stage4_measured_fit": {k: float(v) for k, v in measured_fit.params.items()},
        "targets": [{"name": c.name, "target": c.target, "value": c.value, "tolerance": c.tolerance, "error": c.error, "ok": c.ok} for c in checks],
        "driven_base_modes": [{"freq_hz": c.freq_hz, "zeta": c.zeta, "B_m_per_rad": c.B} for c in driven],
        "held_modes_below_45hz": [{"freq_hz": m.freq_hz, "zeta": m.zeta} for m in held],
        "valve_pole_rad_s": [float(v.real) for v in valve],
        "unity_feedback_pair": [float(cl_pair.real), float(cl_pair.imag)],
        "unity_feedback_pair_target": [nb.EQ10_1[1].real, nb.EQ10_1[1].imag],
        "equilibrium": {"max_qacc": eq.residual_qacc, "max_act_dot": eq.residual_act_dot},
        "elapsed_s": time.perf_counter() - t0,
    }
    (OUT / "tuning.json").write_text(json.dumps(result, indent=2) + "\n")
    _plot(base_fit, target, OUT / "calibration_bode.png")
    ok = all(c.ok for c in checks)
    print(f"all targets {'met' if ok else 'NOT met'}; {time.perf_counter() - t0:.0f} s")
    return 0 if ok else 1


def _plot(result, data, path: Path) -> None:
    import matplotlib.pyplot as plt

    from samii.calibrate.simulator import SimulatorFRF
    from samii.viz.fit_plot import plot_fit_overlay

    st = SimulatorFRF(result.params, result.names)
    fig = plot_fit_overlay(
        data,
        {"stage 1 start": (st, dict(result.start)), "calibrated": (st, dict(result.values))},
        channels=("base",),
        title="SAMII simulator calibrated to eq 9.4's xdd/theta (samii calibrate)",
        note="data: eq 9.4's xdd/theta curve (theta in degrees converted to rad; the notebook's acceleration unit is calibrated as gain.base)",
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
