"""A small in-memory virtual tweezer for the gap benchmark (fallback when ``selfsense.sim`` offers no in-memory
scenario API, and the fast tier's generator).

Physics (SI): the tip obeys thesis ``000_18d138f03f1777c3.txt`` eq. (52) with the eq. (55) convention,
``dx = A1 Q + A2 V_p``, ``f = B21 (Q - C V_p)`` (C = n_A C_p), closed by the load: free ``f = 0``, blocked
``dx = 0``, object ``f = k (dx - g)_+``. The hysteresis is generated on the *voltage* side,
``V_p = V - h[V]`` with h a weighted play sum on V plus a saturating term (not the estimator's H(q) form).
Effects are injected with generator forms that differ from the diagnostic library (FORMS.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .signals import lowpass

__all__ = ["TOY_EFFECTS", "OPEN_SET", "toy_rig", "simulate_case", "draw_scenario"]

N_A, C_P = 5, 0.25e-6
CT = N_A * C_P
A1, A2 = -1000.0, 1.292e-3           # m/C, m/V  -> free 6.3 mm at 150 V
B21 = 1.6e4                           # N/C       -> blocked ~0.1 N at 150 V
VMAX = 150.0

#: library effects the toy can inject (name -> unit magnitude at m = 1, roughly the noise floor)
TOY_EFFECTS = ("slow.creep", "slow.leakage", "slow.offset_drift", "slow.absorption", "slow.temperature",
               "rate.mechanism_mode", "rate.amplifier", "hysteresis.one_sided", "hysteresis.preload",
               "hysteresis.few_operators", "load.cross_terms", "load.stress_hysteresis")
#: effects outside the library (open-set tier)
OPEN_SET = ("open.backlash", "open.dead_zone", "open.second_mode")


def toy_rig() -> dict:
    return {"n_actuators": N_A, "amplifier_gain": 15.0, "shunt_resistance_ohm": 1000.0,
            "actuator_catalog": {"capacitance_f": C_P, "free_displacement_m": 10e-6, "blocked_force_n": 240.0,
                                 "stiffness_n_per_m": 24e6, "max_voltage_v": VMAX},
            "tip_free_displacement_m": 6.3e-3}


def _play_np(x, r, z0):
    from selfsense.hysteresis.operators import play_operator

    return play_operator(x, r, z0)


def _drive(kind: str, t: np.ndarray, rng) -> np.ndarray:
    T = t[-1]
    if kind == "sine":      # decaying sine (nested loops), ~1 Hz
        env = 0.5 * (1 + 0.6 * np.cos(2 * np.pi * t / T))
        v = 0.5 * VMAX * (1 - np.cos(2 * np.pi * 1.2 * t)) * env
    elif kind == "steps":   # symmetric up/down steps with holds at 0 V and high V
        levels = np.array([0, 0.5, 1.0, 0.5, 0, 0.75, 0.25, 0.9, 0]) * VMAX
        levels = np.concatenate([levels, rng.permutation(levels[1:-1]), [0]])
        k = np.minimum((t / T * len(levels)).astype(int), len(levels) - 1)
        v = lowpass(levels[k], 0.01, t[1] - t[0])
    else:                   # mixed: sine bursts + ramps
        v = 0.5 * VMAX * (1 - np.cos(2 * np.pi * 0.7 * t)) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.23 * t))
        v += 0.1 * VMAX * np.sin(2 * np.pi * 3.1 * t) * (v > 0.2 * VMAX)
    return np.clip(v, 0, VMAX)


@dataclass
class _Trial:
    name: str
    role: str
    tip: str
    reference: str
    signal: str
    k_obj: float = 0.0
    gap: float = 0.0


PROTOCOL = (
    _Trial("cal_free", "calibration", "free", "displacement", "mixed"),
    _Trial("cal_blocked", "calibration", "blocked", "force", "sine"),
    _Trial("val_free", "validation", "free", "displacement", "steps"),
    _Trial("val_blocked", "validation", "blocked", "force", "steps"),
    _Trial("val_object", "validation", "object", "force", "mixed", k_obj=40.0, gap=2.0e-3),
)


def _second_order(x, dt, f0, zeta):
    """Exact-ish 2nd-order low-pass (bilinear transform) with unit DC gain."""
    from scipy.signal import bilinear, lfilter

    w = 2 * np.pi * f0
    b, a = bilinear([w * w], [1, 2 * zeta * w, w * w], 1 / dt)
    return lfilter(b, a, x - x[0]) + x[0]


def _trial(tr: _Trial, effects: dict, rng, T: float, fs: float, t0: float) -> pd.DataFrame:
    n = int(T * fs)
    dt = 1 / fs
    t = np.arange(n) * dt
    n_relay = int(0.1 * fs)
    Vc = _drive(tr.signal, t, rng)
    Vc[:n_relay] = 0.0
    relay = np.zeros(n)
    relay[:n_relay] = 1
    # amplifier (terminal voltage)
    Vt = Vc.copy()
    if "rate.amplifier" in effects:
        m = effects["rate.amplifier"]
        slew = 3.0e4 / m ** 0.5                       # V/s slew limit
        y = np.empty(n); y[0] = Vc[0]
        for i in range(1, n):
            y[i] = y[i - 1] + np.clip(Vc[i] - y[i - 1], -slew * dt, slew * dt)
        tau = 1.0e-5 * m                              # 2nd-order bandwidth 1/(2 pi tau)
        Vt = y - 1.4 * tau * np.gradient(y, dt) + (tau ** 2) * np.gradient(np.gradient(y, dt), dt)
    if "open.dead_zone" in effects:
        m = effects["open.dead_zone"]
        dz = 0.0005 * VMAX * m
        Vt = np.maximum(Vt - dz, 0) * VMAX / (VMAX - dz)
    # hysteresis on the voltage side
    nfine = 6
    r = VMAX * np.arange(nfine) / nfine
    w = np.exp(-np.arange(nfine) / (0.3 * nfine))
    w = 0.12 * w / w.sum()
    if "hysteresis.few_operators" in effects:   # sharp reversal corners: many small thresholds (1-8 % of range)
        r = np.concatenate([r, VMAX * np.linspace(0.01, 0.08, 8)])
        w = np.concatenate([w, np.full(8, 0.0015 * effects["hysteresis.few_operators"] / 8)])
    z0 = r * 0.0
    if "hysteresis.preload" in effects:
        z0 = r * min(0.03 * effects["hysteresis.preload"], 1.0)
    P = _play_np(Vt, r, z0)
    h = P @ w * 1.0 + 0.04 * Vt**2 / VMAX
    if "hysteresis.one_sided" in effects:
        runmax = np.maximum.accumulate(Vt)
        h = h + 0.001 * effects["hysteresis.one_sided"] * (runmax - Vt) * (1 - Vt / VMAX)
    Vp = Vt - h
    Ceff = CT * (1 + (0.002 * effects["load.cross_terms"] if "load.cross_terms" in effects else 0))
    ta = np.maximum(t - t[n_relay], 0)  # self-heating during the trial (each trial follows a rest)
    if "slow.temperature" in effects:
        dT = effects["slow.temperature"] * 3 * (1 - np.exp(-ta / 10.0))
        Ceff = Ceff * (1 + 0.002 * dT)
    # load closure
    if tr.tip == "free":
        Q = Ceff * Vp
    elif tr.tip == "blocked":
        Q = -(A2 / A1) * Vp
    else:
        Q = Ceff * Vp
        dx0 = A1 * Q + A2 * Vp
        c = dx0 > tr.gap
        k = tr.k_obj
        Qc = (Vp * (B21 * Ceff + k * A2) - k * tr.gap) / (B21 - k * A1)
        Q = np.where(c, Qc, Q)
    if "load.stress_hysteresis" in effects and tr.tip != "free":
        f0 = B21 * (Q - Ceff * Vp)
        Vp = Vp - 0.004 * effects["load.stress_hysteresis"] * (f0 / 0.1) * h
        Q = np.where(Q != Ceff * Vp, -(A2 / A1) * Vp, Q) if tr.tip == "blocked" else Q
    dx = A1 * Q + A2 * Vp
    f = B21 * (Q - Ceff * Vp)
    if tr.tip == "free":
        f = np.zeros(n)
    if tr.tip == "blocked":
        dx = np.zeros(n)
    # creep of the actuator stroke (multi-exponential, fractional-like weights)
    if "slow.creep" in effects:
        m = effects["slow.creep"]
        taus = np.array([0.03, 0.3, 3.0, 30.0])
        wts = taus ** -0.25
        wts = wts / wts.sum()
        stroke = Vp / VMAX
        cr = sum(wk * (stroke - lowpass(stroke, tk, dt)) for wk, tk in zip(wts, taus))
        dx = dx + 0.1 * m * 6.3e-3 * cr * (tr.tip != "blocked")
        f = f + 0.1 * m * 0.1 * cr * (tr.tip != "free")
    if "rate.mechanism_mode" in effects:
        f0 = 40.0 / effects["rate.mechanism_mode"] ** 0.5
        dx = _second_order(dx, dt, f0, 0.15)
        f = _second_order(f, dt, f0, 0.15) if tr.tip != "free" else f
    if "open.second_mode" in effects:
        m = effects["open.second_mode"]
        osc = _second_order(dx + f * 0.05, dt, 9.0, 0.03) - (dx + f * 0.05)
        dx = dx + 0.05 * m * osc * (tr.tip != "blocked")
        f = f + 0.05 * m * osc * 20 * (tr.tip != "free")
    if "open.backlash" in effects and tr.tip != "blocked":
        rb = 0.004 * effects["open.backlash"] * 6.3e-3
        dx = _play_np(dx, np.array([rb]), np.array([0.0]))[:, 0]
    # measured charge: shunt integral with leak, offset, absorption
    qm = Q.copy()
    if "slow.leakage" in effects:
        qm = qm + np.cumsum(Vt) * dt / (2e9 / effects["slow.leakage"]) * (relay < 0.5)
    if "slow.offset_drift" in effects:
        m = effects["slow.offset_drift"]
        bias = 1.5e-8 * m + np.cumsum(rng.normal(0, 3e-9 * m, n)) * np.sqrt(dt)
        qm = qm + np.cumsum(bias) * dt * (relay < 0.5)
    if "slow.absorption" in effects:
        m = effects["slow.absorption"]
        qm = qm + 0.0015 * m * CT * (0.5 * lowpass(Vt, 0.7, dt) + 0.5 * lowpass(Vt, 7.0, dt))
    qm[:n_relay] = 0.0
    noise = effects.get("floor.noise", 1.0)
    qm = qm + rng.normal(0, 2e-4 * CT * VMAX * noise, n)
    Vs = np.gradient(qm, dt) * 1000.0 * 0  # shunt voltage is negligible in V = V_c - V_s here
    V = Vc + rng.normal(0, 0.02 * noise, n)
    dx_ref = dx + rng.normal(0, 2e-6 * noise, n) if tr.reference == "displacement" else np.full(n, np.nan)
    f_ref = f + rng.normal(0, 3e-4 * noise, n) if tr.reference == "force" else np.full(n, np.nan)
    return pd.DataFrame({"t": t + t0, "V": V, "q": qm, "u_cmd": Vc / 15.0, "relay": relay, "dx_ref": dx_ref,
                         "f_ref": f_ref, "V_c": Vc, "V_s": Vs})


def simulate_case(effects: dict, seed: int, T: float = 4.0, fs: float = 500.0):
    """All protocol trials of one scenario in memory: (trials dict, meta DataFrame, rig dict).

    ``effects``: name -> magnitude (1 ~ the noise floor). The same ``seed`` gives the same drives and noise with or
    without an effect, so a counterfactual re-simulation differs only by the effect.
    """
    trials, rows = {}, []
    for i, tr in enumerate(PROTOCOL):
        rng = np.random.default_rng([seed, i])
        trials[tr.name] = _trial(tr, effects, rng, T, fs, t0=i * T)
        rows.append({"trial": tr.name, "file": f"{tr.name}.parquet", "role": tr.role, "tip": tr.tip,
                     "object_mm": 4.0 if tr.tip == "object" else np.nan, "reference": tr.reference,
                     "signal": tr.signal})
    return trials, pd.DataFrame(rows).set_index("trial"), toy_rig()


def draw_scenario(rng: np.random.Generator, open_set_rate: float = 0.1) -> dict:
    """Effects for one benchmark case: 0 effects ~20 %, 1 ~50 %, 2-3 ~20 %, open-set ~10 %; magnitudes
    log-uniform 0.3x-30x the noise floor."""
    u = rng.random()
    mag = lambda: float(np.exp(rng.uniform(np.log(0.3), np.log(30.0))))
    if u < 0.2:
        return {}
    if u < 0.7:
        return {str(rng.choice(TOY_EFFECTS)): mag()}
    if u < 1 - open_set_rate:
        k = int(rng.integers(2, 4))
        return {str(e): mag() for e in rng.choice(TOY_EFFECTS, size=k, replace=False)}
    return {str(rng.choice(OPEN_SET)): float(np.exp(rng.uniform(np.log(3.0), np.log(30.0))))}
