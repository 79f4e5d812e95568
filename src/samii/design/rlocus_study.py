"""The notebook's mass-damping root-locus study (chapters 2-3) as one library call, ``samii design rlocus``'s:
:func:`run_rlocus_study` summarises every loop variant on every model (:func:`samii.design.rootlocus.default_models`,
:data:`samii.design.rootlocus.NOTEBOOK_VARIANTS`) and, with ``out``, writes ``summary.json``, ``summary.md`` and one
figure per model and variant, all or nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from samii.json_output import dumps
from samii.outputs import OutputFolder
from samii.progress import SILENT, Progress

if TYPE_CHECKING:
    from samii.design.rootlocus import MassDampingLoop, RootLocusSummary

__all__ = ["RlocusStudy", "run_rlocus_study", "rlocus_outputs", "PLOT_MAX_GAINS"]

#: Gains per sign drawn in each root-locus figure (at most ``n_gains``: beyond it the lines get no smoother, the
#: drawing slower).
PLOT_MAX_GAINS = 1500


@dataclass(frozen=True)
class RlocusStudy:
    loops: tuple[MassDampingLoop, ...]
    summaries: tuple[RootLocusSummary, ...]
    table: str  #: summary.md: the summaries as a markdown table
    written: tuple[Path, ...] = ()  #: the files written (with ``out``)

    def rows(self) -> list[dict]:
        """summary.json's rows."""
        return [s.as_dict() for s in self.summaries]


def _plan():
    # (imported here, as every heavy module of this one: the command's parser reads PLOT_MAX_GAINS, and python-control,
    # which samii.design.rootlocus imports, is not needed to build it)
    from samii.design import rootlocus as rl  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    return [(label, p, num, v) for label, (p, num) in rl.default_models().items() for v in rl.NOTEBOOK_VARIANTS]


def _figure_name(label: str, variant) -> str:
    return f"rlocus_{label}_{variant.name}.png"


def rlocus_outputs(plots: bool = True) -> list[str]:
    """The files the study writes into its folder (known before any work)."""
    return ["summary.json", "summary.md", *([_figure_name(label, v) for label, _, _, v in _plan()] if plots else [])]


def run_rlocus_study(*, n_gains: int = 3000, out=None, overwrite: bool = False, plots: bool = True, progress: Progress | None = None) -> RlocusStudy:
    """The study, tracking each locus on ``n_gains`` gains per sign; with ``out`` (a folder path, or a
    samii.outputs.OutputFolder made for :func:`rlocus_outputs` and not yet entered) its tables and, with ``plots``, its
    figures written there. ``progress`` hears a unit per loop summarised and per figure drawn."""
    from samii.design import rootlocus as rl  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    progress = progress or SILENT
    folder = out if isinstance(out, OutputFolder) or out is None else OutputFolder(out, rlocus_outputs(plots), overwrite=overwrite)
    plots = plots and folder is not None
    plan = _plan()
    progress.expect(len(plan) * (2 if plots else 1))
    loops, summaries = [], []
    for label, p, num, v in plan:
        progress.stage(f"{label} {v.name}")
        loop = rl.mass_damping_loop(p, numerator=num, variant=v, model=label)
        loops.append(loop)
        summaries.append(rl.summarize(loop, n_gains=n_gains))
        progress.advance()
    study = RlocusStudy(tuple(loops), tuple(summaries), rl.summary_table(summaries))
    if folder is not None:
        with folder:
            folder.path("summary.json").write_text(dumps(study.rows(), indent=1) + "\n")
            folder.path("summary.md").write_text(study.table)
            if plots:
                from samii.viz.rootlocus_plot import plot_variant  # (lazy: this module is imported at samii's start-up, that one is not needed there)

                for (label, _, _, v), lp, s in zip(plan, loops, summaries):
                    progress.stage(f"plot {lp.model} {lp.variant.name}")
                    plot_variant(lp, s, path=folder.path(_figure_name(label, v)), n_gains=min(n_gains, PLOT_MAX_GAINS))
                    progress.advance()
        study = replace(study, written=tuple(folder.written))
    return study
