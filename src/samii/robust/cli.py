"""``samii robust``: Monte Carlo robustness of a controller in the nonlinear simulator.

Each sample is a plant drawn from the given spreads and/or a calibration's covariance
(:mod:`samii.robust.sampling`), run closed loop (:mod:`samii.robust.task`) in this process or on
Dask (:mod:`samii.robust.engine`). Writes into ``--out``: ``robust.json`` (the summary, the
nominal plant's run, every sample), ``samples.csv`` (one line per sample: its parameters and
results) and the figures ``histograms.png`` and ``influence.png``. Imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

from samii.cli_args import (
    add_json,
    add_model,
    add_no_progress,
    add_out,
    add_overwrite,
    add_seed,
    add_set,
    float_in,
    int_in,
    nonempty,
    nonempty_path,
)
from samii.errors import InputError

__all__ = ["add_arguments", "run", "MAX_SAMPLES"]

#: samii.robust.engine.DEFAULT_CONNECT_TIMEOUT_S (not imported here: that module imports Dask; a test checks they agree)
SCHEDULER_TIMEOUT_S = 30.0

MAX_SAMPLES = 100_000
_FILES = ("robust.json", "samples.csv")
#: An absolute spread below this fraction of its nominal value varies nothing (double precision keeps 1e-16; a
#: parameter known to 1e-4 of itself is known better than any rig's).
TINY_SPREAD = 1e-4
#: Fewer plants than this: the 5 % and 95 % percentiles are the smallest and largest drawn (1/0.05 = 20).
FEW_SAMPLES = 20


def _workers(text: str) -> int:
    """A number of worker processes, or ``auto``: one per core."""
    return (os.cpu_count() or 1) if text == "auto" else int_in(0, 1024)(text)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from samii.closedloop.cli import MAX_DELAY_STEPS
    from samii.closedloop.trial import BUILTIN_CONTROLLERS

    p.add_argument(
        "--controller",
        required=True,
        metavar="SPEC",
        help=f"{', '.join(BUILTIN_CONTROLLERS)}, or a controller file (samii design ... --save); designed once, on the nominal plant",
    )
    p.add_argument(
        "--scenario",
        choices=("step", "loper", "release"),
        default="step",
        help="the closed-loop test each sample runs (samii closedloop; default step: 5 deg at t = 1 s, 10 s)",
    )
    p.add_argument("--samples", type=int_in(1, MAX_SAMPLES), default=100, metavar="N", help="number of plants drawn (default 100)")
    add_seed(p, "seed of the draws (and of the sensor noise with --noise): the same seed gives the same table whatever runs it (default 0)")
    p.add_argument("--spread", action="append", default=[], metavar="NAME=P%",
                   help="a physical spread: NAME normal about its nominal value with standard deviation P %% of it (NAME=SIGMA: "
                        "absolute, in its unit), truncated at 3 sigma and above 5 %% of a positive nominal; repeatable "
                        "(samii params lists the names)")  # fmt: skip
    p.add_argument("--covariance", metavar="CALIBRATION.json", type=nonempty_path,
                   help="draw the calibrated parameters jointly from their standard errors and correlations (samii calibrate --out "
                        "writes calibration.json); the calibrated plant is then the nominal one")  # fmt: skip
    add_model(p, "the nominal plant's parameter file (default: the embedded model)", metavar="PARAMS.json")
    add_set(p, "override a nominal parameter (repeatable)")
    p.add_argument(
        "--delay-samples",
        type=float_in(0.0, float(MAX_DELAY_STEPS), unit="samples"),
        default=0.0,
        metavar="N",
        help="the controller's computation delay [samples] (default 0)",
    )
    p.add_argument("--noise", action="store_true", help="sensor noise on the controller's measurements, seeded per sample from --seed")
    p.add_argument(
        "--workers",
        type=_workers,
        default=None,
        metavar="N",
        help="0: run in this process (the default, unless Dask's configuration names a scheduler); N or auto: on a local "
        "Dask cluster of N worker processes (auto: one per core)",
    )
    p.add_argument("--scheduler", metavar="ADDRESS", type=nonempty("a scheduler's address (tcp://host:port)"),
                   help="run on this Dask cluster (tcp://host:8786); its workers need samii installed. Without --scheduler and "
                        "--workers, Dask's own configured scheduler-address (DASK_SCHEDULER_ADDRESS) is used if set")  # fmt: skip
    p.add_argument(
        "--scheduler-timeout",
        type=float_in(1.0, 3600.0, unit="s"),
        default=None,
        metavar="S",
        help=f"seconds the --scheduler has to answer, and a worker to join it, before the run is refused (default {SCHEDULER_TIMEOUT_S:g})",
    )
    add_out(p, "write robust.json, samples.csv and the figures here")
    add_overwrite(p, "replace existing outputs in --out")
    add_json(p, "print robust.json's summary as JSON")
    add_no_progress(p)


def _nominal_params(args):
    from samii.sim.model import default_params, params_from_dict, params_with_overrides, read_params_file
    from samii.sim.overrides import parse_overrides

    cov = None
    if args.covariance:
        from samii.robust.sampling import read_covariance

        if args.model:
            raise InputError("--model: with --covariance the nominal plant is the calibration's (its calibrated_params); give one of them")
        cov = read_covariance(args.covariance)
        if cov.converged is False:  # its standard errors are those of a point that is no minimum: said, used as asked
            print(
                f"samii robust: warning: --covariance {args.covariance}: the calibration did not converge (field 'converged' is "
                "false): its standard errors and correlations describe no minimum of its cost; calibrate again",
                file=sys.stderr,
            )
        try:
            params = params_from_dict(cov.nominal, complete=True)
        except ValueError as exc:
            raise InputError(f"--covariance {args.covariance}: field 'calibrated_params': {exc}") from None
    elif args.model:
        if not str(args.model).lower().endswith(".json"):
            raise InputError(f"--model {args.model}: samii robust varies a parameter file's values (.json; samii params lists them), not an MJCF")
        params = read_params_file(args.model)
    else:
        params = default_params()
    overrides = parse_overrides(args.set)
    if cov is not None and set(overrides) & set(cov.names):
        raise InputError(f"--set {sorted(set(overrides) & set(cov.names))[0]}: also drawn by --covariance; give one of them")
    return params_with_overrides(params, overrides) if overrides else params, cov


def _study_warnings(args, spreads, nominal: dict) -> list[str]:
    """What makes a study say less than it seems to: an absolute spread that is a rounding error of its parameter (the
    '%' forgotten: NAME=20 is 20 in the parameter's unit), percentiles of fewer plants than they need."""
    out = []
    for sp in spreads:
        value = nominal.get(sp.name)
        if sp.absolute is not None and isinstance(value, (int, float)) and value and 0 < sp.absolute < TINY_SPREAD * abs(value):
            out.append(
                f"--spread {sp.name}={sp.absolute:g}: an absolute standard deviation of {sp.absolute:g} on a nominal "
                f"{value:.6g} ({sp.absolute / abs(value):.2g} of it): the study varies nothing; a relative spread is "
                f"written with % ({sp.name}={sp.absolute:g}%)"
            )
    if args.samples < FEW_SAMPLES:
        out.append(
            f"--samples {args.samples}: the 5 and 95 % percentiles of fewer than {FEW_SAMPLES} plants are the extremes drawn, not the spread's tails"
        )
    return out


def run(args: argparse.Namespace) -> int:
    from samii.outputs import OutputFolder
    from samii.robust.plots import FIGURES

    if args.controller == "unity" and args.delay_samples:
        raise InputError("--delay-samples: the unity servo loop is analog (no digital controller to delay)")
    if args.controller == "unity" and args.noise:
        raise InputError("--noise: the unity servo loop samples no sensors (its analog loop reads the joint angle directly)")
    folder = OutputFolder(args.out, list(_FILES) + list(FIGURES), overwrite=args.overwrite) if args.out is not None else None
    from samii.robust.engine import Engine, configured_scheduler
    from samii.robust.sampling import draw_plants, parse_spread

    spreads = [parse_spread(s) for s in args.spread]
    params, cov = _nominal_params(args)
    from samii.sim.model import dotted, params_with_overrides

    draws = draw_plants(args.samples, args.seed, dotted(params), spreads, cov)
    warnings = _study_warnings(args, spreads, dotted(params))  # (said with the result, after every refusal's one line)

    for i in range(args.samples):  # every drawn value is one the model accepts, checked before any run
        try:
            params_with_overrides(params, draws.overrides(i))
        except InputError as exc:
            raise InputError(f"sample {i}: {exc}: narrow the spread (or give it as an absolute value)") from None
    if args.scheduler and args.workers is not None:
        raise InputError("--workers: with --scheduler the cluster's own workers run the study; give one of them")
    # an explicit --workers (0 included) wins over Dask's configured scheduler address
    scheduler = args.scheduler or (configured_scheduler() if args.workers is None else None)
    source = "--scheduler" if args.scheduler else "Dask's configured scheduler-address (DASK_SCHEDULER_ADDRESS or ~/.config/dask)"
    if scheduler:  # before any work: an address Dask cannot connect to is refused at once
        from samii.robust.engine import check_address

        if check_address(scheduler, source) is None:
            raise InputError(
                f"{source} {scheduler}: an in-process address (inproc://) names a scheduler inside one Python "
                "process, never another command's; give the scheduler's tcp://host:port"
            )
    if args.scheduler_timeout is not None and not scheduler:  # (it was accepted and did nothing)
        raise InputError("--scheduler-timeout: only with a Dask cluster to wait for (--scheduler, or Dask's configured scheduler-address)")
    engine = Engine(
        workers=args.workers or 0, scheduler=scheduler, connect_timeout_s=args.scheduler_timeout or SCHEDULER_TIMEOUT_S, scheduler_source=source
    )

    # the controller is designed (or read) once, on the nominal plant, in this process
    from samii.closedloop.trial import check_fits, resolve_controller
    from samii.robust.task import SampleTask
    from samii.sim.model import load_model, load_spec

    nominal_model = load_model(params=params)
    qpos, act = nominal_model.key_qpos[0].copy(), nominal_model.key_act[0].copy()

    def say(what: str) -> None:  # the stages of a "damping" controller's design
        if not args.json:
            print(f"  damping controller: {what}", file=sys.stderr)

    saved = resolve_controller(args.controller, lambda: (load_spec(params=params)[0], qpos, act), say=say)
    if saved is not None:
        check_fits(saved, args.controller, args.delay_samples, float(nominal_model.opt.timestep))
    from samii.robust.sampling import sample_seeds

    base = params.as_dict()

    def noise_seed(i: int) -> int | None:
        return sample_seeds(args.seed, i)[1] if args.noise else None

    tasks = [SampleTask(-1, base, {}, saved, args.scenario, args.delay_samples, noise_seed(-1))]
    tasks += [SampleTask(i, base, draws.overrides(i), saved, args.scenario, args.delay_samples, noise_seed(i)) for i in range(args.samples)]

    import contextlib
    import time

    from samii.cli_progress import Bar

    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        if engine.scheduler:  # connected first (bounded in time): a scheduler that refuses or never answers is one line
            stack.enter_context(engine)
        if not args.json and not args.no_progress:  # (a progress line: not before a refusal's one line when asked for quiet)
            print(
                f"samii robust: {args.controller}, {args.scenario} test, {args.samples} plants (seed {args.seed}) {engine.describe()}",
                file=sys.stderr,
            )
        with Bar("samii robust", unit="run", disable=args.no_progress or None, leave=False) as bar:
            results = engine.map(tasks, progress=bar)
    wall = time.perf_counter() - t0
    nominal, samples = results[0], results[1:]
    for w in warnings:
        print(f"samii robust: warning: {w}", file=sys.stderr)

    from samii.robust.study import summarise

    summary = summarise(draws, samples)
    if summary.n == 0:
        why = samples[0].note.removeprefix("no plant: ")
        raise InputError(f"none of the {args.samples} drawn plants could be built (the first: {why}); narrow the spreads")
    doc = {
        "controller": args.controller, "scenario": args.scenario, "seed": args.seed, "n_samples": args.samples,
        "engine": engine.describe(), "wall_s": wall, "warnings": warnings,
        "varied": [{"name": n, "nominal": float(v), "source": s} for n, v, s in zip(draws.names, draws.nominal, draws.sources)],
        "nominal_plant": nominal.table_row(),
        "summary": summary.as_json(),
        "samples": [dict(r.table_row(), params=draws.overrides(r.index)) for r in samples],
    }  # fmt: skip
    lines = _lines(doc, summary)
    if folder is not None:
        with folder:
            from samii.json_output import dumps
            from samii.robust.plots import plot_histograms, plot_influence
            from samii.schema import versioned

            folder.path("robust.json").write_text(dumps(versioned(doc), indent=1) + "\n")
            _write_csv(folder.path("samples.csv"), draws, samples)
            plot_histograms(samples, summary, f"{args.controller}, {args.scenario} test, {args.samples} plants", folder.path("histograms.png"))
            plot_influence(draws, samples, summary, folder.path("influence.png"))
        lines.append(f"wrote {args.out}/robust.json, samples.csv, {', '.join(FIGURES)}")
    if args.json:
        from samii.json_output import dumps

        print(dumps({k: v for k, v in doc.items() if k != "samples"}, indent=1))
    else:
        print("\n".join(lines))
    return 0


def _fmt(x, spec: str) -> str:
    return "n/a" if x is None else format(x, spec)


def _mode(row: dict) -> str:
    """A sample's least-damped mode in words: "zeta Z at F Hz", or a real pole by its s = -zeta 2 pi F (it does not
    oscillate: "zeta -1 at 8.7 Hz" read as an 8.7 Hz oscillation), or by the run's growth rate where the pole lies
    below the damping band (F = 0: a joint creeping at +0.197 1/s)."""
    zeta, hz, growth = row["zeta"], row["mode_hz"], row.get("growth_rate_1_s")
    if zeta is not None and abs(zeta) > 1.0 - 1e-9:
        s = -zeta * 2 * math.pi * hz if hz else growth
        return f"a real pole at s = {s:+.3g} 1/s (zeta {zeta:+.0f})" if s is not None else f"a real pole (zeta {zeta:+.0f})"
    return f"zeta {_fmt(zeta, '.3f')} at {_fmt(hz, '.3g')} Hz"


def _lines(doc: dict, s) -> list[str]:
    lo, hi = s.p_unstable_ci95
    nom = doc["nominal_plant"]
    out = [f"robustness of {doc['controller']} ({doc['scenario']} test), {doc['n_samples']} plants, seed {doc['seed']}, {doc['engine']}, "
           f"{doc['wall_s']:.1f} s",
           "varied: " + "; ".join(v["source"] for v in doc["varied"]),
           f"nominal plant: {'stable' if nom['stable'] else 'UNSTABLE'}, least-damped mode {_mode(nom)}, "
           + (f"base settles {nom['base_settle_s']:.2f} s" if nom["base_settle_s"] is not None else "base settling time n/a"),
           f"P(unstable) = {s.n_unstable}/{s.n} = {s.p_unstable:.3g} (95 % interval {lo:.3g}-{hi:.3g}, exact binomial)"]  # fmt: skip
    if s.zeta_percentiles:
        out.append(
            "closed-loop damping (least-damped mode) 5/50/95 %: "
            + " / ".join(f"{v:.3f}" for v in s.zeta_percentiles.values())
            + f" (over {s.n_zeta} samples)"
        )
    if s.settle_percentiles:
        out.append("base settling time 5/50/95 % [s]: " + " / ".join(f"{v:.2f}" for v in s.settle_percentiles.values()))
    if s.influence:
        out.append("influence on the damping (Spearman rho): " + ", ".join(f"{d['name']} {d['spearman']:+.2f}" for d in s.influence[:4]))
    out.append("worst samples:")
    if s.n_invalid:
        out.append(
            f"{s.n_invalid} drawn plant(s) could not be built (no static equilibrium near the nominal pose, or a mode too stiff "
            "for the physics step) and are not counted"
        )
    for w in s.worst[:3]:
        params = ", ".join(f"{k} {rel:+.1f} %" if rel is not None else f"{k} {w['params'][k]:.4g}" for k, rel in w["params_rel_pct"].items())
        state = "UNSTABLE" if not w["stable"] else "stable"
        out.append(f"  #{w['index']}: {state}, {_mode(w)}; {params}")
    return out


def _write_csv(path, draws, samples) -> None:
    import csv

    numbers = ["zeta", "mode_hz", "growth_rate_1_s", "base_settle_s", "theta_settle_s", "theta_overshoot_pct"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["index", *draws.names, "valid", "stable", "linear_stable", *numbers, "note"])
        for r in samples:
            row = r.table_row()
            w.writerow([r.index, *(repr(float(v)) for v in draws.values[r.index]), int(r.valid), int(r.stable), int(r.linear_stable),
                        *("" if row[c] is None else repr(float(row[c])) for c in numbers), r.note])  # fmt: skip
