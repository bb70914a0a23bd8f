"""Vibration and creep sub-models of the integrated PEA model, and a virtual single stack for validation.

Seed: ``002_7d89b7147aad52e4.txt`` Sect. 3-4: u --[RI hysteresis]--> f --[vibration, eq. 12]--> x1
--[creep G_c = 1 + G2, eqs. 13, 17]--> x  (Fig. 4).

Eq. (12) as printed, ``2 zeta omega_n x1' + omega_n^2 x1 = f``, lost its second-derivative term in the OCR (the text
calls it a second-order system and estimates x1' and x1''). We use the unity-DC-gain second-order form

    x1'' / omega_n^2 + (2 zeta / omega_n) x1' + x1 = f,

so f is in displacement units and F(M_max) is the quasi-static displacement. Phase: -atan2(2 zeta w wn, wn^2 - w^2).

Creep (Sect. 4.4): ARX with 4 poles, 1 zero (2 numerator coefficients), 1 sample delay, T_s = 0.1 s, fitted by least
squares to x2 = x - x1 with input x1; converted to continuous time by the ZOH inverse (matrix logarithm, MATLAB's
d2c default), giving the eq. (17) form G2(s) = (c3 s^3 + c2 s^2 + c1 s + c0) / (s^4 + d3 s^3 + ... + d0).
Every continuous system is simulated with the exact ZOH discretisation at the simulation step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.signal

from . import _ri_kernels as K
from .ri import RIModel

__all__ = ["second_order_phase", "fit_second_order_phase", "VibrationModel", "force_from_displacement",
           "fit_arx", "d2c_zoh", "ARXCreep", "fit_arx_creep", "RIActuatorModel", "VirtualStack",
           "measure_phase", "validation_table", "ABG_PAPER"]

#: alpha-beta-gamma gains of 002_7d89b7147aad52e4.txt Sect. 4.3
ABG_PAPER = (8.7e-2, 3.9e-3, 2.4e-3)


# ---------------------------------------------------------------------------------------------- vibration
def second_order_phase(freq_hz, zeta: float, omega_n: float) -> np.ndarray:
    """Phase [rad] of omega_n^2 / (s^2 + 2 zeta omega_n s + omega_n^2) at s = j 2 pi f, in (-pi, 0]."""
    w = 2 * np.pi * np.asarray(freq_hz, float)
    return -np.arctan2(2 * zeta * omega_n * w, omega_n ** 2 - w ** 2)


def fit_second_order_phase(freq_hz, phase_rad) -> tuple[float, float]:
    """Least-squares fit of (zeta, omega_n [rad/s]) of eq. (12) to a measured phase-frequency response.

    ``phase_rad``: phase of x relative to u [rad] (lag negative; wrapped values are unwrapped into (-pi, 0]).
    Starts from a grid search over omega_n (log-spaced, 0.3x-30x the measured frequency span) and zeta.
    """
    f = np.asarray(freq_hz, float)
    ph = np.asarray(phase_rad, float)
    ph = np.where(ph > 0, ph - 2 * np.pi, ph)
    if f.size < 2:
        raise ValueError("fit_second_order_phase: need at least 2 frequencies")

    def res(th):
        return second_order_phase(f, np.exp(th[0]), np.exp(th[1])) - ph

    best = None
    for wn in 2 * np.pi * np.geomspace(0.3 * f.min(), 30 * f.max(), 60):
        for z in (0.02, 0.05, 0.1, 0.2, 0.4, 0.7, 1.0, 2.0):
            c = float(np.sum(res([np.log(z), np.log(wn)]) ** 2))
            if best is None or c < best[0]:
                best = (c, np.log(z), np.log(wn))
    sol = scipy.optimize.least_squares(res, [best[1], best[2]], method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14)
    return float(np.exp(sol.x[0])), float(np.exp(sol.x[1]))


def _zoh(A, B, dt):
    n = A.shape[0]
    Maug = np.zeros((n + 1, n + 1))
    Maug[:n, :n] = A
    Maug[:n, n] = B
    E = scipy.linalg.expm(Maug * dt)
    return E[:n, :n], E[:n, n].copy()


@dataclass
class VibrationModel:
    """Eq. (12) (unity DC gain form, see module docstring); zeta [-], omega_n [rad/s]."""

    zeta: float
    omega_n: float

    def state_space(self):
        w, z = self.omega_n, self.zeta
        return np.array([[0.0, 1.0], [-w * w, -2 * z * w]]), np.array([0.0, w * w]), np.array([1.0, 0.0]), 0.0

    def simulate(self, f, dt: float, x0=None) -> np.ndarray:
        """x1 from f with the exact ZOH discretisation at step dt [s] (f held over each step); starts at rest."""
        A, B, C, D = self.state_space()
        Ad, Bd = _zoh(A, B, dt)
        f = np.ascontiguousarray(f, dtype=float)
        y, _ = K.dss_kernel(Ad, Bd, C, D, f, np.zeros(2) if x0 is None else np.asarray(x0, float))
        return y


def force_from_displacement(x1, dt: float, zeta: float, omega_n: float, method: str = "savgol",
                            abg=ABG_PAPER, window: int = 21, polyorder: int = 4) -> np.ndarray:
    """Sect. 4.3: 'measured' f = x1 + (2 zeta/omega_n) x1' + x1''/omega_n^2 from the measured x1.

    ``method="savgol"`` (default): x1, x1', x1'' from a zero-phase Savitzky-Golay filter (low-pass then
    differentiate, the paper's first option). ``method="abg"``: alpha-beta-gamma filter with gains ``abg``. The
    paper's printed gains (8.7e-2, 3.9e-3, 2.4e-3) give an UNSTABLE filter in the usual conventions (spectral radius
    1.02-1.06 for acceleration gain gamma/(2T^2), gamma/T^2, 2 gamma/T^2), so they are presumably garbled; the abg
    option is kept for user-supplied gains and raises if the loop is unstable.
    """
    x1 = np.ascontiguousarray(x1, dtype=float)
    if method == "savgol":
        w = min(window, x1.size - (1 - x1.size % 2))
        x = scipy.signal.savgol_filter(x1, w, polyorder, deriv=0, mode="interp")
        v = scipy.signal.savgol_filter(x1, w, polyorder, deriv=1, delta=dt, mode="interp")
        a = scipy.signal.savgol_filter(x1, w, polyorder, deriv=2, delta=dt, mode="interp")
    elif method == "abg":
        al, be, ga = map(float, abg)
        F = np.array([[1, 1, 0.5], [0, 1, 1], [0, 0, 1.0]])
        Mloop = (np.eye(3) - np.outer([al, be, ga / 2], [1, 0, 0])) @ F
        rho = float(np.max(np.abs(np.linalg.eigvals(Mloop))))
        if rho >= 1.0:
            raise ValueError(f"force_from_displacement: alpha-beta-gamma gains {abg} give an unstable filter "
                             f"(spectral radius {rho:.4f} >= 1); use method='savgol' or stable gains")
        x, v, a = K.abg_filter_kernel(x1, float(dt), al, be, ga)
    else:
        raise ValueError(f"force_from_displacement: unknown method {method!r} (use 'savgol' or 'abg')")
    return x + (2 * zeta / omega_n) * v + a / omega_n ** 2


# ---------------------------------------------------------------------------------------------- creep
def fit_arx(u, y, na: int = 4, nb: int = 2, nk: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ARX: y[t] + a1 y[t-1] + ... + a_na y[t-na] = b1 u[t-nk] + ... + b_nb u[t-nk-nb+1].

    Returns (a = [1, a1..a_na], b = [b1..b_nb])."""
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    t0 = max(na, nk + nb - 1)
    rows = [np.concatenate([-y[t - na:t][::-1], u[t - nk - nb + 1:t - nk + 1][::-1]]) for t in range(t0, y.size)]
    A = np.asarray(rows)
    norms = np.linalg.norm(A, axis=0)
    norms[norms == 0] = 1.0
    th, *_ = np.linalg.lstsq(A / norms, y[t0:], rcond=None)
    th = th / norms
    return np.concatenate([[1.0], th[:na]]), th[na:]


def d2c_zoh(num_d, den_d, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Inverse ZOH discretisation (MATLAB d2c 'zoh'): log of the augmented matrix [[Ad, Bd], [0, 1]] / Ts.

    num_d, den_d: discrete transfer function in powers of z^-1 (equal length after padding).
    Returns continuous (num, den) with den monic. Raises ValueError if a discrete pole is on the negative real axis.
    """
    num_d = np.asarray(num_d, float)
    den_d = np.asarray(den_d, float)
    n = max(num_d.size, den_d.size)
    num_d = np.pad(num_d, (0, n - num_d.size))
    den_d = np.pad(den_d, (0, n - den_d.size))
    poles = np.roots(den_d)
    if np.any((np.abs(poles.imag) < 1e-12) & (poles.real <= 0)):
        raise ValueError(f"d2c_zoh: discrete pole on the negative real axis {poles}; no ZOH-equivalent continuous model")
    Ad, Bd, Cd, Dd = scipy.signal.tf2ss(num_d, den_d)
    ns = Ad.shape[0]
    Maug = np.zeros((ns + 1, ns + 1))
    Maug[:ns, :ns] = Ad
    Maug[:ns, ns] = Bd[:, 0]
    Maug[ns, ns] = 1.0
    Lg = np.real(scipy.linalg.logm(Maug)) / Ts
    A, B = Lg[:ns, :ns], Lg[:ns, ns:ns + 1]
    num, den = scipy.signal.ss2tf(A, B, Cd, Dd)
    num = np.atleast_1d(np.squeeze(num))
    return num / den[0], den / den[0]


@dataclass
class ARXCreep:
    """Creep sub-model G2 (Sect. 4.4, eq. 17): discrete ARX (a, b) at Ts and its continuous (num, den)."""

    a: np.ndarray
    b: np.ndarray
    Ts: float
    num: np.ndarray
    den: np.ndarray

    def simulate(self, x1, dt: float) -> np.ndarray:
        """x2 = G2 x1 with the exact ZOH discretisation of the continuous G2 at step dt [s]; starts at rest."""
        A, B, C, D = scipy.signal.tf2ss(self.num, self.den)
        Ad, Bd = _zoh(A, B[:, 0], dt)
        y, _ = K.dss_kernel(np.ascontiguousarray(Ad), np.ascontiguousarray(Bd), np.ascontiguousarray(C[0]),
                            float(D[0, 0]), np.ascontiguousarray(x1, dtype=float), np.zeros(A.shape[0]))
        return y

    def to_dict(self) -> dict:
        return {"a": self.a.tolist(), "b": self.b.tolist(), "Ts": self.Ts, "num": self.num.tolist(),
                "den": self.den.tolist()}


def fit_arx_creep(u, y, Ts: float = 0.1, na: int = 4, nb: int = 2, nk: int = 1) -> ARXCreep:
    """Sect. 4.4: ARX (4 poles, 1 zero, 1 sample delay) on (u = x1, y = x2 = x - x1) sampled at Ts [s],
    converted to continuous time with ``d2c_zoh``."""
    a, b = fit_arx(u, y, na, nb, nk)
    num_d = np.concatenate([np.zeros(nk), b])
    num, den = d2c_zoh(num_d, a, Ts)
    return ARXCreep(a=a, b=b, Ts=float(Ts), num=num, den=den)


# ---------------------------------------------------------------------------------------------- integrated model
@dataclass
class RIActuatorModel:
    """Fig. 4: u -> RI hysteresis f -> vibration x1 (eq. 12) -> creep x = x1 + G2 x1 (eq. 13)."""

    hysteresis: RIModel
    zeta: float
    omega_n: float
    creep: ARXCreep | None = None

    def simulate(self, u, dt: float, return_parts: bool = False):
        f = self.hysteresis(u)
        x1 = VibrationModel(self.zeta, self.omega_n).simulate(f, dt)
        x = x1 + (self.creep.simulate(x1, dt) if self.creep is not None else 0.0)
        return (x, {"f": f, "x1": x1}) if return_parts else x


# ---------------------------------------------------------------------------------------------- virtual stack
@dataclass
class VirtualStack:
    """Virtual single piezo stack used by ``validate-table`` (selfsense.sim has no single-stack mode).

    Documented truth model (not an RI model, so the validation is not circular):
    * hysteresis: asymmetric one-sided Bouc-Wen, x_h = d u (1 + c2 u) - h, dh = (alpha d - beta sgn(du) h -
      gamma |h|) du, starting at h = 0 (gives an initial ascending curve and non-congruent loops);
      d = 0.2 um/V, c2 = 2e-3 1/V, alpha = 0.25, beta = 0.02 1/V, gamma = 0.005 1/V (~15 um at 70 V);
    * vibration: 2nd-order mode zeta = 0.35, f_n = 1.5 kHz (unity DC gain);
    * creep: x = x1 + G2 x1 with G2 = k_c / (tau s + 1), k_c = 0.03, tau = 1.5 s;
    * noise: white, sigma = 1 nm, numpy default_rng(seed).
    Units: u [V], output [um].
    """

    d: float = 0.2
    c2: float = 2e-3
    alpha: float = 0.25
    beta: float = 0.02
    gamma: float = 0.005
    zeta: float = 0.35
    f_n: float = 1500.0
    k_c: float = 0.03
    tau_c: float = 1.5
    noise_um: float = 1e-3
    n_sub: int = 8

    def simulate(self, u, dt: float, seed: int = 0, noise: bool = True, return_parts: bool = False):
        u = np.ascontiguousarray(u, dtype=float)
        xh, _ = K.bouc_wen_kernel(u, self.d, self.alpha, self.beta, self.gamma, self.c2, self.n_sub, 0.0, 0.0)
        x1 = VibrationModel(self.zeta, 2 * np.pi * self.f_n).simulate(xh, dt)
        A, B = np.array([[-1.0 / self.tau_c]]), np.array([self.k_c / self.tau_c])
        Ad, Bd = _zoh(A, B, dt)
        x2, _ = K.dss_kernel(Ad, Bd, np.array([1.0]), 0.0, x1, np.zeros(1))
        x = x1 + x2
        if noise and self.noise_um > 0:
            x = x + self.noise_um * np.random.default_rng(seed).standard_normal(x.size)
        return (x, {"f": xh, "x1": x1, "x2": x2}) if return_parts else x


def measure_phase(plant, freqs_hz, dt: float, bias: float = 35.0, amp: float = 5.0, n_periods: int = 8,
                  seed: int = 0) -> np.ndarray:
    """Phase [rad] of the fundamental of plant(u) relative to u = bias + amp sin(2 pi f t), from the last half of
    the periods (DFT projection over whole periods). The bias is approached by a slow ramp first."""
    out = []
    for i, f in enumerate(freqs_hz):
        n_per = int(round(1.0 / (f * dt)))
        dt_f = 1.0 / (f * n_per)  # an integer number of samples per period
        ramp = np.linspace(0.0, bias, 200)
        t = np.arange(n_periods * n_per) * dt_f
        u = np.concatenate([ramp, bias + amp * np.sin(2 * np.pi * f * t)])
        y = plant(u, dt_f, seed + i)[ramp.size:]
        k = slice((n_periods // 2) * n_per, n_periods * n_per)
        ph = np.exp(-2j * np.pi * f * t[k])
        Y = np.sum((y[k] - y[k].mean()) * ph)
        U = np.sum((u[ramp.size:][k] - bias) * ph)
        out.append(float(np.angle(Y / U)))
    return np.asarray(out)


def validation_table(seed: int = 0, fs: float = 20_000.0, freqs=(50, 100, 200, 300, 400, 500),
                     v_max: float = 70.0):
    """RI paper Table 2 style validation on ``VirtualStack``: identify the vibration (phase fit), the RI hysteresis
    (protocol eq. 14, f from the alpha-beta-gamma filter) and the creep (30 V step for 30 s, ARX at 0.1 s), then
    compare model and virtual measurement for u = v_max/2 (1 - cos 2 pi f t), 3 periods, errors over the last two.
    Returns (rows, description)."""
    stack = VirtualStack()
    dt = 1.0 / fs

    def plant(u, dt_, s):
        return stack.simulate(u, dt_, seed=seed * 1000 + s)

    # 1) vibration: phase-frequency response
    fr = np.array([20, 50, 100, 200, 400, 700, 1000, 1500, 2000, 3000], float)
    ph = measure_phase(plant, fr, dt, seed=1)
    zeta, wn = fit_second_order_phase(fr, ph)
    # 2) hysteresis: identification protocol from the virgin state, f from eq. (12) + abg filter
    from .ri_identify import fit_protocol, identification_protocol, fit_line, error_metrics
    records, raw = [], []
    for i, (vpp, u) in enumerate(identification_protocol(v_max=v_max, v_step=5.0, freq=100.0, fs=fs)):
        x = plant(u, dt, 100 + i)
        records.append((u, force_from_displacement(x, dt, zeta, wn)))
        raw.append((u, x))
    H = fit_protocol(records, m_step=5.0)
    # 3) creep: 30 V step for 30 s, sampled at Ts = 0.1 s
    dt_c = 1e-3
    u_step = np.full(int(30.0 / dt_c), 30.0)
    x_meas = plant(u_step, dt_c, 7)
    x1_mod = VibrationModel(zeta, wn).simulate(H(u_step), dt_c)
    dec = int(round(0.1 / dt_c))
    creep, order = None, None
    for na, nb in ((4, 2), (2, 2), (1, 1)):  # paper order first; lower orders if d2c has no ZOH equivalent
        try:
            creep = fit_arx_creep(x1_mod[::dec], (x_meas - x1_mod)[::dec], Ts=0.1, na=na, nb=nb)
            order = (na, nb, 1)
            break
        except ValueError:
            continue
    model = RIActuatorModel(H, zeta, wn, creep)
    line = fit_line(np.concatenate([r[0] for r in raw]), np.concatenate([r[1] for r in raw]))
    rows = []
    for j, f in enumerate(freqs):
        n_per = int(round(fs / f))
        t = np.arange(3 * n_per + 1) * dt
        u = v_max / 2 * (1 - np.cos(2 * np.pi * f * t))
        x = plant(u, dt, 500 + j)
        xm = model.simulate(u, dt)
        k = slice(n_per, None)
        e = xm[k] - x[k]
        rng = float(np.ptp(x[k]))
        rows.append({"freq_hz": float(f), "rms_um": float(np.sqrt(np.mean(e ** 2))),
                     "max_um": float(np.max(np.abs(e))), "rms_pct": float(100 * np.sqrt(np.mean(e ** 2)) / rng),
                     "max_pct": float(100 * np.max(np.abs(e)) / rng),
                     "line_rms_pct": error_metrics(x[k], line(u[k]))[0]})
    info = (f"Virtual single stack (ri_dynamics.VirtualStack: asymmetric Bouc-Wen + 2nd-order mode zeta=0.35, "
            f"f_n=1.5 kHz + creep k_c=0.03, tau=1.5 s, 1 nm noise, seed={seed}); fs={fs:g} Hz. Identified: "
            f"zeta={zeta:.4f}, f_n={wn / 2 / np.pi:.1f} Hz; RI from protocol eq. (14) (Vpp 5-70 V step 5, 100 Hz, "
            f"m grid 5 V); creep ARX{order} at 0.1 s (ARX(4,2,1) of the paper is tried first and dropped when a "
            f"discrete pole is negative real) -> G2 num={np.array2string(creep.num, precision=4)}, "
            f"den={np.array2string(creep.den, precision=4)}. "
            f"Validation input u = 35 (1 - cos 2 pi f t) V, 3 periods from the virgin state, errors over the "
            f"last 2 periods.")
    return rows, info
