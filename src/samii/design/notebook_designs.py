"""The notebook's two digital designs as library calls, each with its figures as a JSON-ready document and its runnable
controller: chapter 8's pole placement with an observer on eq 1.4 (:func:`place_on_eq1_4`, ``samii design place``) and
chapter 10's pole-cancelling compensator on eq 9.4 (:func:`cancel_on_eq9_4`, ``samii design cancel``). Both in the
notebook's units (theta in degrees, the acceleration in ft/s², v in volts); their controllers read SI through
:data:`samii.closedloop.controllers.NOTEBOOK_INPUT_SCALE`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from samii import notebook as nb
from samii.closedloop.controllers import NOTEBOOK_INPUT_SCALE, NOTEBOOK_UNITS_SI, SavedController
from samii.design import placement as pl
from samii.design.cancel import PoleCancelDesign, design_pole_cancel
from samii.design.placement import PlacementDesign
from samii.errors import InputError
from samii.json_output import finite_or_none

__all__ = ["PlaceOnEq14", "place_on_eq1_4", "CancelOnEq94", "cancel_on_eq9_4"]


def _pole_pairs(z) -> list[list[float | None]]:
    """Complex numbers as JSON's [real, imaginary] pairs (a non-finite part null)."""
    return [finite_or_none(complex(x)) for x in np.atleast_1d(z)]


@dataclass(frozen=True)
class PlaceOnEq14:
    """Chapter 8's design on eq 1.4 (samii.design.placement.PlacementDesign) and the longest sample time it allows."""

    design: PlacementDesign
    max_sample_time_s: float

    @property
    def stable(self) -> bool:
        """Every closed-loop pole inside the unit circle."""
        return self.design.unstable_poles_z.size == 0

    def kalman_noise_std(self) -> dict | None:
        d = self.design
        if d.kalman_covariances is None:
            return None
        return {"input_V": d.kalman_covariances[0], "theta": d.kalman_covariances[1][0], "accel": d.kalman_covariances[1][1]}

    def to_dict(self) -> dict:
        d = self.design
        cl = d.closed_loop_poles_z
        return {
            "model": "eq 1.4 (2-mode s^4), canonical form of chapter 5, notebook units",
            "sample_time_s": d.sample_time_s,
            "max_sample_time_s": self.max_sample_time_s,
            "zeta": d.zeta,
            "observer": d.observer,
            "kalman_noise_std": self.kalman_noise_std(),
            "controller_poles_s": _pole_pairs(d.poles_s),
            "controller_poles_z": _pole_pairs(d.poles_z),
            "observer_poles_z": _pole_pairs(d.observer_poles_z),
            "closed_loop_poles_z": _pole_pairs(cl),
            "closed_loop_max_abs_z": float(np.max(np.abs(cl))),
            "closed_loop_stable": self.stable,
            "unstable_closed_loop_poles_z": _pole_pairs(d.unstable_poles_z),
            "K": d.K.ravel().tolist(),
            "L": d.L.tolist(),
            "N": d.N,
        }

    def saved_controller(self):
        """The runnable controller (samii.closedloop.controllers.SavedController), reading SI, with its provenance."""

        d = self.design
        c = d.controller(input_scale={k: NOTEBOOK_INPUT_SCALE[k] for k in ("theta_ref", "theta", "accel")}, model_units=NOTEBOOK_UNITS_SI)
        prov = {"designed_on": "eq 1.4 (notebook, 2 base modes), canonical form of chapter 5", "design": "samii design place (chapter 8)",
                "sample_time_s": d.sample_time_s, "zeta": d.zeta, "observer": d.observer, "kalman_noise_std": self.kalman_noise_std(),
                "closed_loop_stable_on_design_model": self.stable}  # fmt: skip
        return SavedController(c, True, prov)


def place_on_eq1_4(
    *,
    sample_time_s: float = 1e-3,
    zeta: float = nb.EQ8_3_ZETA,
    observer: str = "placement",
    input_noise_std: float | None = None,
    theta_noise_std: float | None = None,
    accel_noise_std: float | None = None,
) -> PlaceOnEq14:
    """Pole placement with an observer on eq 1.4 in the canonical form of chapter 5 (the noise standard deviations, in
    the notebook's units, for ``observer="kalman"``). A sample time too long for the design's fastest pole, or so short
    that the poles miss their targets, is an InputError naming it."""
    from samii.design import canonical as cc  # (lazy: imports sympy, only when called)

    model = cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)
    T = sample_time_s
    t_max = pl.max_sample_time_s(model, zeta=zeta, observer=observer)
    if T > t_max:
        w, which = pl.fastest_pole(model, zeta=zeta, observer=observer)
        raise InputError(
            f"--sample-time-s {T:g}: too long; the fastest {which} pole of this design (|s| = {w:.4g} rad/s, period "
            f"2 pi/|s| = {2e3 * np.pi / w:.3g} ms) needs at least {pl.MIN_SAMPLES_PER_PERIOD} samples per period, so "
            f"--sample-time-s must be <= {pl._floor_digits(t_max, 4):g} s with --observer {observer}"
        )
    noise = (theta_noise_std, accel_noise_std) if observer == "kalman" else None
    try:
        d = pl.design_placement(model, sample_time_s=T, zeta=zeta, observer=observer, input_noise_std=input_noise_std, measurement_noise_std=noise)
    except pl.PlacementInaccurate as exc:
        raise InputError(f"--sample-time-s {T:g} (with --zeta {zeta:g}): {exc}") from None
    return PlaceOnEq14(d, t_max)


@dataclass(frozen=True)
class CancelOnEq94:
    """Chapter 10's compensator on eq 9.4 (samii.design.cancel.PoleCancelDesign) and how it was asked for."""

    design: PoleCancelDesign
    gain_chosen_by_rule: bool  #: the loop gain by the notebook's rule (zeta 0.7 on the slowest moving pair), not given
    sample_time_s: float  #: of the runnable controller

    @property
    def stable(self) -> bool:
        """Every closed-loop pole in the left half plane."""
        return self.design.unstable_poles.size == 0

    def to_dict(self) -> dict:
        d = self.design
        return {
            "model": "eq 9.4 (3-mode s^4), notebook units",
            "loop": d.loop,
            "zeros": _pole_pairs(d.zeros),
            "poles": _pole_pairs(d.poles),
            "num": np.asarray(d.Gc.num[0][0], float).tolist(),
            "den": np.asarray(d.Gc.den[0][0], float).tolist(),
            "gain": d.gain,
            "gain_chosen_by_rule": self.gain_chosen_by_rule,
            "closed_loop_poles": _pole_pairs(d.closed_loop),
            "closed_loop_stable": self.stable,
            "unstable_closed_loop_poles": _pole_pairs(d.unstable_poles),
            "dc_gain_as_drawn": d.dc_gain_as_drawn if self.stable else float("nan"),
            "reference_gain_for_unit_dc": d.reference_gain if self.stable else None,
            "controller_scales_reference_by_default": d.loop == "theta",
        }

    def saved_controller(self):
        """The runnable controller (SavedController), reading SI, with its provenance; a design unstable on eq 9.4 is
        refused (InputError)."""

        d = self.design
        if not self.stable:
            raise InputError(f"--save: the closed loop on eq 9.4 is unstable at K = {d.gain:g}; a controller that is unstable on its own "
                             "design model is not saved")  # fmt: skip
        names = ("theta_ref", "theta") if d.loop == "theta" else ("theta_ref", "theta", "accel")
        c = d.controller(sample_time_s=self.sample_time_s, input_scale={k: NOTEBOOK_INPUT_SCALE[k] for k in names}, model_units=NOTEBOOK_UNITS_SI)
        prov = {"designed_on": "eq 9.4 (notebook, 3 base modes)", "design": "samii design cancel (chapter 10)", "loop": d.loop,
                "gain": d.gain, "gain_chosen_by_rule": self.gain_chosen_by_rule, "sample_time_s": self.sample_time_s}  # fmt: skip
        return SavedController(c, True, prov)


def cancel_on_eq9_4(*, loop: str = "theta", gain: float | None = None, sample_time_s: float = 1e-3) -> CancelOnEq94:
    """The pole-cancelling compensator on eq 9.4 closing ``loop``, at loop gain ``gain`` (None: the notebook's rule)."""
    return CancelOnEq94(design_pole_cancel(nb.EQ9_4, loop=loop, gain=gain), gain is None, sample_time_s)
