"""Issue 8's fidelity targets: the simulator's swept-sine data, fitted by the notebook's own
procedure, against the notebook's eq 9.4.

The rig was measured with a swept sine and fitted with eq 9.1/9.2 (3 modes, s^4 numerator,
phase weight 0.1); eq 9.4 is what came out. The simulator behaves like the rig, as seen
through its data, when its own swept-sine data fitted the same way give eq 9.4 back. Only
unit-free quantities are compared (frequencies, damping ratios, loop gain, signs and ratios
of B): the notebook's theta is in degrees (K1 is converted), its acceleration unit is not
stated.

Tolerances (issue 8): frequencies +-3 % (wp +-5 %), tau +-15 %, K1 +-10 %, damping ratios
+-30 %, B signs exact (B1 < 0 < B2, B3 > 0), B1/B2 and B3/B2 +-30 %.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from samii import notebook as nb

__all__ = ["TargetCheck", "check_fit_against_eq9_4", "TOLERANCES"]

#: name -> relative tolerance against eq 9.4 (issue 8's table).
TOLERANCES: Mapping[str, float] = {
    "wp": 0.05,
    "wz": 0.03,
    "w1": 0.03,
    "w3": 0.03,
    "tau": 0.15,
    "K1_deg": 0.10,
    "zp": 0.30,
    "zz": 0.30,
    "z1": 0.30,
    "z3": 0.30,
    "B1/B2": 0.30,
    "B3/B2": 0.30,
}


@dataclass(frozen=True)
class TargetCheck:
    name: str
    target: float
    value: float
    tolerance: float  #: relative; 0 for an exact sign test

    @property
    def error(self) -> float:
        """Relative error (value / target - 1); for a sign test 0 or 1."""
        if self.tolerance == 0:
            return 0.0 if self.ok else 1.0
        return self.value / self.target - 1.0

    @property
    def ok(self) -> bool:
        if not math.isfinite(self.value):
            return False
        if self.tolerance == 0:
            return math.copysign(1.0, self.value) == math.copysign(1.0, self.target)
        return abs(self.value / self.target - 1.0) <= self.tolerance

    def row(self) -> str:
        if self.tolerance == 0:
            return f"{self.name:8s} sign {'+' if self.target > 0 else '-'}    {self.value:+.4g}    {'ok' if self.ok else 'WRONG SIGN'}"
        return f"{self.name:8s} {self.target:10.4g} {self.value:10.4g} {100 * self.error:+7.1f} %  (+-{100 * self.tolerance:.0f} %)  {'ok' if self.ok else 'MISSED'}"


def check_fit_against_eq9_4(params: Mapping[str, float]) -> list[TargetCheck]:
    """The issue's target table for fitted 3-mode s^4 parameters in SI (theta in rad: K1 in (rad/s)/V)."""
    e = nb.EQ9_4
    p = dict(params)
    p["K1_deg"] = p["K1"] * 180.0 / math.pi
    ref = dict(e)
    ref["K1_deg"] = e["K1"]
    out = [TargetCheck(n, float(ref[n]), float(p[n]), TOLERANCES[n]) for n in ("wp", "zp", "wz", "zz", "tau", "K1_deg", "w1", "z1", "w3", "z3")]
    for n in ("B1", "B2", "B3"):
        out.append(TargetCheck(f"sign {n}", float(e[n]), float(p[n]), 0.0))
    out.append(TargetCheck("B1/B2", e["B1"] / e["B2"], p["B1"] / p["B2"], TOLERANCES["B1/B2"]))
    out.append(TargetCheck("B3/B2", e["B3"] / e["B2"], p["B3"] / p["B2"], TOLERANCES["B3/B2"]))
    return out
