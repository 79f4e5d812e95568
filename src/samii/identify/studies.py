"""The notebook's identification studies, runnable on any frequency response.

* ``phase_weight_sweep``: chapter 9, 3-mode s^4 fits for phase weights 0-0.5.
* ``manual_vs_optimized``: chapter 1, the hand-tuned eq 1.3 against an optimised
  2-mode fit over 1-12 Hz with phase weight 0 (eq 1.4).
* ``s2_vs_s4``: chapter 4, s^2 against s^4 numerator, phase weight 0.1.

The notebook's measured swept-sine data are not available. ``synthetic_rig_frf``
makes stand-in data, stated as such: the eq 9.4 model (the notebook's chosen
fit of the rig, so the best available picture of it) in SI units, plus two
effects the seed models lack, plus the random error of a 3-average swept sine:

1. theta/v lags by a pure delay of 2 ms (valve amplifier and acquisition). The
   notebook's own fits point to it: raising the phase weight from 0 to 0.1
   pulled tau from 294 to 159 rad/s (eq 9.3, 9.4), i.e. the data wanted
   atan(2 pi 20/159) - atan(2 pi 20/294) = 15 deg more lag at 20 Hz than the
   magnitude did, which is what 2 ms gives (360 * 20 Hz * 2 ms = 14 deg);
2. theta/v carries a small antiresonance-resonance pair at base modes 1 and 3
   (the base reacting on the arm; the seed keeps that coupling only at mode 2,
   through the zero wz), the zero 1.5 % (mode 1) and 1 % (mode 3) below the pole;
3. xdd is read through a 2nd-order Butterworth low-pass at 100 Hz (accelerometer
   signal conditioning), 16 deg of lag at 20 Hz.

The amounts are assumptions chosen so the data are not the fitted model itself
(a fit would then be exact at every phase weight and no study would show a
trade-off); the simulator's measured FRF can replace them (every study takes a
FrequencyResponse).

Units: SI, assuming the notebook's theta was in degrees: K1_SI = K1 pi/180,
B_SI = B 180/pi (acceleration unit unchanged). ``to_notebook_units`` converts back.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from samii import notebook as nb
from samii.formats import read_frf_csv
from samii.frequency_response import FrequencyResponse
from samii.identify.cost import FitProblem
from samii.identify.fit import FitResult, fit
from samii.identify.structures import ModelStructure
from samii.identify.synthetic import SweptSineNoise, synthesize

__all__ = [
    "NOTEBOOK_PHASE_WEIGHTS",
    "STANDIN_NOTE",
    "study_data",
    "from_notebook_units",
    "to_notebook_units",
    "synthetic_rig_frf",
    "phase_weight_sweep",
    "ManualVsOptimized",
    "manual_vs_optimized",
    "s2_vs_s4",
]

#: Chapter 9: "Results are shown for phase weights of 0-0.5 by steps of 0.1."
NOTEBOOK_PHASE_WEIGHTS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
#: Unmodelled effects of the stand-in data (module docstring): (mode, relative zero offset)
RIG_DELAY_S = 2e-3
RIG_COUPLING = ((1, 0.015), (3, 0.01))
RIG_ACCEL_FILTER_HZ = 100.0
_DEG = np.pi / 180.0


def from_notebook_units(params: Mapping[str, float]) -> dict[str, float]:
    """Notebook units (theta in degrees, assumed) to SI: K1 * pi/180, B_k * 180/pi."""
    return {k: v * (_DEG if k == "K1" else 1 / _DEG if k.startswith("B") else 1.0) for k, v in params.items()}


def to_notebook_units(params: Mapping[str, float]) -> dict[str, float]:
    """SI to the notebook's units (inverse of ``from_notebook_units``)."""
    return {k: v / (_DEG if k == "K1" else 1 / _DEG if k.startswith("B") else 1.0) for k, v in params.items()}


def synthetic_rig_frf(freq_hz: np.ndarray, *, rng: np.random.Generator | None, noise: SweptSineNoise | None = SweptSineNoise()) -> FrequencyResponse:
    """Stand-in swept-sine data: eq 9.4 in SI + the unmodelled effects of the module docstring + noise."""
    st = ModelStructure.notebook_3mode()
    p = from_notebook_units(nb.EQ9_4)
    f = np.asarray(freq_hz, float)
    s = 2j * np.pi * f
    act = st.response(p, f, "act") * np.exp(-s * RIG_DELAY_S)
    for k, delta in RIG_COUPLING:
        wk, zk = (p["w1"], p["z1"]) if k == 1 else (p[f"w{k}"], p[f"z{k}"])
        wa = wk * (1 - delta)
        act = act * (s**2 + 2 * zk * wa * s + wa**2) / (s**2 + 2 * zk * wk * s + wk**2) * (wk / wa) ** 2
    wf = 2 * np.pi * RIG_ACCEL_FILTER_HZ
    lowpass = wf**2 / (s**2 + np.sqrt(2) * wf * s + wf**2)
    base = st.response(p, f, "base") * lowpass
    meta = {
        "source": "synthetic stand-in for the notebook's swept-sine data (not measured)",
        "model": "eq 9.4 in SI (theta assumed in degrees in the notebook)",
        "unmodelled": f"theta/v delay {RIG_DELAY_S * 1e3:g} ms and pole-zero pairs at base modes 1, 3 (zeros {RIG_COUPLING[0][1]:.1%}, {RIG_COUPLING[1][1]:.1%} below); accelerometer 2nd-order Butterworth {RIG_ACCEL_FILTER_HZ:g} Hz",
    }
    return synthesize(f, {"act": act, "base": base, "total": act * base}, noise=noise, rng=rng, metadata=meta)


#: Printed on every figure made from the stand-in data.
STANDIN_NOTE = (
    "SYNTHETIC DATA, not measured: stand-in for the notebook's 3-average swept sine = eq 9.4 (SI, theta assumed in deg) "
    "+ 2 ms delay and small pole-zero pairs at base modes 1, 3 in theta/v + 100 Hz accelerometer filter + 3-average noise "
    "(samii.identify.studies.synthetic_rig_frf)"
)
STANDIN_SEED = 2003
STANDIN_FREQ_HZ = np.geomspace(0.1, 40.0, 400)  # chapter 9: "frequency content from 0.1-40Hz"


def study_data(
    path=None, *, freq_hz: np.ndarray = STANDIN_FREQ_HZ, seed: int = STANDIN_SEED
) -> tuple[FrequencyResponse, FrequencyResponse | None, str]:
    """Data for a study: an FRF CSV if ``path`` is given, else the stand-in.

    Returns (data, noise-free version or None, note for the figures).
    """
    if path is not None:
        return read_frf_csv(path), None, f"data: {path}"
    data = synthetic_rig_frf(freq_hz, rng=np.random.default_rng(seed))
    return data, synthetic_rig_frf(freq_hz, rng=None, noise=None), STANDIN_NOTE


def phase_weight_sweep(
    data: FrequencyResponse,
    structure: ModelStructure | None = None,
    weights: Sequence[float] = NOTEBOOK_PHASE_WEIGHTS,
    *,
    band_hz: tuple[float, float] | None = None,
    start="both",
    rng: np.random.Generator | None = None,
) -> tuple[FitResult, ...]:
    """One fit per phase weight (chapter 9), each from the same starts."""
    structure = structure or ModelStructure.notebook_3mode()
    rng = rng if rng is not None else np.random.default_rng(0)
    return tuple(fit(data, structure, phase_weight=float(w), band_hz=band_hz, start=start, rng=rng) for w in weights)


@dataclass(frozen=True, eq=False)
class ManualVsOptimized:
    """Chapter 1 on given data: costs of the hand fit (eq 1.3), the notebook's optimum (eq 1.4) and samii's."""

    manual: Mapping[str, float]
    notebook_optimized: Mapping[str, float]
    samii: FitResult
    cost_manual: float
    cost_notebook_optimized: float


def manual_vs_optimized(
    data: FrequencyResponse, *, band_hz: tuple[float, float] = nb.EQ1_4_FIT_RANGE_HZ, si_units: bool = True, rng: np.random.Generator | None = None
) -> ManualVsOptimized:
    """Fit the 2-mode s^4 model (eq 1.1/1.2) over ``band_hz`` with phase weight 0, starting from eq 1.3.

    ``si_units``: the data are SI, so the notebook's sets are converted with
    ``from_notebook_units`` before their cost is taken; the fit starts from eq 1.3's
    frequencies and dampings with gains read off the data.
    """
    st = ModelStructure.notebook_2mode()
    conv = from_notebook_units if si_units else dict
    manual, opt = conv(nb.EQ1_3_MANUAL), conv(nb.EQ1_4_OPTIMIZED)
    problem = FitProblem(data, st, phase_weight=0.0, band_hz=band_hz)
    res = fit(data, st, phase_weight=0.0, band_hz=band_hz, start=manual, rng=rng)
    return ManualVsOptimized(manual, opt, res, problem.cost(st.vector(manual)), problem.cost(st.vector(opt)))


def s2_vs_s4(
    data: FrequencyResponse, *, phase_weight: float = 0.1, band_hz: tuple[float, float] | None = None, rng: np.random.Generator | None = None
) -> dict[str, FitResult]:
    """3-mode fits with s^2 and with s^4 numerator (chapter 4), same data, weight and starts."""
    return {num: fit(data, ModelStructure.notebook_3mode(num), phase_weight=phase_weight, band_hz=band_hz, rng=rng) for num in ("s2", "s4")}
