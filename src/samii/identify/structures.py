"""The notebook's transfer-function model structures, evaluated on a frequency grid.

Actuator, eq 1.1 / 9.1::

    theta/v = K1 wp^2 (s^2 + 2 zz wz s + wz^2) tau / (s wz^2 (s^2 + 2 zp wp s + wp^2) (s + tau))

Flexible base with N modes, eq 9.2 (``w2_factors=False``) or eq 1.2
(``w2_factors=True``, each B_k multiplied by w_k^2)::

    xdd/theta = s^n sum_k B_k [w_k^2] / (s^2 + 2 z_k w_k s + w_k^2),   n = 4 ("s4") or 2 ("s2", chapter 4)

With the tie of eq 9.2 (``tie_mode2=True``) mode 2 is the actuator zero:
w2 = wz, z2 = zz. The product xdd/v = (theta/v)(xdd/theta) is the ``total``
channel.

Parameter names are the notebook's: K1, wp, zp, wz, zz, tau, then w_k, z_k for
every mode not tied (w1, z1, w3, z3, w4, z4, ...), then B1 ... BN. For the
3-mode tied structure this is the order of eq 9.3; for 2 modes that of eq 1.3.

Evaluation is vectorised over the grid and returns, with each response, the
analytic derivative of its natural logarithm with respect to every parameter
(the fit works with log responses: dB and phase are its real and imaginary parts).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Literal, get_args

import numpy as np

from samii import notebook as nb
from samii.frequency_response import Channel

__all__ = ["Numerator", "ModelStructure"]

Numerator = Literal["s4", "s2"]
_ACT_NAMES = ("K1", "wp", "zp", "wz", "zz", "tau")


@dataclass(frozen=True)
class ModelStructure:
    """Which of the notebook's models to fit.

    Parameters
    ----------
    n_modes : int
        Number of base modes (2 in chapter 1, 3 in chapter 9; any N >= 1).
    numerator : {"s4", "s2"}
        Power of s in front of the modal sum of xdd/theta (chapter 2 derives s^4;
        chapter 4 compares s^2).
    tie_mode2 : bool, optional
        Mode 2 of the base is the actuator's zero pair (w2 = wz, z2 = zz, eq 9.2);
        with ``False`` mode 2 gets its own w2, z2. Default: True for 2 or more
        modes (as the notebook), False for 1 mode (there is no mode 2 to tie;
        ``True`` with 1 mode is refused).
    w2_factors : bool, optional
        Gains are B_k w_k^2 (eq 1.2) instead of B_k (eq 9.2). Default as the
        notebook: True for 2 modes, False otherwise. Pass it explicitly to fit
        one convention to the other's data.
    """

    n_modes: int = 3
    numerator: Numerator = "s4"
    tie_mode2: bool | None = None
    w2_factors: bool | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.n_modes, (int, np.integer)) or self.n_modes < 1:
            raise ValueError(f"n_modes must be an integer >= 1, got {self.n_modes}")
        if self.numerator not in get_args(Numerator):
            raise ValueError(f"numerator must be one of {get_args(Numerator)}, got {self.numerator!r}")
        if self.tie_mode2 is None:
            object.__setattr__(self, "tie_mode2", self.n_modes >= 2)
        elif self.tie_mode2 and self.n_modes < 2:
            raise ValueError("tie_mode2=True needs n_modes >= 2 (it makes mode 2 the actuator zero, w2 = wz); a 1-mode base has no mode 2")
        object.__setattr__(self, "tie_mode2", bool(self.tie_mode2))
        if self.w2_factors is None:
            object.__setattr__(self, "w2_factors", self.n_modes == 2)

    # -- presets -----------------------------------------------------------------
    @classmethod
    def notebook_2mode(cls) -> ModelStructure:
        """Eq 1.1 + 1.2: 2 modes, s^4, w2 = wz, gains B_k w_k^2."""
        return cls(n_modes=2, numerator="s4", tie_mode2=True, w2_factors=True)

    @classmethod
    def notebook_3mode(cls, numerator: Numerator = "s4") -> ModelStructure:
        """Eq 9.1 + 9.2: 3 modes, w2 = wz, z2 = zz, plain gains B_k."""
        return cls(n_modes=3, numerator=numerator, tie_mode2=True, w2_factors=False)

    # -- names -------------------------------------------------------------------
    @property
    def power(self) -> int:
        return {"s4": 4, "s2": 2}[self.numerator]

    @cached_property
    def param_names(self) -> tuple[str, ...]:
        names = list(_ACT_NAMES)
        for k in range(1, self.n_modes + 1):
            if not (k == 2 and self.tie_mode2):
                names += [f"w{k}", f"z{k}"]
        names += [f"B{k}" for k in range(1, self.n_modes + 1)]
        return tuple(names)

    @cached_property
    def positive(self) -> np.ndarray:
        """Mask of the parameters that must be positive (all but the B gains); read-only."""
        mask = np.array([not n.startswith("B") for n in self.param_names])
        mask.setflags(write=False)
        return mask

    @cached_property
    def _index(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.param_names)}

    def mode_names(self, k: int) -> tuple[str, str]:
        """Names of the frequency and damping of base mode ``k`` (1-based)."""
        if k == 2 and self.tie_mode2:
            return "wz", "zz"
        return f"w{k}", f"z{k}"

    def describe(self) -> str:
        """One line, e.g. "3 modes, s4 numerator, w2=wz, z2=zz, gains B_k (eq 9.2)"."""
        modes = "1 mode" if self.n_modes == 1 else f"{self.n_modes} modes"
        tie = ("w2=wz, z2=zz, " if self.tie_mode2 else "mode 2 free, ") if self.n_modes >= 2 else ""
        gains = "B_k w_k^2 (eq 1.2)" if self.w2_factors else "B_k (eq 9.2)"
        return f"{modes}, {self.numerator} numerator, {tie}gains {gains}"

    def channel_params(self, channels: tuple[Channel, ...]) -> tuple[str, ...]:
        """Names of the parameters the response of ``channels`` depends on, in ``param_names`` order.

        theta/v (``act``) depends on the actuator's six (K1, wp, zp, wz, zz, tau);
        xdd/theta (``base``) on every mode's frequency and damping (mode 2's are
        wz, zz when tied) and the gains B_k; xdd/v (``total``) on all.
        """
        need: set[str] = set()
        if "act" in channels or "total" in channels:
            need.update(_ACT_NAMES)
        if "base" in channels or "total" in channels:
            for k in range(1, self.n_modes + 1):
                need.update(self.mode_names(k))
                need.add(f"B{k}")
        return tuple(n for n in self.param_names if n in need)

    def units(self, theta: str = "rad", accel: str = "m/s²") -> dict[str, str]:
        """Unit of every parameter, for tables and plot titles.

        ``theta``: unit of the arm angle ("rad" in samii's data, "deg" assumed for
        the notebook's); ``accel``: unit of the base acceleration. Frequencies and
        tau are in rad/s, damping ratios dimensionless; K1 follows from theta/v ~
        K1/s at low frequency; B_k from xdd/theta = s^n B_k [w_k^2] / (s^2 + ...).
        """
        u = {"K1": f"{theta}/(V·s)", "tau": "rad/s"}
        # xdd/theta [accel/theta]: s^n/D has units s^(2-n), w_k^2 has s^-2
        base_power = self.power - 2 + (2 if self.w2_factors else 0)
        gain = f"({accel})/{theta}" + {0: "", 2: "·s²", 4: "·s⁴"}[base_power]
        for n in self.param_names:
            if n.startswith("B"):
                u[n] = gain
            elif n.startswith("w"):
                u[n] = "rad/s"
            elif n.startswith("z"):
                u[n] = "1"
        return {n: u[n] for n in self.param_names}

    def to_dict(self) -> dict:
        return {"n_modes": int(self.n_modes), "numerator": self.numerator, "tie_mode2": bool(self.tie_mode2), "w2_factors": bool(self.w2_factors)}

    # -- parameter vectors ---------------------------------------------------------
    def vector(self, params: Mapping[str, float]) -> np.ndarray:
        """Parameter vector in ``param_names`` order; KeyError naming what is missing."""
        missing = [n for n in self.param_names if n not in params]
        if missing:
            raise KeyError(f"parameters {missing} missing for structure ({self.describe()}); got {sorted(params)}")
        x = np.array([float(params[n]) for n in self.param_names])
        if not np.all(np.isfinite(x)):
            bad = [f"{n} = {float(v):g}" for n, v in zip(self.param_names, x) if not np.isfinite(v)]
            raise ValueError(f"non-finite parameter(s): {', '.join(bad)}")
        bad = [n for n, v, pos in zip(self.param_names, x, self.positive) if pos and v <= 0]
        if bad:
            raise ValueError(f"parameters {bad} must be positive")
        return x

    def params(self, x: np.ndarray) -> dict[str, float]:
        """Name -> value mapping of a parameter vector."""
        x = np.asarray(x, float)
        if x.shape != (len(self.param_names),):
            raise ValueError(f"expected {len(self.param_names)} parameters {self.param_names}, got shape {x.shape}")
        return {n: float(v) for n, v in zip(self.param_names, x)}

    # -- evaluation ----------------------------------------------------------------
    def log_responses(
        self, x: np.ndarray, w: np.ndarray, channels: tuple[Channel, ...] = ("act", "base"), *, derivatives: bool = True
    ) -> dict[Channel, tuple[np.ndarray, np.ndarray | None]]:
        """Complex responses and the derivatives of their logs.

        Parameters
        ----------
        x : array (n_params,)
            Parameters in ``param_names`` order.
        w : array (m,)
            Angular frequencies [rad/s].
        channels : tuple of {"act", "base", "total"}
        derivatives : bool
            Also return the derivatives (else None in their place).

        Returns
        -------
        dict
            channel -> (H (m,), dlogH/dx (m, n_params)). ``dlogH/dx = (dH/dx)/H``
            is analytic (derived term by term from eq 9.1 and 9.2 below).
        """
        idx = self._index
        s = 1j * np.asarray(w, float)
        s2 = s * s
        n = len(self.param_names)
        out: dict = {}
        need_act = any(c in channels for c in ("act", "total"))
        need_base = any(c in channels for c in ("base", "total"))
        if need_act:
            K1, wp, zp, wz, zz, tau = (x[idx[k]] for k in _ACT_NAMES)
            inv_Dp = 1.0 / (s2 + 2 * zp * wp * s + wp * wp)
            Nz = s2 + 2 * zz * wz * s + wz * wz
            inv_lag = 1.0 / (s + tau)
            H = (K1 * wp**2 * tau / wz**2) * Nz * inv_Dp * inv_lag / s
            if not derivatives:
                out["act"] = (H, None)
            else:  # log H = log K1 + 2 log wp + log Nz + log tau - log s - 2 log wz - log Dp - log(s + tau)
                inv_Nz = 1.0 / Nz
                dL = np.zeros((s.size, n), complex)
                dL[:, idx["K1"]] = 1.0 / K1
                dL[:, idx["wp"]] = 2.0 / wp - (2 * zp * s + 2 * wp) * inv_Dp
                dL[:, idx["zp"]] = (-2 * wp) * s * inv_Dp
                dL[:, idx["wz"]] = (2 * zz * s + 2 * wz) * inv_Nz - 2.0 / wz
                dL[:, idx["zz"]] = (2 * wz) * s * inv_Nz
                dL[:, idx["tau"]] = 1.0 / tau - inv_lag
                out["act"] = (H, dL)
        if need_base:  # mode by mode on 1-d arrays: faster than (m, N) broadcasting at these sizes
            sn = s2 * s2 if self.power == 4 else s2
            H = np.zeros(s.size, complex)
            cols: list[tuple[int, np.ndarray]] = []
            for k in range(1, self.n_modes + 1):
                wn, zn = self.mode_names(k)
                wk, zk, Bk = x[idx[wn]], x[idx[zn]], x[idx[f"B{k}"]]
                g, dg = (wk**2, 2 * wk) if self.w2_factors else (1.0, 0.0)
                inv_D = 1.0 / (s2 + 2 * zk * wk * s + wk * wk)
                t = sn * inv_D
                H += (Bk * g) * t
                if derivatives:
                    # d/dw [g/D] = dg/D - g (2 z s + 2 w)/D^2 ;  d/dz [g/D] = -g 2 w s / D^2
                    cols.append((idx[f"B{k}"], g * t))
                    cols.append((idx[wn], Bk * t * (dg - g * (2 * zk * s + 2 * wk) * inv_D)))
                    cols.append((idx[zn], (-2 * Bk * g * wk) * t * s * inv_D))
            dL = None
            if derivatives:
                inv_H = 1.0 / H
                dL = np.zeros((s.size, n), complex)
                for i, col in cols:
                    dL[:, i] = col * inv_H
            out["base"] = (H, dL)
        if "total" in channels:
            (Ha, dLa), (Hb, dLb) = out["act"], out["base"]
            out["total"] = (Ha * Hb, dLa + dLb if derivatives else None)
        return {c: out[c] for c in channels}

    @cached_property
    def mode_index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions in ``param_names`` of every base mode's frequency, damping and gain, mode 1 first."""
        idx = self._index
        names = [self.mode_names(k) for k in range(1, self.n_modes + 1)]
        return tuple(np.array([idx[n] for n in col]) for col in (*zip(*names), [f"B{k}" for k in range(1, self.n_modes + 1)]))

    def _modal_terms(self, wk: np.ndarray, zk: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s^n / D_k (m, N), gain factor g_k (N,), 1/D_k (m, N)), D_k = s^2 + 2 z_k w_k s + w_k^2."""
        s2 = (s * s)[:, None]
        sn = s2 * s2 if self.power == 4 else s2
        inv_D = 1.0 / (s2 + (2 * zk * wk) * s[:, None] + wk * wk)
        g = wk**2 if self.w2_factors else np.ones_like(wk)
        return sn * inv_D, g, inv_D

    def modal_columns(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        """xdd/theta of each mode with unit gain, (m, N): column k is s^n g_k / D_k, so base = columns @ B."""
        wi, zi, _ = self.mode_index
        x = np.asarray(x, float)
        t, g, _ = self._modal_terms(x[wi], x[zi], 1j * np.asarray(w, float))
        return t * g

    def response(self, params: Mapping[str, float], freq_hz: np.ndarray, channel: Channel) -> np.ndarray:
        """Complex response of ``channel`` at ``freq_hz`` for named parameters."""
        w = 2 * np.pi * np.asarray(freq_hz, float)
        return self.log_responses(self.vector(params), w, (channel,), derivatives=False)[channel][0]

    # -- python-control -------------------------------------------------------------
    def to_tf(self, params: Mapping[str, float], channel: Channel = "total"):
        """python-control ``TransferFunction`` of ``channel``.

        theta/v is ``samii.notebook.actuator_tf`` (eq 9.1); xdd/theta is built here
        mode by mode exactly as ``samii.notebook.base_tf`` builds eq 9.2 (any
        number of modes, 1 included). The base channel with the s^4 numerator is
        improper (relative degree -2, chapter 2 notes it is non-causal); the total
        xdd/v is proper.
        """

        p = self.params(self.vector(params))
        if channel not in ("act", "base", "total"):
            raise ValueError(f"channel must be 'act', 'base' or 'total', got {channel!r}")
        if channel == "act":
            return nb.actuator_tf(p)
        base = nb.base_tf(p, numerator=self.numerator, w2_factors=self.w2_factors)
        return base if channel == "base" else nb.actuator_tf(p) * base

    def to_ss(self, params: Mapping[str, float], channel: Channel = "total"):
        """python-control ``StateSpace`` (minimal realisation) of ``channel``.

        For ``total`` the tied mode 2 cancels the actuator's zero pair (eq 8.1
        lists no mode-2 pole for that reason); the minimal realisation drops it.
        """
        import control  # (lazy: imports control, only when called)

        tf = self.to_tf(params, channel)
        num, den = (np.trim_zeros(np.asarray(c[0][0], float), "f") for c in (tf.num, tf.den))
        if num.size > den.size:
            raise ValueError(f"channel {channel!r} with numerator {self.numerator} is improper and has no state-space form; use 'total'")
        # slycot-free: cancel pole-zero pairs on the transfer function, then realise it
        return control.ss(tf.minreal(tol=1e-6))
