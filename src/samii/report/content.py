"""What a main job's output folder holds, as the report reads it (no plotting, no HTML).

The folder is read by :meth:`samii.pipeline.Run.load` (its files checked, ``summary.json`` typed); this module adds
what the page needs beside it: the figures the stages drew (referenced by path, embedded as they are), the recordings'
sizes, what a folder lacks (:func:`gaps`), the fit's parameters beside eq 9.4 (:func:`parameter_rows`), and a log of
the fields the page reads from the stages' own documents (:func:`traced`), which names the field a damaged value
most likely sits in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from samii.closedloop.controllers import FT_PER_M
from samii.run_summary import RECORDINGS  # (linked by the page, not embedded: tens of MB)

if TYPE_CHECKING:  # (the type only: samii.pipeline writes its report through this package)
    from samii.pipeline import Run

__all__ = [
    "stage_figures",
    "recordings",
    "traces",
    "gaps",
    "ParamRow",
    "parameter_rows",
    "STAGE_FIGURES",
    "RECORDINGS",
    "FieldLog",
    "traced",
]

#: Figures a stage drew, embedded as they are: key -> path in the folder.
STAGE_FIGURES = {
    "bode_fit": "fit/bode_fit.png",
    "measure_bode": "measure/bode.png",
    "diagnose_bode": "diagnose/bode.png",
    "diagnose_residuals": "diagnose/residuals.png",
    "diagnose_harmonics": "diagnose/harmonics.png",
}


def stage_figures(run: Run) -> dict[str, Path]:
    """The STAGE_FIGURES in ``run``'s folder that are PNG images: key -> path."""
    return {k: run.path / rel for k, rel in STAGE_FIGURES.items() if _is_png(run.path / rel)}


def recordings(run: Run) -> dict[str, int]:
    """The RECORDINGS in ``run``'s folder: name -> size in bytes."""
    return {name: (run.path / name).stat().st_size for name in RECORDINGS if (run.path / name).is_file()}


def traces(run: Run) -> dict:
    """The closed-loop runs' signals (samii.timeseries.TimeSeries) by name; a run that diverged at once has none."""
    return {name: cl.trace for name, cl in run.closed_loop.items() if cl.trace is not None}


class FieldLog(list):
    """The leaves of a run folder's JSON files read, in order: (file and field, value). A value of the wrong kind fails
    where it is used, not where it is read; the last field read that holds no number is where to look."""

    def suspect(self, error: str = "") -> str | None:
        """The field a failure with message ``error`` most likely comes from: the last read that holds no number (a
        string, null; a list or an object where the message names one and nothing inside it was read after)."""
        containers = any(word in error for word in ("list", "dict", "_Traced"))
        if "NoneType" in error or "'str'" in error:  # the message names the kind: the last field of that kind first
            kind = type(None) if "NoneType" in error else str
            for where, value in reversed(self):
                if type(value) is kind:
                    return f"{where} (holds {_shown(value)})"
        inner: list[str] = []  # fields read after the one looked at
        for where, value in reversed(self):
            if value is _MISSING:
                return f"{where} (missing)"
            if value is None or isinstance(value, str):  # (a bool formats as the number it is)
                return f"{where} (holds {_shown(value)})"
            if containers and isinstance(value, (dict, list)) and not any(w.startswith((where + ".", where + "[")) for w in inner):
                return f"{where} (holds {'a list' if isinstance(value, list) else 'an object'})"
            inner.append(where)
        return None


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:40] + f"... ({len(text)} characters)"


_MISSING = object()


class _TracedDict(dict):
    """A JSON object whose reads are logged in a :class:`FieldLog` (``where``: the file and the path to it)."""

    def __init__(self, data: dict, where: str, log: FieldLog):
        super().__init__(data)
        self._where, self._log = where, log

    def _path(self, key) -> str:
        return f"{self._where}{'' if self._where.endswith(' ') else '.'}{key}"  # ("summary.json: " begins a file's paths)

    def _wrap(self, key, value):
        return _traced_value(value, self._path(key), self._log)

    def __getitem__(self, key):
        try:
            return self._wrap(key, super().__getitem__(key))
        except KeyError:
            self._log.append((self._path(key), _MISSING))
            raise

    def get(self, key, default=None):
        return self[key] if key in self else default

    def items(self):
        return [(k, self._wrap(k, v)) for k, v in super().items()]

    def values(self):
        return [v for _, v in self.items()]


class _TracedList(list):
    def __init__(self, data: list, where: str, log: FieldLog):
        super().__init__(data)
        self._where, self._log = where, log

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        return _traced_value(super().__getitem__(i), f"{self._where}[{i if i >= 0 else len(self) + i}]", self._log)

    def __iter__(self):
        return (self[i] for i in range(len(self)))


def _traced_value(value, where: str, log: FieldLog):
    log.append((where, value))
    if isinstance(value, dict):
        return _TracedDict(value, where, log)
    if isinstance(value, list):
        return _TracedList(value, where, log)
    return value


def traced(run: Run) -> tuple[Run, FieldLog]:
    """``run`` with the reads of fit/fit.json logged (the report names the field a failure most likely comes from; the
    other documents are typed, their fields checked when the folder is read, samii.schema)."""
    log = FieldLog()
    return replace(run, fit_record=_TracedDict(run.fit_record, "fit/fit.json: ", log)), log


def _kind(value) -> str:
    return {list: "a list", str: "a string", type(None): "null", bool: "a boolean"}.get(type(value), type(value).__name__)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _is_png(path: Path) -> bool:
    """A file that begins as every PNG does (a damaged one, embedded, shows as a broken image)."""
    try:
        with open(path, "rb") as f:
            return f.read(len(_PNG_SIGNATURE)) == _PNG_SIGNATURE
    except OSError:
        return False


#: Numbers the main job always writes (summary.json's damping design; a found effect's fitted parameters): null there is
#: damage, shown as "–" without a word before. (The roll-off may be absent: a design without one.)
_DESIGN_NUMBERS = ("gain_v_per_m_s2", "gain_limit_v_per_m_s2", "gain_margin_db", "filter_hz")


def gaps(run: Run) -> list[str]:
    """What a main job writes and ``run`` lacks (figures, fitted parameters), one phrase each. A closed-loop run missing
    from summary.json is refused instead (the summary's lines need each); the recordings are not counted (tens of MB a
    user may remove to archive a folder; the page's Recordings section says what is there)."""
    present = stage_figures(run)
    out = [
        f"{rel} is {'not a PNG image (damaged)' if (run.path / rel).exists() else 'missing'}"
        for key, rel in STAGE_FIGURES.items()
        if key not in present
    ]
    design = run.summary.damping_design
    out += [f"summary.json: damping_design.{k} holds null (or is missing)" for k in _DESIGN_NUMBERS if getattr(design, k) is None]
    for i, e in enumerate(run.diagnosis.effects):
        out += [f"diagnose/diagnosis.json: effects[{i}].params.{k} holds null" for k, v in e.params.items() if v is None]
    params = run.fit_record.get("params")
    if not isinstance(params, dict):
        out.append(f"fit/fit.json: params holds {_kind(params) if 'params' in run.fit_record else 'nothing (missing)'}, not the fitted parameters")
    else:
        for name in _PARAMS:
            if name not in params:
                out.append(f"fit/fit.json: params.{name} is missing")
            elif params[name] is None:
                out.append(f"fit/fit.json: params.{name} holds null")
    return out


@dataclass(frozen=True)
class ParamRow:
    """One fitted parameter beside eq 9.4's, in the unit shown."""

    name: str
    meaning: str
    unit: str
    value: float | None  #: None: the fit's file holds no value (gaps says so)
    stderr: float | None
    notebook: float | None
    #: The fit's 95 % profile interval in the unit shown (``samii.identify.profile``), a side the data
    #: do not bound None; None for a parameter not profiled (or a fit.json written before profiles).
    interval_95: tuple[float | None, float | None] | None = None

    @property
    def rel_stderr_pct(self) -> float | None:
        return None if self.stderr is None or not self.value else 100.0 * abs(self.stderr / self.value)

    @property
    def diff_pct(self) -> float | None:
        return None if self.notebook in (None, 0) or self.value is None else 100.0 * (self.value - self.notebook) / abs(self.notebook)

    @property
    def sigmas(self) -> float | None:
        """How many standard errors the fit lies from eq 9.4."""
        if self.notebook is None or not self.stderr or self.value is None:
            return None
        return abs(self.value - self.notebook) / self.stderr


#: name -> (meaning, unit shown, factor from the fit's SI value to the unit shown, factor from the notebook's value to it).
#: The notebook's gains read theta in degrees and the acceleration in ft/s² (experiments/closed_loop/README.md):
#: K1 [deg/s/V] * pi/180 = rad/s/V; B_k [(ft/s²)/deg] * 0.3048 * 180/pi = (m/s²)/rad.
_PARAMS = {
    "K1": ("actuator gain", "rad/(s V)", 1.0, math.pi / 180.0),
    "wp": ("actuator pole pair", "Hz", 1 / (2 * math.pi), 1 / (2 * math.pi)),
    "zp": ("actuator pole pair damping", "1", 1.0, 1.0),
    "wz": ("actuator zero pair = base mode 2", "Hz", 1 / (2 * math.pi), 1 / (2 * math.pi)),
    "zz": ("its damping", "1", 1.0, 1.0),
    "tau": ("actuator real pole", "1/s", 1.0, 1.0),
    "w1": ("base mode 1", "Hz", 1 / (2 * math.pi), 1 / (2 * math.pi)),
    "z1": ("base mode 1 damping", "1", 1.0, 1.0),
    "w3": ("base mode 3", "Hz", 1 / (2 * math.pi), 1 / (2 * math.pi)),
    "z3": ("base mode 3 damping", "1", 1.0, 1.0),
    "B1": ("base mode 1 coefficient", "(m/s²)/rad", 1.0, 180.0 / (math.pi * FT_PER_M)),
    "B2": ("base mode 2 coefficient", "(m/s²)/rad", 1.0, 180.0 / (math.pi * FT_PER_M)),
    "B3": ("base mode 3 coefficient", "(m/s²)/rad", 1.0, 180.0 / (math.pi * FT_PER_M)),
}


def parameter_rows(fit: dict, notebook: dict) -> list[ParamRow]:
    """The fit's parameters with standard errors beside eq 9.4's, in Hz, 1/s and SI gains."""
    rows = []
    params, stderr = fit.get("params", {}), fit.get("stderr", {}) or {}
    profiles = fit.get("profile_intervals") or {}
    for name, (meaning, unit, to_shown, nb_to_shown) in _PARAMS.items():
        nb = notebook.get(name)
        if params.get(name) is None:  # shown as a row without a value (gaps names it), not left out
            rows.append(ParamRow(name, meaning, unit, None, None, None if nb is None else float(nb) * nb_to_shown))
            continue
        se = stderr.get(name)
        iv = (profiles.get(name) or {}).get("95%")
        interval = (
            None
            if not iv
            else (float(iv["low"]) * to_shown if iv.get("bounded_low") else None, float(iv["high"]) * to_shown if iv.get("bounded_high") else None)
        )
        rows.append(ParamRow(name, meaning, unit, float(params[name]) * to_shown,
                             None if se is None or not math.isfinite(se) else abs(float(se) * to_shown),
                             None if nb is None else float(nb) * nb_to_shown, interval))  # fmt: skip
    return rows
