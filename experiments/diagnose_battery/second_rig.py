"""A second, independent time-domain test rig for ``samii diagnose`` (numpy/scipy only).

Written from the physics, not from samii: nothing here imports or copies ``samii.diagnose.rig``,
``samii.notebook`` or ``samii.measure.*``, so that a convention or bug shared by samii's own rig and
its diagnosis cannot hide.

Physics (SAMII research notebook, Fall 2003, ch. 9)
--------------------------------------------------
* Actuator, eq 9.1: ``theta/v = K1 wp^2 (s^2 + 2 zz wz s + wz^2) tau / (s wz^2 (s^2 + 2 zp wp s + wp^2)(s + tau))``.
* Base, eq 9.2: ``xdd/theta = s^4 sum_k B_k / (s^2 + 2 z_k w_k s + w_k^2)`` with ``w2 = wz``, ``z2 = zz``.
* Parameters: eq 9.4 (phase weight 0.1, the one the notebook designs with), below as ``EQ9_4``.

Units. The notebook's theta is in degrees and its acceleration in ft/s^2 (samii.notebook's docstring says
so too: eq 9.4's B_k over the simulator's are ~3.3 per m/s^2, i.e. ft/s^2). In SI: ``theta/v`` [rad/V] is
the notebook's times pi/180; ``xdd/theta`` [(m/s^2)/rad] is the notebook's times 0.3048 * 180/pi. (samii's
own rigs, ``samii.measure.linear_rig`` and ``samii.diagnose.rig``, use 180/pi alone, i.e. read the
acceleration as m/s^2; the diagnosis refits the B_k, so only the signal-to-noise ratio differs.
``Rig.accel_unit_m_s2`` sets the factor.) The position loop is the notebook's unity feedback,
``Kp = 1 V/deg = 180/pi V/rad``.

The rig
-------
A continuous-time state-space realisation (series blocks: valve -> actuator structural mode -> eq 9.1's
zero/pole pair -> first-order lag -> integrator (pole at 0, or at ``leak_per_s``) -> theta; then
``w = s^2 theta = C A^2 x + C A B u`` (exact, theta/u has relative degree >= 2) drives the modal base
``xdd = sum_k B_k s^2/(s^2 + 2 z_k w_k s + w_k^2) w``, then the accelerometer's own dynamics). It is
integrated exactly (``scipy.linalg.expm`` of the augmented ``[[A, B], [0, 0]] h``) at ``oversample`` x the
DAQ rate, the valve input piecewise constant on the internal steps (a command delay that is not a whole
number of internal steps splits one step exactly). The ``oversample`` internal steps of a DAQ period are
composed into one affine map of ``[x_k, u_a, u_b]`` (u_a, u_b the valve inputs before and after the delayed
command change), so the per-sample Python loop is two small matrix-vector products.

The position loop is digital: at each DAQ sample k the controller reads theta (encoder-quantised, noisy,
possibly read late), computes ``v_k = r_k - Kp theta_meas_k`` and holds it (zero-order hold) until the next
sample. The recorded ``v`` is that command, ``r`` the excitation sample. Sensors sample the continuous
signal (left limit at the sample instant: the DAQ reads before the new command is output). Sensor
dynamics (low/high-pass) are states of the integrated system; sensor delays read the continuous signal
at ``t_k - T`` (a whole number of internal steps, else linear interpolation between internal points).

Out-of-library physics: ``mode1_drift_fraction`` (base mode 1's frequency drifts linearly over the file;
the system is re-discretised every ``drift_block_s``) and ``accel_gain_step`` (the accelerometer's gain
steps at ``accel_gain_step_at`` of the file).

API: :class:`Rig` (``Rig.drawn(rng, spread=0.15, **effects)``, ``rig.simulate(r, fs, ...) -> dict``),
:func:`swept_sine` (the excitation), :func:`write_csv` (DATA_FORMATS.md's time-series CSV).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import expm

__all__ = ["EQ9_4", "NAMES", "DEG", "FT", "Rig", "swept_sine", "write_csv", "valve_law"]

#: eq 9.4 of the SAMII research notebook (Fall 2003, ch. 9, phase weight 0.1; as transcribed in
#: shared/reference/seed_parameters.json "fits_3mode_s4" / "pw_0.1_eq9_4"). Frequencies in rad/s, theta in
#: degrees, acceleration in ft/s^2. Copied here: the project may not read shared/ at run time.
NAMES = ("K1", "wp", "zp", "wz", "zz", "tau", "w1", "z1", "w3", "z3", "B1", "B2", "B3")
EQ9_4 = dict(
    zip(
        NAMES, (27.8962, 55.2835, 0.139813, 62.0634, 0.0486851, 158.869, 10.8862, 0.0298125, 156.814, 0.0336399, -0.00146074, 0.00156505, 0.000280877)
    )
)
DEG = np.pi / 180.0  # rad per degree
FT = 0.3048  # m per ft

VALVE_LAWS = ("dead_band", "saturation", "asymmetry")


def valve_law(kind: str, value: float):
    """The valve nonlinearity on the command, ``u = N(v)`` (memoryless)."""
    if kind == "dead_band":
        d = float(value)
        return lambda v: v - d if v > d else (v + d if v < -d else 0.0)
    if kind == "saturation":
        L = float(value)
        return lambda v: L if v > L else (-L if v < -L else v)
    if kind == "asymmetry":
        g = 1.0 - float(value)
        return lambda v: v if v >= 0.0 else g * v
    raise ValueError(f"valve nonlinearity must be one of {VALVE_LAWS}, got {kind!r}")


# ---------------------------------------------------------------------------------------------- state space


@dataclass
class _SS:
    """Continuous SISO-in state space; C may have several rows."""

    A: np.ndarray
    B: np.ndarray  # (n, 1)
    C: np.ndarray  # (p, n)
    D: np.ndarray  # (p, 1)


def _ss(A, B, C, D) -> _SS:
    A = np.atleast_2d(np.asarray(A, float))
    return _SS(A, np.asarray(B, float).reshape(-1, 1), np.atleast_2d(np.asarray(C, float)), np.asarray(D, float).reshape(-1, 1))


def _series(s1: _SS, s2: _SS) -> _SS:
    """s2 after s1 (both single output here)."""
    n1, n2 = s1.A.shape[0], s2.A.shape[0]
    A = np.block([[s1.A, np.zeros((n1, n2))], [s2.B @ s1.C, s2.A]])
    B = np.vstack([s1.B, s2.B @ s1.D])
    C = np.hstack([s2.D @ s1.C, s2.C])
    D = s2.D @ s1.D
    return _SS(A, B, C, D)


def _second_order_ratio(wn_num: float | None, z_num: float, wn_den: float, z_den: float, gain: float) -> _SS:
    """``gain (s^2 + 2 z_num wn_num s + wn_num^2) / (s^2 + 2 z_den wn_den s + wn_den^2)``; numerator 1 when
    ``wn_num`` is None."""
    a1, a0 = 2.0 * z_den * wn_den, wn_den**2
    A = [[0.0, 1.0], [-a0, -a1]]
    B = [0.0, 1.0]
    if wn_num is None:
        return _ss(A, B, [[gain, 0.0]], [0.0])
    b1, b0 = 2.0 * z_num * wn_num, wn_num**2
    return _ss(A, B, [[gain * (b0 - a0), gain * (b1 - a1)]], [gain])


def _first_order(pole: float, b: float, c: float, d: float) -> _SS:
    return _ss([[pole]], [b], [[c]], [d])


def _discretise(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation over ``h``: ``expm([[A, B], [0, 0]] h)``."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A
    M[:n, n:] = B
    E = expm(M * h)
    return E[:n, :n], E[:n, n:]


def _delay_points(delay_s: float, dt: float) -> tuple[int, float]:
    """A delay as (whole internal steps m, fraction f): the value at t - delay is (1 - f) y[J - m] + f y[J - m - 1]."""
    x = delay_s / dt
    m = int(np.floor(x + 1e-9))
    f = x - m
    return m, (0.0 if f < 1e-9 else f)


# -------------------------------------------------------------------------------------------------- the rig


@dataclass(frozen=True)
class Rig:
    """The rig: eq 9.1/9.2 (notebook units in ``params``) with optional effects.

    Effects (all off by default): ``command_delay_s`` (the valve acts on v(t - T)); ``theta_delay_s`` (the
    encoder's reading is of theta(t - T); the controller uses that reading); ``accel_delay_s``; ``base_mode``
    (f_hz, zeta, B [(m/s^2)/rad]) added to the modal sum; ``act_mode`` (fp_hz, zp, fz_hz, zz): the factor
    ``(wp/wz)^2 (s^2 + 2 zz wz s + wz^2)/(s^2 + 2 zp wp s + wp^2)`` in theta/v; ``accel_lowpass_hz`` with
    ``accel_lowpass_order`` 1 or 2 (Butterworth); ``accel_highpass_hz`` (first order, AC coupling);
    ``accel_antialias_hz`` (another first-order low-pass); ``valve_hz``, ``valve_zeta`` (second-order valve);
    ``leak_per_s`` (theta/v's 1/s becomes 1/(s - a)); ``valve_nonlinearity`` (kind, level) with kind
    dead_band / saturation / asymmetry; out of the library: ``mode1_drift_fraction`` and ``accel_gain_step``.
    """

    params: dict = field(default_factory=lambda: dict(EQ9_4))
    kp_v_per_rad: float = 1.0 / DEG
    accel_unit_m_s2: float = FT
    command_delay_s: float = 0.0
    theta_delay_s: float = 0.0
    accel_delay_s: float = 0.0
    base_mode: tuple | None = None
    act_mode: tuple | None = None
    accel_lowpass_hz: float | None = None
    accel_lowpass_order: int = 1
    accel_highpass_hz: float | None = None
    accel_antialias_hz: float | None = None
    valve_hz: float | None = None
    valve_zeta: float = 0.7
    leak_per_s: float = 0.0
    valve_nonlinearity: tuple | None = None
    mode1_drift_fraction: float = 0.0
    drift_block_s: float = 0.5
    accel_gain_step: float = 0.0
    accel_gain_step_at: float = 0.5

    # ----- parameters in SI
    def si(self, w1_scale: float = 1.0) -> dict:
        p = self.params
        k_theta = p["K1"] * DEG  # rad/V/s (the integrator's gain)
        kb = self.accel_unit_m_s2 / DEG  # (ft/s^2)/deg -> (m/s^2)/rad
        modes = [(p["w1"] * w1_scale, p["z1"], p["B1"] * kb), (p["wz"], p["zz"], p["B2"] * kb), (p["w3"], p["z3"], p["B3"] * kb)]
        if self.base_mode:
            f, z, b = self.base_mode
            modes.append((2 * np.pi * f, z, b))
        return {"k_theta": k_theta, "modes": modes}

    # ----- analytic responses (for validation; independent of the state space)
    def G(self, f_hz) -> np.ndarray:
        """theta/v [rad/V], continuous, with the loop's effects (valve, act mode, leak, command delay)."""
        p = self.params
        s = 2j * np.pi * np.asarray(f_hz, float)
        g = (
            p["K1"]
            * DEG
            * p["wp"] ** 2
            * (s * s + 2 * p["zz"] * p["wz"] * s + p["wz"] ** 2)
            * p["tau"]
            / ((s - self.leak_per_s) * p["wz"] ** 2 * (s * s + 2 * p["zp"] * p["wp"] * s + p["wp"] ** 2) * (s + p["tau"]))
        )
        if self.valve_hz:
            wv = 2 * np.pi * self.valve_hz
            g = g * wv * wv / (s * s + 2 * self.valve_zeta * wv * s + wv * wv)
        if self.act_mode:
            fp, zp, fz, zz = self.act_mode
            wp, wz = 2 * np.pi * fp, 2 * np.pi * fz
            g = g * (wp / wz) ** 2 * (s * s + 2 * zz * wz * s + wz * wz) / (s * s + 2 * zp * wp * s + wp * wp)
        return g * np.exp(-s * self.command_delay_s)

    def Bx(self, f_hz) -> np.ndarray:
        """xdd/theta [(m/s^2)/rad], continuous (eq 9.2 with any extra base mode)."""
        s = 2j * np.pi * np.asarray(f_hz, float)
        return s**4 * sum(b / (s * s + 2 * z * w * s + w * w) for w, z, b in self.si()["modes"])

    def accel_sensor(self, f_hz) -> np.ndarray:
        s = 2j * np.pi * np.asarray(f_hz, float)
        h = np.exp(-s * self.accel_delay_s)
        if self.accel_lowpass_hz:
            wc = 2 * np.pi * self.accel_lowpass_hz
            h = h * (wc / (s + wc) if self.accel_lowpass_order == 1 else wc * wc / (s * s + np.sqrt(2) * wc * s + wc * wc))
        if self.accel_antialias_hz:
            wc = 2 * np.pi * self.accel_antialias_hz
            h = h * wc / (s + wc)
        if self.accel_highpass_hz:
            wc = 2 * np.pi * self.accel_highpass_hz
            h = h * s / (s + wc)
        return h

    # ----- state space
    def _actuator(self) -> _SS:
        p = self.params
        blocks = []
        if self.valve_hz:
            wv = 2 * np.pi * self.valve_hz
            blocks.append(_second_order_ratio(None, 0.0, wv, self.valve_zeta, wv * wv))
        if self.act_mode:
            fp, zp, fz, zz = self.act_mode
            wp, wz = 2 * np.pi * fp, 2 * np.pi * fz
            blocks.append(_second_order_ratio(wz, zz, wp, zp, (wp / wz) ** 2))
        blocks.append(_second_order_ratio(p["wz"], p["zz"], p["wp"], p["zp"], p["wp"] ** 2 / p["wz"] ** 2))
        blocks.append(_first_order(-p["tau"], p["tau"], 1.0, 0.0))
        blocks.append(_first_order(self.leak_per_s, p["K1"] * DEG, 1.0, 0.0))  # theta, the last state
        sys = blocks[0]
        for b in blocks[1:]:
            sys = _series(sys, b)
        return sys

    def _accel_path(self, w1_scale: float) -> _SS:
        """w = s^2 theta -> base -> accelerometer dynamics."""
        modes = self.si(w1_scale)["modes"]
        n = 2 * len(modes)
        A = np.zeros((n, n))
        B = np.zeros(n)
        C = np.zeros((1, n))
        for i, (w, z, b) in enumerate(modes):
            A[2 * i, 2 * i + 1] = 1.0
            A[2 * i + 1, 2 * i] = -w * w
            A[2 * i + 1, 2 * i + 1] = -2 * z * w
            B[2 * i + 1] = 1.0
            C[0, 2 * i] = -b * w * w
            C[0, 2 * i + 1] = -b * 2 * z * w
        sys = _ss(A, B, C, [sum(b for _, _, b in modes)])
        if self.accel_lowpass_hz:
            wc = 2 * np.pi * self.accel_lowpass_hz
            if self.accel_lowpass_order == 1:
                sys = _series(sys, _first_order(-wc, wc, 1.0, 0.0))
            elif self.accel_lowpass_order == 2:
                sys = _series(sys, _second_order_ratio(None, 0.0, wc, np.sqrt(0.5), wc * wc))
            else:
                raise ValueError("accel_lowpass_order must be 1 or 2")
        if self.accel_antialias_hz:
            wc = 2 * np.pi * self.accel_antialias_hz
            sys = _series(sys, _first_order(-wc, wc, 1.0, 0.0))
        if self.accel_highpass_hz:
            wc = 2 * np.pi * self.accel_highpass_hz
            sys = _series(sys, _first_order(-wc, wc, -1.0, 1.0))
        return sys

    def state_space(self, w1_scale: float = 1.0) -> _SS:
        """Input: the valve input u [V]; outputs: theta [rad], the accelerometer's signal [m/s^2] (before delay)."""
        act = self._actuator()
        Ca = act.C  # theta
        if abs((Ca @ act.B).item()) > 0.0:
            raise AssertionError("theta/u must have relative degree >= 2")
        Cw = Ca @ act.A @ act.A
        Dw = Ca @ act.A @ act.B
        acc = self._accel_path(w1_scale)
        na, nb = act.A.shape[0], acc.A.shape[0]
        A = np.block([[act.A, np.zeros((na, nb))], [acc.B @ Cw, acc.A]])
        B = np.vstack([act.B, acc.B @ Dw])
        C = np.vstack([np.hstack([Ca, np.zeros((1, nb))]), np.hstack([acc.D @ Cw, acc.C])])
        D = np.vstack([np.zeros((1, 1)), acc.D @ Dw])
        return _SS(A, B, C, D)

    # ----- one DAQ period as an affine map
    def _period_maps(self, fs: float, oversample: int, w1_scale: float = 1.0):
        """The map of one DAQ period on z = [x_k, u_a, u_b] (u_a before the delayed command change inside the period,
        u_b after): rows 0..n-1 give x_{k+1}; then theta at the internal points the theta delay reads, then the
        accelerometer's signal at the points the accel delay reads. Returns (M, n, info)."""
        sys = self.state_space(w1_scale)
        n = sys.A.shape[0]
        T = 1.0 / fs
        dt = T / oversample
        q = int(np.floor(self.command_delay_s / T + 1e-9))
        delta = self.command_delay_s - q * T
        istar, phi = _delay_points(delta, dt)
        if istar >= oversample:  # (rounding) the change is at the next period's start
            q, istar, phi = q + 1, 0, 0.0
        Phi, Gam = _discretise(sys.A, sys.B, dt)
        if phi > 0:
            Phi1, Gam1 = _discretise(sys.A, sys.B, phi * dt)
            Phi2, Gam2 = _discretise(sys.A, sys.B, (1 - phi) * dt)
        ea = np.zeros((1, n + 2))
        ea[0, n] = 1.0
        eb = np.zeros((1, n + 2))
        eb[0, n + 1] = 1.0
        Mx = np.hstack([np.eye(n), np.zeros((n, 2))])
        pts = []  # output maps at internal points i = 0..os-1 (left limits)
        for i in range(oversample):
            left = ea if i <= istar else eb
            pts.append(sys.C @ Mx + sys.D @ left)
            if i < istar:
                Mx = Phi @ Mx + Gam @ ea
            elif i == istar and phi > 0:
                Mx = Phi2 @ (Phi1 @ Mx + Gam1 @ ea) + Gam2 @ eb
            else:
                Mx = Phi @ Mx + Gam @ eb
        mt, ft = _delay_points(self.theta_delay_s, dt)
        ma, fa = _delay_points(self.accel_delay_s, dt)
        it0, it1 = (-mt) % oversample, (-mt - 1) % oversample
        ia0, ia1 = (-ma) % oversample, (-ma - 1) % oversample
        M = np.vstack([Mx, pts[it0][0:1], pts[it1][0:1], pts[ia0][1:2], pts[ia1][1:2]])
        info = {"q": q, "n": n, "mt": mt, "ft": ft, "ma": ma, "fa": fa, "C": sys.C, "D": sys.D, "pts": pts}
        return M, n, info

    # ----- stability of the digital loop (exact, linear: the valve nonlinearity left out)
    def closed_loop_radius(self, fs: float, oversample: int = 10) -> float:
        """Spectral radius of the sampled closed loop (DAQ-rate lifted state: x_k .. x_{k-P}, v_{k-1} .. v_{k-Q})."""
        M, n, info = self._period_maps(fs, oversample)
        os_ = oversample
        q, mt, ft = info["q"], info["mt"], info["ft"]
        # theta_meas_k = (1 - ft) th[J] + ft th[J - 1], J = k os - mt; th at internal index j from period j // os
        J0 = -mt
        per0, per1 = J0 // os_, (J0 - 1) // os_  # (relative to k, <= 0)
        P = max(-per0, -per1, 0)
        Q = P + q + 2
        N = n * (P + 1) + Q
        xi = lambda p: slice(n * p, n * (p + 1))  # x_{k-p}
        vi = lambda j: n * (P + 1) + (j - 1)  # v_{k-j}, j = 1..Q
        pts = info["pts"]

        def theta_row(per: int, i: int, w: float) -> np.ndarray:
            """w * theta at internal point i of period k + per, as a row on the lifted state (v_k's coefficient apart)."""
            row = np.zeros(N + 1)  # last: coefficient of v_k
            y = pts[i][0]  # on [x, u_a, u_b] of that period: u_a = v_{k+per-q-1}, u_b = v_{k+per-q}
            row[xi(-per)] += w * y[:n]
            for coef, j in ((y[n], -(per - q - 1)), (y[n + 1], -(per - q))):
                if coef == 0.0:
                    continue
                if j == 0:
                    row[N] += w * coef
                else:
                    row[vi(j)] += w * coef
            return row

        th = theta_row(per0, J0 % os_, 1.0 - ft) + (theta_row(per1, (J0 - 1) % os_, ft) if ft else 0.0)
        if th[N] != 0.0:
            raise AssertionError("theta read at k depends on v_k")
        vrow = -self.kp_v_per_rad * th[:N]  # v_k on the lifted state (r = 0)
        T = np.zeros((N, N))
        Mx = M[:n]

        def v_of(j: int) -> np.ndarray:
            """v_{k-j} as a row on the lifted state (j = 0 is v_k)."""
            if j == 0:
                return vrow
            r = np.zeros(N)
            r[vi(j)] = 1.0
            return r

        T[xi(0)] = Mx[:, :n] @ np.eye(n, N) + np.outer(Mx[:, n], v_of(q + 1)) + np.outer(Mx[:, n + 1], v_of(q))
        for p in range(1, P + 1):
            T[xi(p), xi(p - 1)] = np.eye(n)
        T[vi(1)] = vrow
        for j in range(2, Q + 1):
            T[vi(j), vi(j - 1)] = 1.0
        return float(np.max(np.abs(np.linalg.eigvals(T))))

    def is_stable(self, fs: float, oversample: int = 10) -> bool:
        return self.closed_loop_radius(fs, oversample) < 1.0 - 1e-9

    @classmethod
    def drawn(
        cls, rng: np.random.Generator, *, spread: float = 0.15, fs: float = 1000.0, oversample: int = 10, max_draws: int = 200, **effects
    ) -> Rig:
        """Each eq 9.4 parameter uniform within +-``spread``; drawn again while the sampled loop is unstable."""
        for _ in range(max_draws):
            p = {k: v * (1.0 + spread * rng.uniform(-1.0, 1.0)) for k, v in EQ9_4.items()}
            rig = cls(params=p, **effects)
            if rig.is_stable(fs, oversample):
                return rig
        raise ValueError(f"no stable rig in {max_draws} draws with {effects}")

    # ----- simulation
    def simulate(
        self,
        r: np.ndarray,
        fs: float,
        *,
        oversample: int = 10,
        rng: np.random.Generator | None = None,
        encoder_bits: int | None = 16,
        theta_noise_sd: float = 0.0,
        accel_noise_sd: float = 2e-3,
        accel_bias: float = 0.0,
        accel_drift: tuple | None = None,
        hum: tuple | None = None,
        valve_noise_sd: float = 0.0,
        check_stable: bool = True,
    ) -> dict:
        """Closed-loop run of the excitation ``r`` [V] sampled at ``fs``.

        DAQ nuisances: ``encoder_bits`` (None: no quantisation; else 2 pi / 2^bits rad per count), white
        ``theta_noise_sd`` [rad] on the reading the controller uses, white ``accel_noise_sd`` [m/s^2]
        (needs ``rng``), ``accel_bias`` [m/s^2], ``accel_drift``: ("ramp", total) over the file or ("sine", f_hz,
        amplitude); ``hum``: (f_hz, accel amplitude, v amplitude) a mains sinusoid on the recorded accel and v
        (the v read-back; the valve gets the command); ``valve_noise_sd`` [V]: white noise added to the valve's input
        each DAQ period (process noise, not in the recorded v; off by default).

        Returns a dict of arrays t, v, theta, accel, r (and ``theta_true``, ``accel_true``: the sensor signals
        before quantisation, gain step, noise and offsets).
        """
        r = np.asarray(r, float)
        N = r.size
        if check_stable and not self.is_stable(fs, oversample):
            raise ValueError("the sampled position loop is unstable for this rig")
        if (theta_noise_sd or accel_noise_sd or hum or valve_noise_sd or accel_drift) and rng is None:
            rng = np.random.default_rng(0)
        law = valve_law(*self.valve_nonlinearity) if self.valve_nonlinearity else None
        kp = self.kp_v_per_rad
        q_enc = 2 * np.pi / 2**encoder_bits if encoder_bits else None
        th_noise = theta_noise_sd * rng.standard_normal(N) if theta_noise_sd else np.zeros(N)
        u_noise = valve_noise_sd * rng.standard_normal(N) if valve_noise_sd else np.zeros(N)

        drifting = bool(self.mode1_drift_fraction)
        block = max(1, int(round(self.drift_block_s * fs))) if drifting else N
        M, n, info = self._period_maps(fs, oversample)
        q, mt, ft, ma, fa = info["q"], info["mt"], info["ft"], info["ma"], info["fa"]
        os_ = oversample
        x = np.zeros(n)
        v = np.zeros(N)
        u = np.zeros(N)  # valve input N(v_k)
        th_pts = np.zeros((N, 2))  # theta at the two internal points the theta delay reads, per period
        ac_pts = np.zeros((N, 2))
        th_meas = np.zeros(N)
        th_true = np.zeros(N)
        z = np.zeros(n + 2)
        # theta at J = k os - mt: period (k os - mt) // os
        Jt = -mt
        dper_t0, dper_t1 = Jt // os_, (Jt - 1) // os_  # <= 0
        C_th = info["C"][0]
        t_total = N / fs
        for k in range(N):
            if drifting and k % block == 0:
                mid = (k + 0.5 * min(block, N - k)) / fs
                M, _, _ = self._period_maps(fs, oversample, 1.0 + self.mode1_drift_fraction * mid / t_total)
            # theta as read at t_k
            if dper_t0 == 0:
                a0 = C_th @ x  # (index 0 of this period; theta has no feedthrough)
            else:
                a0 = th_pts[k + dper_t0, 0] if k + dper_t0 >= 0 else 0.0
            if ft:
                a1 = th_pts[k + dper_t1, 1] if k + dper_t1 >= 0 else 0.0
                th_k = (1 - ft) * a0 + ft * a1
            else:
                th_k = a0
            th_true[k] = th_k
            tm = th_k if q_enc is None else q_enc * np.round(th_k / q_enc)
            tm += th_noise[k]
            th_meas[k] = tm
            vk = r[k] - kp * tm
            v[k] = vk
            uk = vk + u_noise[k]
            u[k] = law(uk) if law else uk
            ia, ib = k - q - 1, k - q
            z[:n] = x
            z[n] = u[ia] if ia >= 0 else 0.0
            z[n + 1] = u[ib] if ib >= 0 else 0.0
            out = M @ z
            x = out[:n]
            th_pts[k] = out[n : n + 2]
            ac_pts[k] = out[n + 2 : n + 4]
        # accelerometer at t_k - accel delay
        k = np.arange(N)
        Ja = k * os_ - ma
        p0 = Ja // os_
        acc = np.where(p0 >= 0, ac_pts[np.clip(p0, 0, None), 0], 0.0)
        if fa:
            p1 = (Ja - 1) // os_
            acc = (1 - fa) * acc + fa * np.where(p1 >= 0, ac_pts[np.clip(p1, 0, None), 1], 0.0)
        acc_true = acc.copy()
        t = k / fs
        if self.accel_gain_step:
            acc = acc * np.where(t >= self.accel_gain_step_at * t_total, 1.0 + self.accel_gain_step, 1.0)
        acc = acc + accel_bias
        if accel_drift:
            if accel_drift[0] == "ramp":
                acc = acc + accel_drift[1] * t / t_total
            elif accel_drift[0] == "sine":
                acc = acc + accel_drift[2] * np.sin(2 * np.pi * accel_drift[1] * t + (rng.uniform(0, 2 * np.pi) if rng is not None else 0.0))
            else:
                raise ValueError(f"accel_drift must be ('ramp', total) or ('sine', f_hz, amplitude), got {accel_drift!r}")
        v_rec = v.copy()
        if hum:
            fh, ah, vh = (tuple(hum) + (0.0,))[:3]
            ph = rng.uniform(0, 2 * np.pi)
            acc = acc + ah * np.sin(2 * np.pi * fh * t + ph)
            if vh:
                v_rec = v_rec + vh * np.sin(2 * np.pi * fh * t + ph + 0.3)
        if accel_noise_sd:
            acc = acc + accel_noise_sd * rng.standard_normal(N)
        return {"t": t, "v": v_rec, "theta": th_meas, "accel": acc, "r": r.copy(), "theta_true": th_true, "accel_true": acc_true}


# ------------------------------------------------------------------------------------------------ excitation


def swept_sine(
    fs: float,
    *,
    f_lo: float = 0.1,
    f_hi: float = 40.0,
    sweep_s: float = 120.0,
    amplitude_v: float = 0.1,
    n_records: int = 3,
    rest_s: float = 20.0,
    lead_s: float = 0.0,
    direction: str = "up",
    alternate: bool = False,
    fade_s: float = 1.0,
    fade_cycles: float = 2.0,
) -> tuple[np.ndarray, str]:
    """A logarithmic swept sine repeated ``n_records`` times: [lead] + n x [sweep, rest].

    Each sweep: ``sin(phase(t))`` with the instantaneous frequency ``f0 (f1/f0)^(t/T)`` (f0 = f_lo, f1 = f_hi up;
    the reverse down), faded in and out by raised cosines of ``min(fade_s, fade_cycles / f)`` at each end's
    frequency. ``alternate``: signs +, -, +, ... Returns (r, a one-line description).
    """
    if direction not in ("up", "down"):
        raise ValueError("direction must be 'up' or 'down'")
    f0, f1 = (f_lo, f_hi) if direction == "up" else (f_hi, f_lo)
    ns = int(round(sweep_s * fs))
    t = np.arange(ns) / fs
    k = np.log(f1 / f0)
    phase = 2 * np.pi * f0 * sweep_s / k * (np.exp(k * t / sweep_s) - 1.0)
    s = np.sin(phase)
    env = np.ones(ns)
    for f_end, at_start in ((f0, True), (f1, False)):
        nf = int(round(min(fade_s, fade_cycles / f_end) * fs))
        if nf > 1:
            ramp = 0.5 * (1 - np.cos(np.pi * np.arange(nf) / nf))
            if at_start:
                env[:nf] *= ramp
            else:
                env[ns - nf :] *= ramp[::-1]
    sweep = amplitude_v * s * env
    rest = np.zeros(int(round(rest_s * fs)))
    parts = [np.zeros(int(round(lead_s * fs)))]
    for i in range(n_records):
        sign = -1.0 if (alternate and i % 2) else 1.0
        parts += [sign * sweep, rest]
    r = np.concatenate(parts)
    text = (
        f"swept sine {f_lo:g}-{f_hi:g} Hz, {n_records} sweeps ({direction}, {sweep_s:g} s each"
        f"{', alternating sign' if alternate else ''}{f', {rest_s:g} s rest' if rest_s else ', back to back'}), {amplitude_v:g} V"
    )
    return r, text


# ------------------------------------------------------------------------------------------------------- CSV


def write_csv(path, data: dict, metadata: dict | None = None) -> None:
    """A time-series CSV per DATA_FORMATS.md: ``# key: value`` lines, header ``t,v,theta,accel,r``, one row a sample."""
    cols = ("t", "v", "theta", "accel", "r")
    arr = np.column_stack([np.asarray(data[c], float) for c in cols])
    if not np.all(np.isfinite(arr)):
        raise ValueError("non-finite values in the data")
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        for key, val in (metadata or {}).items():
            fh.write(f"# {key}: {val}\n")
        fh.write(",".join(cols) + "\n")
        fmt = "%.10g,%.9g,%.9g,%.9g,%.9g"
        chunk = 50000
        for i in range(0, arr.shape[0], chunk):
            fh.write("\n".join(fmt % tuple(row) for row in arr[i : i + chunk].tolist()))
            fh.write("\n")


# ------------------------------------------------------------------------------------------------ validation


def _alias_sum(H, f_hz: np.ndarray, fs: float, M: int, c: complex = 0.0, *, left: bool = True) -> np.ndarray:
    """Exact pulse transfer function at e^{j w T} of a continuous H behind a zero-order hold, sampled:
    ``sum_m H(j w_m) (1 - e^{-j w_m T})/(j w_m T)``, w_m = w + 2 pi m fs (|m| <= M), with H's value at infinity ``c``
    taken out and put back as the left-limit sample of a step (``c e^{-j w T}``)."""
    T = 1.0 / fs
    out = np.zeros(f_hz.size, complex)
    for m in range(-M, M + 1):
        fm = f_hz + m * fs
        wm = 2 * np.pi * fm
        Z = (1 - np.exp(-1j * wm * T)) / (1j * wm * T)
        out += (H(fm) - c) * Z
    return out + c * np.exp(-2j * np.pi * f_hz * T)


def _pulse(H, f_hz, fs, c=0.0, M=1000):
    """Richardson-extrapolated alias sum (the tail goes as 1/M)."""
    a, b = _alias_sum(H, f_hz, fs, M, c), _alias_sum(H, f_hz, fs, 2 * M, c)
    return 2 * b - a


def _spectra(d: dict, f_hz: np.ndarray, fs: float) -> dict:
    """DTFT of each channel at f_hz (the run starts and ends at rest, so these are exact)."""
    n = d["t"].size
    k = np.arange(n)
    E = np.exp(-2j * np.pi * np.outer(f_hz / fs, k))
    return {c: E @ d[c] for c in ("r", "v", "theta", "accel")}


def _err(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    e = np.log(a / b)
    return float(np.max(np.abs(e.real)) * 20 / np.log(10)), float(np.max(np.abs(e.imag)) * 180 / np.pi)


def validate(fs: float = 1000.0, oversample: int = 10) -> dict:
    """The rig against the analytic physics (module docstring): a clean, noiseless, unquantised run of one
    0.1-40 Hz sweep (120 s, then 30 s of rest), DTFTs at 0.15-38 Hz."""
    rig = Rig()
    r, _ = swept_sine(fs, sweep_s=120.0, n_records=1, rest_s=30.0, amplitude_v=0.1)
    quiet = dict(encoder_bits=None, accel_noise_sd=0.0, oversample=oversample)
    f = np.concatenate([np.geomspace(0.15, 10.0, 60), np.geomspace(10.0, 38.0, 30)[1:]])
    lo, hi = f < 10.0, f >= 10.0
    res = {}
    d0 = rig.simulate(r, fs, **quiet)
    S0 = _spectra(d0, f, fs)
    T = 1.0 / fs
    Gd = _pulse(rig.G, f, fs)
    p = rig.params
    c = sum(b for _, _, b in rig.si()["modes"]) * p["K1"] * DEG * p["wp"] ** 2 * p["tau"] / p["wz"] ** 2  # BG at s -> inf
    BGd = _pulse(lambda x: rig.Bx(x) * rig.G(x), f, fs, c=c)
    cl_th = Gd / (1 + rig.kp_v_per_rad * Gd)
    cl_ac = BGd / (1 + rig.kp_v_per_rad * Gd)
    s = 2j * np.pi * f
    for name, data, model in (
        ("theta/r vs exact sampled closed loop (ZOH pulse TF)", S0["theta"] / S0["r"], cl_th),
        ("accel/r vs exact sampled closed loop (ZOH pulse TF)", S0["accel"] / S0["r"], cl_ac),
        ("theta/v vs exact ZOH pulse TF", S0["theta"] / S0["v"], Gd),
        ("theta/v vs G(jw) e^{-jwT/2} (half-sample hold)", S0["theta"] / S0["v"], rig.G(f) * np.exp(-s * T / 2)),
        ("theta/v vs G(jw) (no hold)", S0["theta"] / S0["v"], rig.G(f)),
        ("accel/theta vs B(jw)", S0["accel"] / S0["theta"], rig.Bx(f)),
    ):
        res[name] = {"<10 Hz": _err(data[lo], model[lo]), "10-38 Hz": _err(data[hi], model[hi])}
    # the oversampling changes nothing for a clean rig (the command is constant over a DAQ period)
    d1 = rig.simulate(r, fs, **{**quiet, "oversample": 2 * oversample})
    res["oversample 2x: max |theta diff| / max|theta|"] = float(np.max(np.abs(d1["theta"] - d0["theta"])) / np.max(np.abs(d0["theta"])))

    # sampled accel/theta against B(jw): the command's staircase passes straight through xdd/v (biproper: the
    # notebook's actuator has relative degree 2, its base s^2 at high frequency) and aliases (exact: accel/r above)
    fb = np.array([0.3, 0.5, 1.0, 2.0, 5.0, 10.0, 15.0, 20.0, 30.0, 40.0])
    Sb = _spectra(d0, fb, fs)
    eb = np.log(Sb["accel"] / Sb["theta"] / rig.Bx(fb))
    res["accel/theta vs B(jw) by frequency [Hz: dB, deg]"] = {
        f"{x:g}": (round(float(20 * e.real / np.log(10)), 4), round(float(np.degrees(e.imag)), 3)) for x, e in zip(fb, eb)
    }

    def at(eff, num, den, ff):
        d = replace(rig, **eff).simulate(r, fs, **quiet)
        Sa, Sb = _spectra(d, ff, fs), _spectra(d0, ff, fs)
        return (Sa[num] / Sa[den]) / (Sb[num] / Sb[den])

    def db_deg(x):
        return f"{20 * np.log10(abs(x)):+.3f} dB {np.degrees(np.angle(x)):+.2f} deg"

    checks = {}
    BG = lambda x: rig.Bx(x) * rig.G(x)
    for eff, ff, c_eff, label in (
        ({"accel_lowpass_hz": 30.0}, 30.0, 0.0, "accel LP1 30 Hz"),
        ({"accel_lowpass_hz": 60.0, "accel_lowpass_order": 2}, 30.0, 0.0, "accel LP2 60 Hz"),
        ({"accel_highpass_hz": 1.0}, 1.0, c, "accel HP 1 Hz"),
    ):
        fr = np.array([ff])
        g = at(eff, "accel", "theta", fr)[0]
        L = replace(rig, **eff).accel_sensor
        exact = (_pulse(lambda x: BG(x) * L(x), fr, fs, c=c_eff) / _pulse(BG, fr, fs, c=c))[0]  # noqa: B023 - called within this iteration
        checks[f"{label}: accel/theta change at {ff:g} Hz: sim | exact sampled | continuous filter"] = (db_deg(g), db_deg(exact), db_deg(L(fr)[0]))
    ff = np.array([2.0, 8.0, 20.0])
    for eff, num, den, T_d in (
        ({"command_delay_s": 0.004}, "theta", "v", 0.004),
        ({"theta_delay_s": 0.003}, "theta", "v", 0.003),
        ({"accel_delay_s": 0.003}, "accel", "theta", 0.003),
        ({"command_delay_s": 0.00253}, "theta", "v", 0.00253),
    ):
        g = at(eff, num, den, ff)
        checks[f"{eff}: {num}/{den} phase at 2/8/20 Hz vs -360 f T"] = tuple(
            f"{np.degrees(np.angle(x)):.3f} vs {-360 * fq * T_d:.3f} deg, {20 * np.log10(abs(x)):+.4f} dB" for x, fq in zip(g, ff)
        )
    g = at({"valve_hz": 50.0, "valve_zeta": 0.7}, "theta", "v", ff)
    wv = 2 * np.pi * 50.0
    hv = wv**2 / ((2j * np.pi * ff) ** 2 + 1.4 * wv * 2j * np.pi * ff + wv**2)
    checks["valve 50 Hz z0.7: theta/v change vs valve TF at 2/8/20 Hz [dB, deg]"] = tuple(
        f"{20 * np.log10(abs(x)):+.3f}/{20 * np.log10(abs(y)):+.3f}, {np.degrees(np.angle(x)):.2f}/{np.degrees(np.angle(y)):.2f}"
        for x, y in zip(g, hv)
    )
    g = at({"leak_per_s": -0.5}, "theta", "v", np.array([0.2, 1.0]))
    sl = 2j * np.pi * np.array([0.2, 1.0])
    hl = sl / (sl + 0.5)
    checks["leak -0.5 1/s: theta/v change vs s/(s+0.5) at 0.2/1 Hz [dB, deg]"] = tuple(
        f"{20 * np.log10(abs(x)):+.3f}/{20 * np.log10(abs(y)):+.3f}, {np.degrees(np.angle(x)):.2f}/{np.degrees(np.angle(y)):.2f}"
        for x, y in zip(g, hl)
    )
    res["effects"] = checks
    return res


if __name__ == "__main__":
    import json
    import sys

    fs = float(sys.argv[1]) if len(sys.argv) > 1 else 1000.0
    print(json.dumps(validate(fs), indent=1, default=str))
