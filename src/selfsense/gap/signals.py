"""Small causal signal helpers used by the effect library (exact discretisations, SI units)."""
from __future__ import annotations

import numpy as np
from selfsense.signals.iir import lfilter

__all__ = ["dt_of", "lowpass", "leaky_integral", "deriv", "t_active", "branch", "first_loading", "active"]


def dt_of(t: np.ndarray) -> float:
    """Median sample period [s]."""
    return float(np.median(np.diff(t))) if len(t) > 1 else 1e-3


def lowpass(x: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """First-order low-pass y' = (x - y)/tau, zero-order-hold exact, y(0) = x(0)."""
    x = np.asarray(x, float)
    a = np.exp(-dt / tau)
    y, _ = lfilter([1 - a], [1, -a], x, zi=[a * x[0]] if len(x) else [0.0])
    return y


def leaky_integral(x: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """y' = x - y / tau (integral of x that forgets with time constant tau) [unit(x) s], y(0) = 0."""
    a = np.exp(-dt / tau)
    y = lfilter([dt], [1, -a], np.asarray(x, float))
    return y


def deriv(x: np.ndarray, dt: float, tau: float | None = None) -> np.ndarray:
    """Time derivative after an optional low-pass (tau [s]) [unit(x)/s]."""
    x = np.asarray(x, float)
    if tau:
        x = lowpass(x, tau, dt)
    return np.gradient(x, dt)


def active(df) -> np.ndarray:
    """True where the actuator leads are not shorted (relay == 0)."""
    return df["relay"].to_numpy() < 0.5


def t_active(df) -> np.ndarray:
    """Time since the relay opened [s] (0 while shorted)."""
    t = df["t"].to_numpy(float)
    act = active(df)
    if not act.any():
        return np.zeros_like(t)
    t0 = t[np.argmax(act)]
    return np.where(act, t - t0, 0.0)


def branch(x: np.ndarray, deadband: float) -> np.ndarray:
    """Rising (+1) / falling (-1) branch with a dead band (the sign of x - play_r[x], thesis eq. 29 with r)."""
    x = np.asarray(x, float)
    z = np.empty_like(x)
    zc = x[0] if len(x) else 0.0
    # play operator with threshold deadband (vectorised enough for short trials via a python loop fallback)
    try:
        from selfsense.hysteresis.operators import play_operator

        z = play_operator(x, np.array([deadband]), np.array([x[0]]))[:, 0]
    except Exception:  # pragma: no cover - fallback
        for i, xi in enumerate(x):
            zc = max(xi - deadband, min(xi + deadband, zc))
            z[i] = zc
    s = np.sign(x - z)
    # hold the last branch through flat parts
    idx = np.where(s != 0, np.arange(len(s)), 0)
    np.maximum.accumulate(idx, out=idx)
    s = s[idx]
    return s


def first_loading(x: np.ndarray, tol: float) -> np.ndarray:
    """1 where x is on its first-loading (virgin) curve: at its running maximum (within tol) and rising."""
    x = np.asarray(x, float)
    runmax = np.maximum.accumulate(x)
    return (x >= runmax - tol).astype(float)
