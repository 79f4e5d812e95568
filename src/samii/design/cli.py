"""``samii design``: control design on the notebook's models (a thin layer over :mod:`samii.design`).

Subcommands::

    samii design seed-report [--json]
    samii design rlocus [--out DIR] [--json] [--no-plots] [--force]
    samii design canonical [--modes 2|3] [--outputs accel|modal] [--out DIR] [--force]
    samii design place [--sample-time-s T] [--zeta Z] [--observer placement|kalman] [--json]
    samii design cancel [--loop theta|accel] [--gain K] [--json]

Only numpy is imported at module level (the CLI builds its parser cheaply).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="design_command", metavar="ACTION", required=True)

    p = sub.add_parser("seed-report", help="recompute eq 8.1-8.3 and 10.1-10.9 and the gain, beside the notebook's values")
    p.add_argument("--json", action="store_true", help="print machine-readable results")

    p = sub.add_parser("rlocus", help="mass-damping root-locus study (chapters 2-3): stable K_a intervals and best damping")
    p.add_argument("--out", type=Path, help="folder for summary.json, summary.md and one PNG per model and variant")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--no-plots", action="store_true", help="with --out, write only the tables")
    p.add_argument("--force", action="store_true", help="overwrite existing files in --out")
    p.add_argument("--n-gains", type=int, default=3000, help="gains per sign on the tracking grid (default 3000)")

    p = sub.add_parser("canonical", help="controllable canonical form (chapters 5-7), checked against the transfer functions")
    p.add_argument("--modes", type=int, choices=(2, 3), default=2, help="base modes: 2 (eq 1.4) or 3 (eq 9.4)")
    p.add_argument("--outputs", choices=("accel", "modal"), default="accel", help="one accelerometer or modal feedback")
    p.add_argument("--out", type=Path, help="folder for the LaTeX file")
    p.add_argument("--force", action="store_true", help="overwrite an existing LaTeX file")
    p.add_argument("--json", action="store_true", help="print the check as JSON")

    p = sub.add_parser("place", help="digital pole placement with observer (chapter 8) on the eq 1.4 model")
    p.add_argument("--sample-time-s", type=float, default=1e-3, help="controller sample time [s] (default 0.001)")
    p.add_argument("--zeta", type=float, default=1 / np.sqrt(2), help="damping of the moved poles (default 1/sqrt(2), see seed-report)")
    p.add_argument("--observer", choices=("placement", "kalman"), default="placement")
    p.add_argument("--input-noise-std", type=float, default=None, help="Kalman: valve-command noise [V]")
    p.add_argument("--theta-noise-std", type=float, default=None, help="Kalman: theta noise [model units]")
    p.add_argument("--accel-noise-std", type=float, default=None, help="Kalman: acceleration noise [model units]")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("cancel", help="pole-cancelling compensator (chapter 10) on the eq 9.4 model")
    p.add_argument("--loop", choices=("theta", "accel"), default="theta", help="the loop the compensator closes (see samii.design.cancel)")
    p.add_argument("--gain", type=float, default=None, help="use this gain instead of the zeta = 0.7 rule")
    p.add_argument("--json", action="store_true")


def _pairs(z) -> list[list[float]]:
    return [[float(np.real(x)), float(np.imag(x))] for x in np.atleast_1d(z)]


def _check_out(out: Path, names: list[str], force: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    existing = [n for n in names if (out / n).exists()]
    if existing and not force:
        raise SystemExit(f"samii design: {out} already has {existing[:3]}{'...' if len(existing) > 3 else ''}; pass --force to overwrite")


def run_seed_report(args) -> int:
    from samii.design.seed_report import seed_report

    report = seed_report()
    if args.json:
        print(json.dumps(report.as_json(), indent=1))
    else:
        print(report.text())
    return 0


def run_rlocus(args) -> int:
    from samii.design import rootlocus as rl

    models = rl.default_models()
    summaries = []
    loops = []
    for label, (p, num) in models.items():
        for v in rl.NOTEBOOK_VARIANTS:
            loop = rl.mass_damping_loop(p, numerator=num, variant=v, model=label)
            loops.append(loop)
            summaries.append(rl.summarize(loop, n_gains=args.n_gains))
    table = rl.summary_table(summaries)
    if args.out is not None:
        pngs = [] if args.no_plots else [f"rlocus_{lp.model}_{lp.variant.name}.png" for lp in loops]
        _check_out(args.out, ["summary.json", "summary.md", *pngs], args.force)
        (args.out / "summary.json").write_text(json.dumps([s.as_dict() for s in summaries], indent=1))
        (args.out / "summary.md").write_text(table)
        if not args.no_plots:
            from samii.viz.rootlocus_plot import plot_variant

            for lp, s, name in zip(loops, summaries, pngs):
                plot_variant(lp, s, path=args.out / name)
    if args.json:
        print(json.dumps([s.as_dict() for s in summaries], indent=1))
    else:
        print(table)
        if args.out is not None:
            print(f"wrote {args.out}")
    return 0


def run_canonical(args) -> int:
    from samii import notebook as nb
    from samii.design import canonical as cc

    form = cc.derive_canonical_form(args.modes, args.outputs)
    p = nb.EQ1_4_OPTIMIZED if args.modes == 2 else nb.EQ9_4
    check = cc.compare_with_tf(form, p)
    if args.out is not None:
        name = f"ccf_{args.modes}mode_{args.outputs}.tex"
        _check_out(args.out, [name], args.force)
        (args.out / name).write_text(form.latex())
    if args.json:
        print(json.dumps({"outputs": list(form.outputs), "model": "eq 1.4" if args.modes == 2 else "eq 9.4", "check": check}, indent=1))
        return 0
    print(f"controllable canonical form, {args.modes} base modes, outputs {form.outputs}, input v; checked at {'eq 1.4' if args.modes == 2 else 'eq 9.4'}")
    print(f"  poles of A vs transfer functions: max relative difference {check['poles']['rel']:.2e}")
    for name in form.outputs:
        c = check[name]
        print(
            f"  {name}/v: frequency response {c['freq_response_rel']:.2e}, numerator N_ss D - N D_ss {c['numerator_rel']:.2e} (relative), "
            f"zeros at the origin {c['origin_zeros_ss']} (state space) / {c['origin_zeros_tf']} (transfer function)"
        )
    if args.out is not None:
        print(f"wrote {args.out / f'ccf_{args.modes}mode_{args.outputs}.tex'}")
    return 0


def run_place(args) -> int:
    from samii import notebook as nb
    from samii.design import canonical as cc
    from samii.design.placement import design_placement

    model = cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)
    noise = None
    if args.observer == "kalman":
        if None in (args.input_noise_std, args.theta_noise_std, args.accel_noise_std):
            raise SystemExit("samii design place: --observer kalman needs --input-noise-std, --theta-noise-std and --accel-noise-std")
        noise = (args.theta_noise_std, args.accel_noise_std)
    d = design_placement(
        model, sample_time_s=args.sample_time_s, zeta=args.zeta, observer=args.observer,
        input_noise_std=args.input_noise_std, measurement_noise_std=noise,
    )  # fmt: skip
    out = {
        "model": "eq 1.4 (2-mode s^4), canonical form of chapter 5, notebook units",
        "sample_time_s": d.sample_time_s,
        "zeta": d.zeta,
        "observer": d.observer,
        "controller_poles_s": _pairs(d.poles_s),
        "controller_poles_z": _pairs(d.poles_z),
        "observer_poles_z": _pairs(d.observer_poles_z),
        "K": d.K.ravel().tolist(),
        "L": d.L.tolist(),
        "N": d.N,
    }
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"pole placement on eq 1.4 (notebook units), T = {d.sample_time_s:g} s, zeta = {d.zeta:.5g}, observer: {d.observer}")
        for s, z in zip(d.poles_s, d.poles_z):
            print(f"  controller pole s = {s.real:10.4f} {s.imag:+10.4f}j  ->  z = {z.real:.6f} {z.imag:+.6f}j")
        for z in d.observer_poles_z:
            print(f"  observer pole z = {z.real:.6f} {z.imag:+.6f}j")
        print(f"  K = {np.array2string(d.K.ravel(), precision=4)}\n  N = {d.N:.6g}")
    return 0


def run_cancel(args) -> int:
    from samii import notebook as nb
    from samii.design.cancel import design_pole_cancel

    d = design_pole_cancel(nb.EQ9_4, loop=args.loop, gain=args.gain)
    cl = d.closed_loop
    out = {
        "model": "eq 9.4 (3-mode s^4), notebook units",
        "loop": d.loop,
        "zeros": _pairs(d.zeros),
        "poles": _pairs(d.poles),
        "num": np.asarray(d.Gc.num[0][0], float).tolist(),
        "den": np.asarray(d.Gc.den[0][0], float).tolist(),
        "gain": d.gain,
        "closed_loop_poles": _pairs(cl),
        "reference_gain_for_unit_dc": d.reference_gain,
        "controller_scales_reference_by_default": d.loop == "theta",
    }
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"pole-cancelling compensator on eq 9.4, {d.loop} loop, K = {d.gain:.5g}")
        print(f"  numerator   {np.array2string(np.asarray(out['num']), precision=4)}")
        print(f"  denominator {np.array2string(np.asarray(out['den']), precision=4)}")
        for z in sorted(cl, key=abs):
            if z.imag >= 0:
                print(f"  closed-loop pole {z.real:10.4f} {z.imag:+10.4f}j  zeta {-z.real / abs(z):.3f}")
        if d.loop == "theta":
            print(
                f"  theta/theta_ref DC gain of the loop as drawn {1 / d.reference_gain:.3f}; the runnable controller scales "
                f"theta_ref by {d.reference_gain:.4g} (unit DC gain) unless told not to"
            )
    return 0


_RUN = {"seed-report": run_seed_report, "rlocus": run_rlocus, "canonical": run_canonical, "place": run_place, "cancel": run_cancel}


def run(args) -> int:
    return _RUN[args.design_command](args)


if __name__ == "__main__":  # pragma: no cover
    parser = argparse.ArgumentParser(prog="samii design")
    add_arguments(parser)
    sys.exit(run(parser.parse_args()))
