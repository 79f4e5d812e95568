"""``samii modes``: linearise at the nominal pose and print the modes."""

from __future__ import annotations

import argparse

from samii.cli_args import add_json, add_model, add_set, positive_float
from samii.json_output import dumps
from samii.sim.overrides import parse_overrides


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_model(p, "MJCF file (default: the embedded SAMII model)")
    add_set(p, "override a model parameter, e.g. beam.clamp_stiffness_Nm_rad=2e5 (repeatable)")
    p.add_argument("--max-freq-hz", type=positive_float, default=45.0, help="list modes and poles up to this frequency (default 45)")
    add_json(p, "print machine-readable JSON")


def run(args: argparse.Namespace) -> int:
    import warnings

    import numpy as np

    from samii.sim.linearize import modes_report

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # scipy logm accuracy notes at 1e-13
        rep = modes_report(args.model, overrides=parse_overrides(args.set) or None, max_freq_hz=args.max_freq_hz)
    if args.json:
        print(dumps(rep.as_json(), indent=2))
        return 0
    print("SAMII at the nominal pose: joint angles " + ", ".join(f"{a:.2f}" for a in rep.pose_deg) + " deg")
    print("\n(a) base modes, joint 2 held")
    print("    mode   freq [Hz]   zeta")
    for i, m in enumerate(rep.base_modes, 1):
        print(f"    {i:4d}   {m.freq_hz:9.3f}   {m.zeta:.4f}")
    print(f"\n(b) whole system, servo position loop closed ({rep.position_gain_v_per_rad:.4g} V/rad)")
    print("    pole [1/s]                      freq [Hz]   zeta")
    for s in rep.coupled_poles:
        if s.imag < -1e-9:
            continue
        wn = abs(s)
        zeta = -s.real / wn if wn > 0 else float("nan")
        im = f"{s.imag:+10.3f}j" if abs(s.imag) > 1e-9 else " " * 11
        flag = "   UNSTABLE" if s in rep.unstable_poles else ""
        print(f"    {s.real:10.3f} {im}          {wn / (2 * np.pi):9.3f}   {zeta:.4f}{flag}")
    if not rep.stable:
        n = sum(1 for p in rep.unstable_poles if p.imag >= 0)
        print(
            f"\nUNSTABLE: {n} pole(s) or pair(s) in the right half plane, marked above: the nominal pose is not a "
            "stable rest state under the servo loop (samii measure refuses this model)"
        )
    return 0
