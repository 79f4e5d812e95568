"""The model a diagnosis tests: the notebook's structure refitted to each file, or a saved fit held fixed.

``notebook`` (the default): eq 9.1/9.2's structure (3 modes, s^4, mode 2 tied to
the actuator's zero pair), its 13 parameters refitted to every file with the
effects; the start is the better of samii's fit and eq 9.4 itself
(:func:`samii.diagnose.model.start_params`). Which fitted modes are "the
model's" is decided by eq 9.4's modes (:func:`samii.diagnose.model.relabel_modes`).

A saved fit (``fit.json`` as ``samii fit --out`` writes it): its structure and
parameters, held fixed; only the effects are fitted. Then a gain error of the
accelerometer is testable (a refitted baseline's gains B_k absorb it).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from samii.diagnose.model import Baseline, Dataset, level_ratio, notebook_reference, start_params
from samii.errors import InputError
from samii.frequency_response import CHANNEL_NAMES
from samii.identify.structures import ModelStructure
from samii.measure.measured import Measured
from samii.schema import schema_version

__all__ = ["SavedFit", "notebook_baseline", "saved_fit_baseline", "read_fit_json", "check_level", "LEVEL_MISMATCH"]


def notebook_baseline(measured: Sequence[Measured]) -> Baseline:
    st = ModelStructure.notebook_3mode()
    return Baseline(
        structure=st,
        params=tuple(start_params(m, st) for m in measured),
        reference=notebook_reference(),
        label="notebook: eq 9.1/9.2's structure refitted to each file (started from eq 9.4 or samii's fit, the better)",
    )


@dataclass(frozen=True)
class SavedFit:
    """A fit saved by ``samii fit --out``: its structure, parameters, and what it says is wrong with itself."""

    path: str
    structure: ModelStructure
    params: dict
    concerns: tuple[str, ...] = ()


def read_fit_json(path, *, name: str | None = None) -> SavedFit:
    """The saved fit at ``path`` (``samii fit --out DIR`` writes DIR/fit.json), named ``name`` (default: the path as
    given) in its messages and label; InputError naming the file and field."""
    real = Path(path)
    path = real if name is None else Path(name)
    try:
        text = real.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file; expected a saved fit (fit.json as samii fit --out writes it)") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not JSON ({exc.msg} at line {exc.lineno}); expected a saved fit (fit.json as samii fit --out writes it)") from None
    if isinstance(d, list) and len(d) == 1:
        d = d[0]
    if not isinstance(d, dict):
        raise InputError(f"{path}: expected one fit (a JSON object with 'structure' and 'params'), got {type(d).__name__}")
    schema_version(d, path)
    for key in ("structure", "params"):
        if not isinstance(d.get(key), dict):
            raise InputError(f"{path}: field '{key}' missing or not an object; expected a saved fit (fit.json as samii fit --out writes it)")
    s = d["structure"]
    try:
        st = ModelStructure(
            n_modes=int(s.get("n_modes", 3)), numerator=s.get("numerator", "s4"), tie_mode2=s.get("tie_mode2"), w2_factors=s.get("w2_factors")
        )
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: field 'structure': {exc}") from None
    params = {}
    for name in st.param_names:
        v = d["params"].get(name)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v):
            raise InputError(f"{path}: field 'params.{name}': expected a finite number, got {v!r} (a parameter not fitted cannot be a baseline)")
        params[name] = float(v)
    try:
        st.vector(params)
    except ValueError as exc:
        raise InputError(f"{path}: field 'params': {exc}") from None
    concerns = []
    if d.get("sound") is False:
        said = "; ".join(str(c) for c in d.get("concerns") or []) or "no reason given"
        concerns.append(f"{path} says it is not a sound fit ({said}): effects found against it may be its own errors")
    elif d.get("undetermined"):
        named = ", ".join(str(n) for n in d["undetermined"])
        concerns.append(f"{path} says its data do not determine {named}: effects found where those act may be the fit's own errors")
    return SavedFit(str(path), st, params, tuple(concerns))


def saved_fit_baseline(saved: SavedFit, datasets: Sequence[Dataset]) -> Baseline:
    """A saved fit as fixed responses on every dataset's usable points."""
    st, params = saved.structure, saved.params
    fixed = []
    for ds in datasets:
        per = {}
        for ch in ds.data:
            f = ds.freq_hz[ds.keep[ch]]
            need = {"act": ("act",), "base": ("base",), "total": ("act", "base")}[ch]
            per[ch] = {c: st.response(params, f, c) for c in need}
        fixed.append(per)
    return Baseline(
        structure=st, params=tuple(params for _ in datasets), fixed=tuple(fixed), reference=params, label=f"saved fit {saved.path} (held fixed)"
    )


#: A saved fit whose response is this factor or more from the data's (the median over a channel's usable points, either
#: way: 20 dB) is of another rig, or of the same one in other units: no effect of the library is a gain on theta/v.
LEVEL_MISMATCH = 10.0


def check_level(saved: SavedFit, datasets: Sequence[Dataset], baseline: Baseline) -> None:
    """Refuse data whose level a saved fit misses by LEVEL_MISMATCH or more, naming the channel and the factor: a fit of
    theta in mrad held against data in rad was "diagnosed" as a pole at 0.01 Hz, a leak of -10 1/s and an accelerometer
    gain of 100, each on its bound, with 60 dB of error left."""

    for ds, per in zip(datasets, baseline.fixed):
        for ch, resp in per.items():
            g = level_ratio(ds.data[ch], resp["act"] * resp["base"] if ch == "total" else resp[ch])
            if g is not None and not 1.0 / LEVEL_MISMATCH < g < LEVEL_MISMATCH:
                raise InputError(
                    f"{ds.source}: the data's {CHANNEL_NAMES[ch]} is {g:.3g} x the saved fit {saved.path}'s "
                    f"({20 * np.log10(g):+.0f} dB, the median over its usable points): not one rig in one set of units "
                    "(theta in rad, xdd in m/s², v in V: DATA_FORMATS.md); check the units, or fit these data (samii fit)"
                )
