"""The main job of ``samii`` with no arguments, on the embedded default model.

For now: print the modes at the nominal pose and run a short simulation of a
valve step under the servo position loop (later issues grow this into the
full pipeline: measure, fit, design, closed loop).
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["run_main_job"]


def run_main_job() -> int:
    from samii.sim.linearize import modes_report
    from samii.sim.model import load_model
    from samii.sim.simulate import simulate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rep = modes_report()
    print("SAMII on its flexible beam, nominal pose " + ", ".join(f"{a:.1f}" for a in rep.pose_deg) + " deg")
    print("base modes with joint 2 held: " + ", ".join(f"{m.freq_hz:.2f} Hz (zeta {m.zeta:.3f})" for m in rep.base_modes[:3]))
    pair = [s for s in rep.coupled_poles if 30 < abs(s.imag) < 80]
    if pair:
        print(f"servo-loop pole pair: {pair[0].real:.2f} ± {abs(pair[0].imag):.2f}j 1/s")

    model = load_model()
    dt = model.opt.timestep
    n = int(round(3.0 / dt))
    ctrl = np.zeros(n)
    ctrl[int(0.5 / dt) : int(0.6 / dt)] = 1.0  # a 1 V, 0.1 s pulse on the valve
    res = simulate(model, ctrl)
    # no speed figure here: a 3 s run is dominated by set-up; benchmarks/ measures speed
    print(
        f"simulated {n * dt:.1f} s: 1 V x 0.1 s valve pulse -> "
        f"joint 2 peak {np.degrees(np.max(np.abs(res.theta))):.2f} deg, base acceleration peak "
        f"{np.max(np.abs(res.accel)):.3f} m/s^2, load pressure peak {np.max(np.abs(res.p_load)) / 1e6:.2f} MPa"
    )
    return 0
