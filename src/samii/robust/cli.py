"""``samii robust``: Monte Carlo robustness of a controller in the nonlinear simulator.

Each sample is a plant drawn from the given spreads and/or a calibration's covariance
(:mod:`samii.robust.sampling`), run closed loop (:mod:`samii.robust.task`) in this process, in worker processes
forked from it, or on a user's Dask cluster (:mod:`samii.robust.engine`); the study is one library call (:mod:`samii.robust.runner`), which
writes into ``--out``: ``robust.json`` (the summary, the nominal plant's run, every sample), ``samples.csv``
(one line per sample: its parameters and results) and the figures ``histograms.png`` and ``influence.png``.
This module parses, shows progress and prints. Imports nothing heavy at module level (the runner imports Dask).
"""

from __future__ import annotations

import argparse
import math
import sys

from samii.cli_args import (
    add_antialias,
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

__all__ = ["add_arguments", "run", "MAX_SAMPLES"]

#: samii.robust.engine.DEFAULT_CONNECT_TIMEOUT_S (not imported here: that module imports Dask; a test checks they agree)
SCHEDULER_TIMEOUT_S = 30.0

MAX_SAMPLES = 100_000


def _workers(text: str) -> int:
    """A number of worker processes, or ``auto``: one per core this process may run on."""
    from samii.errors import InputError
    from samii.forkmap import workers

    if text != "auto":
        return int_in(0, 1024)(text)
    try:
        return workers()
    except InputError as exc:  # (a bad SAMII_WORKERS: argparse would have said only "invalid _workers value: 'auto'")
        raise argparse.ArgumentTypeError(str(exc)) from None


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
    add_antialias(p)
    p.add_argument(
        "--workers",
        type=_workers,
        default=None,
        metavar="N",
        help="0: run in this process; N: in N worker processes on this machine; auto (the default, unless Dask's "
        "configuration names a scheduler): one per core this process may run on (SAMII_WORKERS sets it)",
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


def run(args: argparse.Namespace) -> int:
    from samii.cli_progress import Bar
    from samii.robust.plots import FIGURES
    from samii.robust.runner import NoPlantBuilt, StudyRequest, plan_study

    request = StudyRequest(
        controller=args.controller,
        scenario=args.scenario,
        samples=args.samples,
        seed=args.seed,
        spreads=tuple(args.spread),
        covariance=args.covariance,
        model=args.model,
        overrides=tuple(args.set),
        delay_samples=args.delay_samples,
        noise=args.noise,
        antialias=args.antialias,
        workers=args.workers,
        scheduler=args.scheduler,
        scheduler_timeout_s=args.scheduler_timeout,
    )

    def say(what: str) -> None:  # the stages of a "damping" controller's design
        print(f"  damping controller: {what}", file=sys.stderr)

    study = plan_study(request, out=args.out, overwrite=args.overwrite, say=None if args.json else say)

    def warn() -> None:  # what makes the study say less than it seems to: said once the plants have run
        for w in study.warnings:
            print(f"samii robust: warning: {w.text}", file=sys.stderr)

    try:
        with study:  # (connected to a user's cluster first: one that refuses or never answers is one line)
            if not args.json and not args.no_progress:  # (a progress line: not before a refusal's one line when asked for quiet)
                print(f"samii robust: {study.describe()}", file=sys.stderr)
            with Bar("samii robust", unit="run", disable=args.no_progress or None, leave=False) as bar:
                result = study.run(progress=bar)
    except NoPlantBuilt:  # (the plants have run: what the study's spreads say is said before the refusal, as with a result)
        warn()
        raise
    warn()
    if args.json:
        from samii.json_output import dumps
        from samii.schema import as_json

        print(dumps({k: v for k, v in as_json(result.record).items() if k != "samples"}, indent=1))
        return 0
    lines = _lines(result.record, result.summary)
    if result.written:
        lines.append(f"wrote {args.out}/robust.json, samples.csv, {', '.join(FIGURES)}")
    print("\n".join(lines))
    return 0


def _fmt(x, spec: str) -> str:
    return "n/a" if x is None else format(x, spec)


def _mode(row) -> str:
    """A sample's least-damped mode in words: "zeta Z at F Hz", or a real pole by its s = -zeta 2 pi F (it does not
    oscillate: "zeta -1 at 8.7 Hz" read as an 8.7 Hz oscillation), or by the run's growth rate where the pole lies
    below the damping band (F = 0: a joint creeping at +0.197 1/s)."""
    zeta, hz, growth = row.zeta, row.mode_hz, row.growth_rate_1_s
    if zeta is not None and abs(zeta) > 1.0 - 1e-9:
        s = -zeta * 2 * math.pi * hz if hz else growth
        return f"a real pole at s = {s:+.3g} 1/s (zeta {zeta:+.0f})" if s is not None else f"a real pole (zeta {zeta:+.0f})"
    return f"zeta {_fmt(zeta, '.3f')} at {_fmt(hz, '.3g')} Hz"


def _lines(doc, s) -> list[str]:
    """The study's summary in words: ``doc`` is robust.json (samii.schema.robust.RobustRecord), ``s`` its summary."""
    lo, hi = s.p_unstable_ci95
    nom = doc.nominal_plant
    out = [f"robustness of {doc.controller} ({doc.scenario} test), {doc.n_samples} plants, seed {doc.seed}, {doc.engine}, "
           f"{doc.wall_s:.1f} s",
           "varied: " + "; ".join(v.source for v in doc.varied),
           f"nominal plant: {'stable' if nom.stable else 'UNSTABLE'}, least-damped mode {_mode(nom)}, "
           + (f"base settles {nom.base_settle_s:.2f} s" if nom.base_settle_s is not None else "base settling time n/a"),
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
    for w in doc.summary.worst[:3]:
        params = ", ".join(f"{k} {rel:+.1f} %" if rel is not None else f"{k} {w.params[k]:.4g}" for k, rel in w.params_rel_pct.items())
        state = "UNSTABLE" if not w.stable else "stable"
        out.append(f"  #{w.index}: {state}, {_mode(w)}; {params}")
    return out
