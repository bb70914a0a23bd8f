"""Plain, readable reference implementations of the operators (pure Python loops; slow; for tests).

Seed: ``000_18d138f03f1777c3.txt`` eqs. (29)-(42). Each function mirrors one equation as printed
(eq. 33 with its third case corrected to ``min(x - r_s, 0)``, see seeds/README.md).
Units: whatever x is in; thresholds share x's unit; ``dt`` in s, eigenvalues ``a`` in 1/s.
"""

from __future__ import annotations

import math

import numpy as np


def play(x_k: float, y_prev: float, r: float) -> float:
    """Eq. (31): H(x, y, r) = max(x - r, min(x + r, y))."""
    return max(x_k - r, min(x_k + r, y_prev))


def play_operator(x, r, z0=None) -> np.ndarray:
    """Eqs. (29)-(30): output (N, n) of n play operators with thresholds r and initial states z0."""
    x = [float(v) for v in np.asarray(x, dtype=float)]
    r = [float(v) for v in np.atleast_1d(r)]
    z = [0.0] * len(r) if z0 is None else [float(v) for v in np.broadcast_to(z0, (len(r),))]
    out = np.empty((len(x), len(r)))
    for k, xk in enumerate(x):
        for i, ri in enumerate(r):
            z[i] = play(xk, z[i], ri)  # eq. (29) at k = 0, eq. (30) afterwards
            out[k, i] = z[i]
    return out


def superposition(x_k: float, r: float) -> float:
    """Eq. (33), corrected third case."""
    if r > 0:
        return max(x_k - r, 0.0)
    if r == 0:
        return x_k
    return min(x_k - r, 0.0)


def superposition_operator(x, r) -> np.ndarray:
    """Eq. (33)/(34) for every sample and threshold: (N, l)."""
    x = np.asarray(x, dtype=float)
    r = np.atleast_1d(np.asarray(r, dtype=float))
    out = np.empty((len(x), len(r)))
    for k in range(len(x)):
        for i in range(len(r)):
            out[k, i] = superposition(float(x[k]), float(r[i]))
    return out


def creep_step(y_prev: float, x_prev: float, r: float, a: float, dt: float) -> float:
    """Eq. (39), the three cases as printed."""
    e = math.exp(-a * dt)
    if x_prev - y_prev >= r:
        return e * y_prev + (1.0 - e) * (x_prev - r)
    if x_prev - y_prev <= -r:
        return e * y_prev + (1.0 - e) * (x_prev + r)
    return y_prev


def creep_operator(x, r, a, dt, Z0=None) -> np.ndarray:
    """Eq. (39) for every threshold r (n,) and eigenvalue a (m,): (N, n, m). y_0 = Z0 (zeros by default)."""
    x = np.asarray(x, dtype=float)
    r = np.atleast_1d(np.asarray(r, dtype=float))
    a = np.atleast_1d(np.asarray(a, dtype=float))
    n, m = len(r), len(a)
    Z = np.zeros((n, m)) if Z0 is None else np.array(np.broadcast_to(Z0, (n, m)), dtype=float)
    out = np.empty((len(x), n, m))
    for k in range(len(x)):
        if k > 0:
            for i in range(n):
                for j in range(m):
                    Z[i, j] = creep_step(Z[i, j], float(x[k - 1]), float(r[i]), float(a[j]), dt)
        out[k] = Z
    return out


def log_creep_eigenvalues(m: int, dt: float) -> np.ndarray:
    """Eq. (40): a_j = 1 / (10^(j-1) T_s), j = 1..m  [1/s]."""
    return np.array([1.0 / (10.0 ** (j - 1) * dt) for j in range(1, m + 1)])


def modified_pi(x, r_H, w_H, z_H0, r_K, w_K, a_K, Z_K0, r_S, w_S, dt, offset=0.0) -> np.ndarray:
    """Eq. (42): Gamma[x] = w_S^T S_{r_S}[ w_H^T H_{r_H}[x, z_H0] + w_K^T K[x, Z_K0] i + offset ]."""
    H = play_operator(x, r_H, z_H0)
    u = H @ np.asarray(w_H, dtype=float) + offset
    if len(np.atleast_1d(r_K)) and len(np.atleast_1d(a_K)):
        K = creep_operator(x, r_K, a_K, dt, Z_K0)  # (N, n, m)
        u = u + K.sum(axis=2) @ np.asarray(w_K, dtype=float)  # eq. (41): w_K^T K i
    S = superposition_operator(u, r_S)
    return S @ np.asarray(w_S, dtype=float)
