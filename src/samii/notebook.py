"""Figures and transfer-function models of the SAMII research notebook.

This is the project's own copy of every published figure that code or tests
compare against. Equation numbers are the notebook's ("SAMII research
notebook, Fall 2003", chapters 1-11). Frequencies are in rad/s unless a name
says otherwise.

The notebook does not state the units of theta and of the base acceleration.
Set against the simulator's linearisation (SI), its coefficients say theta in
degrees and the acceleration in ft/s² (eq 9.4's B_k over the simulator's:
3.85, 3.32, 2.85 per m/s², ft/s² = 3.281; samii.closedloop.controllers).
Gains (K1, B1...) are in those units; frequencies, damping ratios, loop gains and the signs and
ratios of the B coefficients are unit-free and are what the simulator is
calibrated to.

Models
------
Actuator, eq 1.1 / 9.1::

    theta/v = K1 wp^2 (s^2 + 2 zz wz s + wz^2) tau / (s wz^2 (s^2 + 2 zp wp s + wp^2) (s + tau))

Flexible base, 2 modes, eq 1.2 as printed (note the w^2 factors)::

    xdd/theta = B1 w1^2 s^4/(s^2 + 2 z1 w1 s + w1^2) + B2 wz^2 s^4/(s^2 + 2 zz wz s + wz^2)

Flexible base, 3 modes, eq 9.2 (w2 = wz, z2 = zz; no w^2 factors)::

    xdd/theta = s^4 (B1/(s^2+2 z1 w1 s+w1^2) + B2/(s^2+2 z2 w2 s+w2^2) + B3/(s^2+2 z3 w3 s+w3^2))
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # python-control takes ~1 s to import; the functions import it when called
    import control

__all__ = [
    "NAMES_2MODE",
    "NAMES_3MODE",
    "EQ1_3_MANUAL",
    "EQ1_4_OPTIMIZED",
    "EQ9_FITS",
    "EQ9_4",
    "EQ8_1",
    "EQ8_2",
    "EQ8_3",
    "EQ8_3_ZETA",
    "EQ10_1",
    "EQ10_2",
    "EQ10_3_HZ",
    "EQ10_ZETA",
    "EQ10_8",
    "EQ10_9_NUM",
    "EQ10_9_DEN",
    "EQ10_GAIN",
    "BASE_MODES_HZ",
    "BASE_ZETAS",
    "TMM",
    "actuator_tf",
    "base_tf",
    "total_tf",
    "second_order",
]


def _params(names: tuple[str, ...], values: list[float]) -> Mapping[str, float]:
    assert len(names) == len(values)
    return MappingProxyType(dict(zip(names, values)))


NAMES_2MODE = ("K1", "wp", "zp", "wz", "zz", "tau", "w1", "z1", "B1", "B2")
NAMES_3MODE = ("K1", "wp", "zp", "wz", "zz", "tau", "w1", "z1", "w3", "z3", "B1", "B2", "B3")

#: Manual (trial-and-error) 2-mode fit, eq 1.3.
EQ1_3_MANUAL = _params(
    NAMES_2MODE,
    [20, 51.5221, 0.11, 62.8319, 0.06, 188.496, 10.9956, 0.05, -2.10526e-05, 3.33333e-07],
)
#: Optimised 2-mode s^4 fit over 1-12 Hz, magnitude only (phase weight 0), eq 1.4.
EQ1_4_OPTIMIZED = _params(
    NAMES_2MODE,
    [22.0616, 52.3786, 0.119069, 61.5192, 0.0767268, 188.51, 10.5585, 0.0413066, -1.71e-05, 3.786e-07],
)
EQ1_4_FIT_RANGE_HZ = (1.0, 12.0)

#: 3-mode s^4 fits, 0.1-40 Hz swept sine, by phase weight (eq 9.3 ... 9.12).
EQ9_FITS: Mapping[float, Mapping[str, float]] = MappingProxyType(
    {
        0.0: _params(
            NAMES_3MODE,
            [25.4406, 54.6046, 0.163755, 62.1284, 0.0677148, 294.127, 10.8724, 0.0281329, 156.561, 0.0395, -0.00153797, 0.00159421, 0.000276836],
        ),
        0.1: _params(
            NAMES_3MODE,
            [27.8962, 55.2835, 0.139813, 62.0634, 0.0486851, 158.869, 10.8862, 0.0298125, 156.814, 0.0336399, -0.00146074, 0.00156505, 0.000280877],
        ),
        0.2: _params(
            NAMES_3MODE,
            [28.4998, 55.2627, 0.113717, 62.0611, 0.035692, 143.207, 10.8871, 0.0382545, 157.501, 0.0258995, -0.00140709, 0.00153227, 0.000291275],
        ),
        0.3: _params(
            NAMES_3MODE,
            [28.6391, 55.2783, 0.103414, 62.0692, 0.0303846, 139.245, 10.8884, 0.047849, 157.829, 0.0219657, -0.00135041, 0.0014989, 0.000303583],
        ),
        0.4: _params(
            NAMES_3MODE,
            [28.6947, 55.2662, 0.0992186, 62.0713, 0.0284038, 137.869, 10.8883, 0.0533673, 157.982, 0.0199391, -0.0012746, 0.00145774, 0.000318233],
        ),
        0.5: _params(
            NAMES_3MODE,
            [28.8249, 54.3453, 0.104566, 61.8723, 0.0406231, 143.094, 7.08669, 0.817514, 158.322, 0.0325469, -0.00218181, 0.00199658, 0.000247715],
        ),
    }
)
#: The fit the notebook chose for control design (phase weight 0.1), eq 9.4.
EQ9_4 = EQ9_FITS[0.1]

# Chapter 8, computed by the notebook from eq 1.4 (2-mode model).
#: Open-loop poles, eq 8.1.
EQ8_1 = (0.0, -188.5, -6.237 + 52.01j, -6.237 - 52.01j, -0.4361 + 10.55j, -0.4361 - 10.55j)
#: Poles with unity theta feedback, eq 8.2.
EQ8_2 = (-169.8, -2.986 + 51.56j, -2.986 - 51.56j, -25.19, -0.4361 + 10.55j, -0.4361 - 10.55j)
#: Desired poles (complex poles of eq 8.2 moved to zeta 1/sqrt(2) at the same magnitude), eq 8.3.
EQ8_3 = (-169.8, -36.52 - 36.52j, -36.52 + 36.52j, -25.19, -7.466 - 7.466j, -7.466 + 7.466j)
#: Damping of eq 8.3. Not printed by the notebook (chapter 8 says only "a specified
#: damping ratio"); derived: eq 8.3 prints equal real and imaginary parts, which
#: only zeta = 1/sqrt(2) gives, and it reproduces every printed digit, while 0.707
#: gives -36.5115 -+ 36.5226j and -7.4649 -+ 7.4671j (printed -36.52, -7.466).
EQ8_3_ZETA = 1.0 / np.sqrt(2.0)

# Chapter 10, computed by the notebook from eq 9.4 (3-mode model).
#: Inner-loop (unity theta feedback) pair to cancel, eq 10.1.
EQ10_1 = (-4.214 - 52.84j, -4.214 + 52.84j)
#: Base modes 1 and 3 to cancel, eq 10.2.
EQ10_2 = (-0.3245 - 10.88j, -0.3245 + 10.88j, -5.275 - 156.7j, -5.275 + 156.7j)
#: Desired compensator pole frequencies [Hz] and damping ratios, eq 10.3-10.6.
EQ10_3_HZ = (3.0, 8.0, 10.0)
EQ10_ZETA = (1.0, 1.0, 1.0)
#: Desired compensator poles, eq 10.8.
EQ10_8 = (-18.85, -18.85, -50.27, -50.27, -62.83, -62.83)
#: Compensator numerator and denominator, highest power first, eq 10.9.
EQ10_9_NUM = (1.0, 19.63, 2.762e4, 2.57e5, 7.251e7, 7.293e7, 8.189e9)
EQ10_9_DEN = (1.0, 263.9, 2.799e4, 1.515e6, 4.37e7, 6.299e8, 3.544e9)
#: Compensator gain chosen on the root locus for closed-loop damping ~0.7 (chapter 10).
EQ10_GAIN = 0.0666

#: Base modes of eq 9.4 in Hz (w1, wz, w3 / 2 pi) and their damping ratios: the
#: simulator's calibration targets (DESIGN.md, issue 2).
BASE_MODES_HZ = (1.73, 9.88, 24.96)
BASE_ZETAS = (0.030, 0.049, 0.034)

#: Public transfer-matrix model values of SAMII (the notebook author's TMM code):
#: beam and the three lumped links. SI units.
TMM: Mapping[str, Mapping[str, float]] = MappingProxyType(
    {
        "beam": MappingProxyType({"length_m": 4.6482, "EI_Nm2": 339134.5, "mass_per_length_kg_m": 5.7281}),
        "link_l0": MappingProxyType({"length_m": 0.3302, "mass_kg": 16.032, "cg_m": 0.0902, "I_cg_kgm2": 0.19}),
        "link_l1": MappingProxyType({"length_m": 0.1969, "mass_kg": 5.0264, "cg_m": 0.06145, "I_cg_kgm2": 0.027}),
        "link_l2": MappingProxyType({"length_m": 0.4001, "mass_kg": 5.5799, "cg_m": 0.1077, "I_cg_kgm2": 0.0728}),
    }
)


def second_order(wn: float, zeta: float) -> control.TransferFunction:
    """The monic quadratic ``s^2 + 2 zeta wn s + wn^2`` as a transfer function numerator/1."""
    import control  # (lazy: python-control takes ~1 s to import: only when a transfer function is built)

    return control.tf([1.0, 2.0 * zeta * wn, wn**2], [1.0])


def actuator_tf(p: Mapping[str, float]) -> control.TransferFunction:
    """theta/v of eq 9.1 for parameters ``p`` (keys K1, wp, zp, wz, zz, tau)."""
    import control  # (lazy: imports control, only when called)

    K1, wp, zp, wz, zz, tau = (p[k] for k in ("K1", "wp", "zp", "wz", "zz", "tau"))
    num = K1 * wp**2 * tau * np.array([1.0, 2.0 * zz * wz, wz**2])
    den = wz**2 * np.polymul([1.0, 2.0 * zp * wp, wp**2, 0.0], [1.0, tau])
    return control.tf(num, den)


def _mode_names(p: Mapping[str, float]) -> list[int]:
    """Mode indices present in ``p``: 1, 2, ... as long as a gain B_k is given (mode 2 is tied to wz/zz unless w2 is given)."""
    modes = []
    while f"B{len(modes) + 1}" in p:
        modes.append(len(modes) + 1)
    return modes


def base_tf(p: Mapping[str, float], *, numerator: str = "s4", w2_factors: bool | None = None) -> control.TransferFunction:
    """xdd/theta of eq 9.2 (3 or more modes) or eq 1.2 (2 modes).

    Parameters
    ----------
    p : mapping
        Notebook names. Mode 2 uses ``w2``/``z2`` if present, else ``wz``/``zz`` (the tie of eq 9.2).
    numerator : {"s4", "s2"}
        Power of s in front of the modal sum (chapter 4 compares both).
    w2_factors : bool, optional
        Multiply each B_i by w_i^2 as eq 1.2 prints it. Default: True for the
        2-mode model (eq 1.2), False for 3 or more modes (eq 9.2).
    """
    import control  # (lazy: imports control, only when called)

    modes = _mode_names(p)
    if w2_factors is None:
        w2_factors = len(modes) == 2
    power = {"s4": 4, "s2": 2}[numerator]
    sn = control.tf([1.0] + [0.0] * power, [1.0])
    total = control.tf([0.0], [1.0])
    for k in modes:
        wk = p.get(f"w{k}", p["wz"] if k == 2 else None)
        zk = p.get(f"z{k}", p["zz"] if k == 2 else None)
        gain = p[f"B{k}"] * (wk**2 if w2_factors else 1.0)
        total = total + control.tf([gain], [1.0, 2.0 * zk * wk, wk**2])
    return sn * total


def total_tf(p: Mapping[str, float], **kwargs) -> control.TransferFunction:
    """xdd/v = (theta/v)(xdd/theta)."""
    return actuator_tf(p) * base_tf(p, **kwargs)
