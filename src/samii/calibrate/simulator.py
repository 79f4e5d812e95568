"""The linearised simulator as a parametric frequency-response model.

``SimulatorFRF`` maps a vector of physical parameters (dotted ``--set`` names,
e.g. ``beam.clamp_stiffness_Nm_rad``) to the simulator's small-signal FRF at the
nominal pose: the MJCF is written from the parameters, the ``home`` keyframe put
at the new static equilibrium, the model linearised (``samii.sim.linearize``)
and its response taken in discrete time at the physics step
(``samii.measure.campaign.linearised_frf``), which is what a simulated
swept-sine measurement converges to. One evaluation costs about 10 ms.

It offers the interface ``samii.identify.cost.FitProblem`` expects of a model
structure (``param_names``, ``channel_params``, ``log_responses``), so the
calibration minimises exactly the notebook's weighted cost that ``samii fit``
minimises, with the same coherence weighting and noise profile.

Optional channel gains (``gain.act``, ``gain.base``, ``gain.total``) multiply a
channel's response: a sensor whose unit or calibration factor is unknown (the
notebook never states its accelerometer unit). The gain on ``base`` multiplies
``total`` too, since both carry the accelerometer; the one on ``act`` divides
``base`` and multiplies ``total`` (the angle sensor).

Derivatives are central differences in the logarithm of each parameter (relative
step ``rel_step``); the complex log of the ratio of the two responses keeps the
phase difference on the principal branch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from samii.frequency_response import Channel, FrequencyResponse
from samii.sim.mjcf import SamiiParams

__all__ = ["SimulatorFRF", "GAIN_PREFIX", "SIGNED", "parameter_value", "check_parameter_name"]

#: Prefix of the channel-gain parameters.
GAIN_PREFIX = "gain."
#: Parameters that may be zero or negative (all others are positive), with the scale [their
#: unit] below which their finite-difference step stops shrinking.
SIGNED = {"beam.accel_offset_m": 0.1, "arm.heading_deg": 10.0, "beam.pitch_deg": 10.0}
_GAIN_CHANNELS = ("act", "base")


def check_parameter_name(params: SamiiParams, name: str) -> None:
    """Raise ValueError unless ``name`` is a calibratable parameter: a float field
    ``beam.*``, ``arm.*``, ``hydraulic.*`` or ``sensor.*``, or a channel gain ``gain.act`` / ``gain.base``."""
    if name.startswith(GAIN_PREFIX):
        if name[len(GAIN_PREFIX) :] not in _GAIN_CHANNELS:
            raise ValueError(f"parameter {name!r}: channel gains are {[GAIN_PREFIX + c for c in _GAIN_CHANNELS]}")
        return
    parts = name.split(".")
    sections = ("beam", "arm", "hydraulic", "sensor")
    if len(parts) != 2 or parts[0] not in sections:
        raise ValueError(
            f"parameter {name!r}: expected 'beam.<name>', 'arm.<name>', 'hydraulic.<name>', 'sensor.<name>' or a channel gain 'gain.act'/'gain.base'"
        )
    section = getattr(params, parts[0])
    types = {f.name: f.type for f in fields(section)}
    if parts[1] not in types:
        raise ValueError(f"parameter {name!r}: {parts[0]} has no parameter {parts[1]!r}; expected one of {sorted(types)}")
    if parts[1] == "n_segments":
        raise ValueError(f"parameter {name!r} is a discretisation choice (an integer), not a physical parameter to calibrate")
    if parts[1] == "accel_body_fixed":  # (its --start hint led to "must be 0 or 1")
        raise ValueError(
            f"parameter {name!r} is a 0/1 switch (1 for a body-fixed accelerometer whose axis tilts with the tip, 0 for the world-frame reading), not a "
            "physical parameter to calibrate; set it with --set"
        )


def parameter_value(params: SamiiParams, name: str) -> float:
    """Current value of a dotted parameter (a channel gain is 1)."""
    if name.startswith(GAIN_PREFIX):
        return 1.0
    section, field_name = name.split(".")
    return float(getattr(getattr(params, section), field_name))


@dataclass(frozen=True, eq=False)  # holds a cache: compare by identity
class SimulatorFRF:
    """Simulator FRF as a function of the parameters ``param_names`` (all positive).

    Parameters
    ----------
    base : SamiiParams
        Every parameter not calibrated keeps its value here.
    param_names : sequence of str
        Dotted names (see :func:`check_parameter_name`).
    rel_step : float
        Relative step of the central-difference derivatives.
    """

    base: SamiiParams
    param_names: tuple[str, ...]
    rel_step: float = 1e-4
    _cache: dict = field(default_factory=dict, init=False, repr=False)
    _models: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "param_names", tuple(self.param_names))
        if len(set(self.param_names)) != len(self.param_names):
            raise ValueError(f"parameters named twice: {self.param_names}")
        for name in self.param_names:
            check_parameter_name(self.base, name)

    # -- the interface of samii.identify.structures.ModelStructure that FitProblem uses --
    @property
    def positive(self) -> np.ndarray:
        return np.array([n not in SIGNED for n in self.param_names])

    def channel_params(self, channels: tuple[Channel, ...]) -> tuple[str, ...]:
        """Every physical parameter may move every channel; a gain only its channels."""
        used = []
        for name in self.param_names:
            if name.startswith(GAIN_PREFIX):
                ch = name[len(GAIN_PREFIX) :]
                touches = {"act": ("act", "base", "total"), "base": ("base", "total")}[ch]
                if not any(c in touches for c in channels):
                    continue
            used.append(name)
        return tuple(used)

    def vector(self, values: Mapping[str, float]) -> np.ndarray:
        return np.array([float(values[n]) for n in self.param_names])

    def params(self, x: np.ndarray) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.param_names, x)}

    # -- evaluation ------------------------------------------------------------------
    def samii_params(self, x: Sequence[float]) -> SamiiParams:
        """The full parameter set for ``x`` (channel gains are not model parameters)."""
        from samii.sim.model import params_with_overrides  # (lazy: this module is imported at samii's start-up, that one is not needed there)

        physical = {n: float(v) for n, v in zip(self.param_names, x) if not n.startswith(GAIN_PREFIX)}
        return params_with_overrides(self.base, physical)

    #: Compiled models kept (the last few ``x``): a calibration's step is evaluated and then checked on the same model.
    MODELS_KEPT = 4

    def model(self, x: Sequence[float]):
        """The compiled MuJoCo model for ``x``, at its static equilibrium (not to be modified: it may be kept)."""
        from samii.sim.model import load_model  # (lazy: this module is imported at samii's start-up, that one is not needed there)

        key = np.asarray(x, float).tobytes()
        hit = self._models.get(key)
        if hit is None:
            while len(self._models) >= self.MODELS_KEPT:
                self._models.pop(next(iter(self._models)))
            hit = self._models[key] = load_model(params=self.samii_params(x))
        return hit

    def frf(self, x: Sequence[float], freq_hz: np.ndarray) -> FrequencyResponse:
        """The linearised simulator's FRF (act, base, total) for ``x``, channel gains applied."""
        h = self._responses(np.asarray(x, float), np.asarray(freq_hz, float))
        return FrequencyResponse(
            np.asarray(freq_hz, float), act=h["act"], base=h["base"], total=h["total"], metadata={"source": "linearised simulator (samii calibrate)"}
        )

    def with_gains(self, x: Sequence[float], frf: FrequencyResponse) -> dict[str, np.ndarray]:
        """``frf``'s channels (act, base, total) as the sensors with the gains in ``x`` read them."""
        gains = {c: 1.0 for c in _GAIN_CHANNELS}
        for n, v in zip(self.param_names, x):
            if n.startswith(GAIN_PREFIX):
                gains[n[len(GAIN_PREFIX) :]] = float(v)
        ga, gb = gains["act"], gains["base"]
        return {"act": frf.act * ga, "base": frf.base * gb / ga, "total": frf.total * gb}

    def response(self, values: Mapping[str, float], freq_hz: np.ndarray, channel: Channel) -> np.ndarray:
        """One channel for named parameter values (``ModelStructure.response``'s signature, for plots)."""
        return self._responses(self.vector(values), np.asarray(freq_hz, float))[channel]

    def _responses(self, x: np.ndarray, freq_hz: np.ndarray) -> dict[str, np.ndarray]:
        key = (x.tobytes(), freq_hz.tobytes())
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        from samii.measure.campaign import linearised_frf  # (lazy: this module is imported at samii's start-up, that one is not needed there)

        out = self.with_gains(x, linearised_frf(self.model(x), freq_hz))
        if len(self._cache) > 64:
            self._cache.clear()
        self._cache[key] = out
        return out

    def log_responses(
        self, x: np.ndarray, w: np.ndarray, channels: tuple[Channel, ...] = ("act", "base"), *, derivatives: bool = True
    ) -> dict[Channel, tuple[np.ndarray, np.ndarray | None]]:
        """channel -> (H, dlogH/dx), as ``ModelStructure.log_responses``; derivatives by central
        differences, relative steps (in log x) for positive parameters, absolute ones
        (``rel_step`` times max(|x|, scale)) for the signed ones (``SIGNED``)."""
        x = np.asarray(x, float)
        f = np.asarray(w, float) / (2 * np.pi)
        h0 = self._responses(x, f)
        out: dict = {c: (h0[c], None) for c in channels}
        if not derivatives:
            return out
        d = {c: np.empty((f.size, x.size), complex) for c in channels}
        for i, name in enumerate(self.param_names):
            up, down = x.copy(), x.copy()
            if name in SIGNED:
                h = self.rel_step * max(abs(x[i]), SIGNED[name])
                up[i] += h
                down[i] -= h
                span = 2 * h
            else:  # d log H / d x_i = d log H / d log x_i / x_i
                up[i] *= 1 + self.rel_step
                down[i] *= 1 - self.rel_step
                span = np.log((1 + self.rel_step) / (1 - self.rel_step)) * x[i]
            hu, hd = self._responses(up, f), self._responses(down, f)
            for c in channels:
                d[c][:, i] = np.log(hu[c] / hd[c]) / span
        return {c: (h0[c], d[c]) for c in channels}
