"""True electrical hysteresis of the virtual tweezer: a continuous asymmetric Preisach model.

Deliberately NOT the estimator's family (modified Prandtl-Ishlinskii, thesis eqs. 28-43): a
Preisach operator of relay hysterons {0, 1} with up-threshold a >= down-threshold b and a smooth
density, evaluated exactly through its Everett function and a memory stack of dominant turning
points (wiping-out, congruent minor loops; Mayergoyz).  The Everett function is a sum of
logistic-product components

    E(a, b) = sum_k w_k [P_k(a) - P_k(b)] [R_k(a) - R_k(b)],
    P_k(x) = L((x - c_k - h_k)/s_k),   R_k(x) = L((x - c_k + h_k)/s_k),   L = logistic,

whose density -d2E/da db = w_k [p_k(a) r_k(b) + r_k(a) p_k(b)] >= 0 and E(a, a) = 0.  Hysterons of
component k switch on near a = c_k + h_k and off near b = c_k - h_k.  A component with
c_k - h_k < 0 < c_k + h_k holds hysterons that a unipolar drive switches on at first loading and
never switches off: the initial ascending (virgin) curve.  The initial state is an AC-demagnetised
staircase (alternating decaying history), i.e. the relaxed state after the relay
(thesis 000_18d138f03f1777c3.txt sec. 5.1.1: "shorting the leads allows a consistent initial
condition").

State arrays (all owned by the caller): turning points ``tp``, outputs there ``ty``, cached
logistic values ``tl`` (MAXS, ncomp, 2), index ``K`` of the last turning point (even = a minimum,
segment going up; odd = a maximum, going down), current input/output and its cached logistics.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["MAXS", "preisach_state", "preisach_commit", "preisach_eval", "demagnetise",
           "preisach_path", "preisach_reference_grid"]

MAXS = 2048
U_BOTTOM = -50.0


@njit(cache=True)
def _logis(x):
    if x < -700.0:
        return 0.0
    return 1.0 / (1.0 + math.exp(-x))


@njit(cache=True)
def _fill_l(u, comps, out):
    for k in range(comps.shape[0]):
        c, h, s = comps[k, 0], comps[k, 1], comps[k, 2]
        out[k, 0] = _logis((u - c - h) / s)
        out[k, 1] = _logis((u - c + h) / s)


@njit(cache=True)
def _everett(la, lb, comps):
    """E(a, b) from cached logistic values of a (la) and b (lb)."""
    e = 0.0
    for k in range(comps.shape[0]):
        e += comps[k, 3] * (la[k, 0] - lb[k, 0]) * (la[k, 1] - lb[k, 1])
    return e


def preisach_state(ncomp: int):
    """Fresh state: all hysterons off (input at -infinity).  Returns (tp, ty, tl, iv, fv, cl)
    with iv = [K], fv = [u_cur, y_cur], cl = cached logistics of u_cur."""
    tp = np.zeros(MAXS)
    ty = np.zeros(MAXS)
    tl = np.zeros((MAXS, ncomp, 2))
    tp[0] = U_BOTTOM
    iv = np.zeros(1, np.int64)
    fv = np.array([U_BOTTOM, 0.0])
    cl = np.zeros((ncomp, 2))
    return tp, ty, tl, iv, fv, cl


@njit(cache=True)
def preisach_eval(u, lu, tp, ty, tl, iv, fv, cl, comps):
    """Output y(u) for a new input u (its logistics in ``lu``) WITHOUT changing the state."""
    K = iv[0]
    ucur = fv[0]
    if K % 2 == 0:  # going up from the minimum tp[K]
        if u >= ucur:
            k = K
            while k >= 2 and u > tp[k - 1]:
                k -= 2
            return ty[k] + _everett(lu, tl[k], comps)
        # reversal at ucur (new maximum), going down
        if u >= tp[K]:
            return fv[1] - _everett(cl, lu, comps)
        k = K - 1
        while k >= 3 and u < tp[k - 1]:
            k -= 2
        return ty[k] - _everett(tl[k], lu, comps)
    else:  # going down from the maximum tp[K]
        if u <= ucur:
            k = K
            while k >= 3 and u < tp[k - 1]:
                k -= 2
            return ty[k] - _everett(tl[k], lu, comps)
        # reversal at ucur (new minimum), going up
        if u <= tp[K]:
            return fv[1] + _everett(lu, cl, comps)
        k = K - 1
        while k >= 2 and u > tp[k - 1]:
            k -= 2
        return ty[k] + _everett(lu, tl[k], comps)


@njit(cache=True)
def preisach_commit(u, lu, tp, ty, tl, iv, fv, cl, comps):
    """Move the state to input u; return y(u)."""
    K = iv[0]
    ucur = fv[0]
    if K % 2 == 0:
        if u < ucur:  # reversal: push ucur as a maximum
            if K + 1 < MAXS:
                K += 1
                tp[K] = ucur
                ty[K] = fv[1]
                tl[K, :, :] = cl
            while K >= 3 and u < tp[K - 1]:
                K -= 2
    else:
        if u > ucur:  # reversal: push ucur as a minimum
            if K + 1 < MAXS:
                K += 1
                tp[K] = ucur
                ty[K] = fv[1]
                tl[K, :, :] = cl
            while K >= 2 and u > tp[K - 1]:
                K -= 2
    # wiping while continuing in the same direction
    if K % 2 == 0:
        while K >= 2 and u > tp[K - 1]:
            K -= 2
        y = ty[K] + _everett(lu, tl[K], comps)
    else:
        while K >= 3 and u < tp[K - 1]:
            K -= 2
        y = ty[K] - _everett(tl[K], lu, comps)
    iv[0] = K
    fv[0] = u
    fv[1] = y
    cl[:, :] = lu
    return y


@njit(cache=True)
def _commit_u(u, tp, ty, tl, iv, fv, cl, comps, lu):
    _fill_l(u, comps, lu)
    return preisach_commit(u, lu, tp, ty, tl, iv, fv, cl, comps)


@njit(cache=True)
def demagnetise(amplitude, cycles, tp, ty, tl, iv, fv, cl, comps):
    """Drive the state through an alternating history of linearly decaying amplitude ending at 0
    (AC demagnetisation); returns y at u = 0."""
    lu = np.zeros((comps.shape[0], 2))
    _commit_u(-amplitude, tp, ty, tl, iv, fv, cl, comps, lu)
    for j in range(cycles):
        a = amplitude * (1.0 - (j + 0.5) / cycles)
        _commit_u(a, tp, ty, tl, iv, fv, cl, comps, lu)
        _commit_u(-a * (1.0 - 0.5 / cycles), tp, ty, tl, iv, fv, cl, comps, lu)
    return _commit_u(0.0, tp, ty, tl, iv, fv, cl, comps, lu)


@njit(cache=True)
def _path(u, comps, amplitude, cycles, tp, ty, tl, iv, fv, cl):
    y = np.empty(u.size)
    demagnetise(amplitude, cycles, tp, ty, tl, iv, fv, cl, comps)
    lu = np.zeros((comps.shape[0], 2))
    for i in range(u.size):
        y[i] = _commit_u(u[i], tp, ty, tl, iv, fv, cl, comps, lu)
    return y


def preisach_path(u, comps, amplitude=2.0, cycles=60) -> np.ndarray:
    """Preisach output along an input path u, starting from the demagnetised state (y is the raw
    Preisach sum; units of the component weights)."""
    comps = np.ascontiguousarray(comps, dtype=float)
    st = preisach_state(comps.shape[0])
    return _path(np.ascontiguousarray(u, dtype=float), comps, float(amplitude), int(cycles), *st)


def preisach_reference_grid(u, comps, amplitude=2.0, cycles=60, n=500, lo=-2.5, hi=2.5):
    """Independent brute-force reference: an n x n grid of relay hysterons with cell weights
    from the density, switched one by one (plain NumPy).  Same demagnetising history."""
    comps = np.asarray(comps, float)
    g = np.linspace(lo, hi, n + 1)
    mid = 0.5 * (g[:-1] + g[1:])
    A, B = np.meshgrid(mid, mid, indexing="ij")   # A: up threshold, B: down threshold

    def cdf(x, c, s):
        return 1.0 / (1.0 + np.exp(-(x - c) / s))
    W = np.zeros((n, n))
    for c, h, s, w in comps:
        pa = np.diff(cdf(g, c + h, s))
        ra = np.diff(cdf(g, c - h, s))
        W += w * (np.outer(pa, ra) + np.outer(ra, pa))
    W[A < B] = 0.0
    diag = np.isclose(A, B)
    W[diag] *= 0.5      # half of each diagonal cell lies in the half-plane a >= b
    state = np.zeros((n, n), bool)
    hist = [-amplitude]
    for j in range(cycles):
        a = amplitude * (1.0 - (j + 0.5) / cycles)
        hist += [a, -a * (1.0 - 0.5 / cycles)]
    hist += [0.0]
    prev = U_BOTTOM
    out = []
    seq = list(hist) + list(np.asarray(u, float))
    for k, x in enumerate(seq):
        if x > prev:
            state |= (A <= x)
        elif x < prev:
            state &= ~(B >= x)
        prev = x
        if k >= len(hist):
            out.append(float((W * state).sum()))
    return np.array(out)
