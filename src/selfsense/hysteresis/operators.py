"""Hysteresis and creep operators of the modified Prandtl-Ishlinskii model (numba-backed).

Seed: ``000_18d138f03f1777c3.txt`` section 4.2.1, eqs. (29)-(41). Thresholds share the unit of the
input x; ``dt`` [s]; creep eigenvalues ``a`` [1/s]. Plain-Python twins live in ``reference.py``.
"""

from __future__ import annotations

import numpy as np

from . import _kernels


def _vec(v, name: str) -> np.ndarray:
    a = np.ascontiguousarray(np.atleast_1d(np.asarray(v, dtype=float)))
    if a.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {a.shape}")
    return a


def play_operator(x, r, z0=None) -> np.ndarray:
    """Play operators H_r[x, z0], eqs. (29)-(31). x (N,), r (n,) >= 0, z0 (n,) or scalar (default 0) -> (N, n)."""
    x = _vec(x, "x")
    r = _vec(r, "r")
    if np.any(r < 0):
        raise ValueError("play thresholds r must be >= 0")
    z = np.zeros(len(r)) if z0 is None else np.array(np.broadcast_to(np.asarray(z0, float), r.shape))
    out = np.empty((len(x), len(r)))
    _kernels.play_kernel(x, r, z, out)
    return out


def superposition_operator(x, r) -> np.ndarray:
    """Superposition (dead-zone) operators S_r[x], eq. (33) two-sided, corrected; eq. (34) for r > 0. -> (N, l)."""
    x = _vec(x, "x")
    r = _vec(r, "r")
    out = np.empty((len(x), len(r)))
    _kernels.superposition_kernel(x, r, out)
    return out


def log_creep_eigenvalues(m: int, dt: float) -> np.ndarray:
    """Eq. (40): a_j = 1 / (10^(j-1) T_s) for j = 1..m  [1/s]."""
    if dt <= 0:
        raise ValueError("dt must be > 0")
    return 1.0 / (10.0 ** np.arange(m, dtype=float) * dt)


def creep_operator(x, r, a, dt, Z0=None) -> np.ndarray:
    """Elementary creep operators K_{r a}[x, Z0], eqs. (38)-(39) (exact zero-order hold). -> (N, n, m).

    Sample 0 holds the initial state Z0 (n, m) (default 0); sample k is the exact solution of eq. (38) at
    t_k for the input held at x[k-1] over [t_{k-1}, t_k).
    """
    x = _vec(x, "x")
    r = _vec(r, "r")
    a = _vec(a, "a")
    if np.any(r < 0) or np.any(a <= 0):
        raise ValueError("creep thresholds must be >= 0 and eigenvalues > 0")
    g = -np.expm1(-a * dt)  # 1 - exp(-a T_s)
    c = np.zeros((len(r), len(a))) if Z0 is None else np.array(np.broadcast_to(np.asarray(Z0, float), (len(r), len(a))))
    out = np.empty((len(x), len(r), len(a)))
    _kernels.creep_kernel(x, r, g, c, out)
    return out


def play_sum(x, r, w, z0=None) -> np.ndarray:
    """Eq. (32): w_H^T H_{r_H}[x, z_H0] -> (N,)."""
    return play_operator(x, r, z0) @ _vec(w, "w")


def superposition_sum(x, r, w) -> np.ndarray:
    """Eq. (35): w_S^T S_{r_S}[x] -> (N,)."""
    return superposition_operator(x, r) @ _vec(w, "w")


def creep_sum(x, r, a, w, dt, Z0=None) -> np.ndarray:
    """Eq. (41): w_K^T K_{r_K a_K}[x, Z_K0] i -> (N,)."""
    return creep_operator(x, r, a, dt, Z0).sum(axis=2) @ _vec(w, "w")
