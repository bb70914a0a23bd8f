"""Compiled kernels of the H(q) model registry: Preisach grid features and creep (relaxation) filters.

Preisach grid (Mayergoyz's Preisach operator with a density that is constant on the cells of a uniform grid of
the (alpha, beta) half-plane alpha >= beta, alpha = up-switching and beta = down-switching threshold): the
output is ``y = sum_c w_c F_c(t)`` where ``F_c`` is the fraction of cell ``c`` whose relays are "up" at time t.
The up-region is ``{(a, b): b < g(a)}`` with ``g`` a non-increasing staircase kept as a stack of dominant maxima
``M_j`` (decreasing) and minima ``m_j`` (increasing) -- the wiping-out property; the area of each cell inside it
is integrated exactly, so the output is continuous (piecewise quadratic) in the input. All relays start "down"
(the relaxed state that the relay of the charge circuit establishes, thesis 000_18d138f03f1777c3.txt sec. 5.1.1).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["preisach_grid_features", "preisach_grid_output", "relaxation_bank", "relaxation_output", "GRID_STACK",
           "grid_state", "play_output"]

_BIG = 1e300
#: capacity of the Preisach grid's stack of dominant extrema (nested reversals beyond it are dropped, as before)
GRID_STACK = 4096


def grid_state() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The relaxed state of :func:`preisach_grid_output` (all relays down): stacks of dominant maxima / minima and
    ``[K (stack depth), previous input, started (0/1)]``. Streaming callers keep these arrays between blocks."""
    return np.empty(GRID_STACK), np.empty(GRID_STACK), np.array([0.0, 0.0, 0.0])


@njit(cache=True)
def _prim(x, b0, top):
    """Integral from -inf to x of (clip(a, b0, top) - b0) da (top > b0)."""
    if x <= b0:
        return 0.0
    if x <= top:
        return 0.5 * (x - b0) * (x - b0)
    return 0.5 * (top - b0) * (top - b0) + (top - b0) * (x - top)


def preisach_grid_features(u, lo, hi, n, stride=1):
    """Cell up-fractions F (see :func:`_grid`), every ``stride``-th row, from the relaxed state."""
    Ms, ms, st = grid_state()
    st[1] = lo
    return _grid(np.ascontiguousarray(u, dtype=np.float64), float(lo), float(hi), int(n), np.zeros(0), False,
                 int(stride), Ms, ms, st)


def preisach_grid_output(u, lo, hi, n, w, state=None):
    """``F @ w`` of :func:`preisach_grid_features` without storing F: memory O(len(u)), not O(len(u) n^2).
    ``state`` (from :func:`grid_state`, updated in place): continue from it, so that blocks fed one after the other
    give exactly the output of one call on the whole input."""
    if state is None:
        state = grid_state()
    Ms, ms, st = state
    if st[2] == 0.0:
        st[1] = lo
    return _grid(np.ascontiguousarray(u, dtype=np.float64), float(lo), float(hi), int(n),
                 np.ascontiguousarray(w, dtype=np.float64), True, 1, Ms, ms, st)[:, 0]


@njit(cache=True)
def _grid(u, lo, hi, n, w, weighted, stride, Ms, ms, st):
    """Features F (len(u), n (n + 1) / 2) of the Preisach grid on [lo, hi] (inputs are clipped to it); with
    ``stride`` > 1 only every stride-th row is kept (the state still runs over every sample). The state (stacks
    ``Ms``, ``ms``; ``st = [K, previous input, started]``) is read at the start and written back at the end.

    Cell (i, j), j <= i, covers a in [g_i, g_i+1], b in [g_j, g_j+1] (half of it when i == j); its feature is the
    up-fraction of its area, in [0, 1]."""
    N = u.size
    nc = n * (n + 1) // 2
    F = np.zeros((N, 1)) if weighted else np.zeros(((N + stride - 1) // stride, nc))
    h = (hi - lo) / n
    cap = Ms.shape[0]
    K = int(st[0])
    prev = st[1]
    started = st[2] != 0.0
    for k in range(N):
        x = min(max(u[k], lo), hi)
        if not started or x > prev:
            started = True
            # ascending: relays with a <= x switch up; pairs with M_j <= x are wiped out
            while K > 0 and Ms[K - 1] <= x:
                K -= 1
            if K < cap:
                Ms[K] = x
                ms[K] = _BIG
                K += 1
        elif x < prev:
            # descending: relays with b >= x switch down: g := min(g, x); pairs after the first m_j >= x go
            j = 0
            while j < K and ms[j] < x:
                j += 1
            if j < K:
                ms[j] = x
                K = j + 1
        prev = x
        if k % stride != 0:
            continue
        row = k if weighted else k // stride
        # cell areas
        c = 0
        for i in range(n):
            a0 = lo + i * h
            a1 = a0 + h
            for jb in range(i + 1):
                b0 = lo + jb * h
                b1 = b0 + h
                area = 0.0
                # pieces of g over [a0, a1]: g = ms[j] on (Ms[j+1], Ms[j]], -inf above Ms[0]
                for jj in range(K):
                    p1 = Ms[jj]
                    p0 = Ms[jj + 1] if jj + 1 < K else -_BIG
                    if p1 <= a0:
                        break
                    if p0 >= a1:
                        continue
                    q0 = max(p0, a0)
                    q1 = min(p1, a1)
                    top = min(ms[jj], b1)
                    if top <= b0:
                        continue
                    area += _prim(q1, b0, top) - _prim(q0, b0, top)
                full = h * h if jb < i else 0.5 * h * h
                if weighted:
                    F[row, 0] += w[c] * (area / full)
                else:
                    F[row, c] = area / full
                c += 1
    st[0] = K
    st[1] = prev
    st[2] = 1.0 if started else 0.0
    return F


@njit(cache=True)
def _relax(u, g, zs, j):
    """``u - z`` with ``z += g (u - z)`` per sample, starting from ``zs[j]`` and leaving the last z there."""
    z = zs[j]
    out = np.empty(u.size)
    for k in range(u.size):
        z += g * (u[k] - z)
        out[k] = u[k] - z
    zs[j] = z
    return out


def relaxation_bank(u, dt: float, tau_s) -> np.ndarray:
    """Creep columns ``u - z_j``, ``dz_j/dt = (u - z_j) / tau_j`` discretised exactly at the sample time ``dt`` [s]
    (``z_j(0) = 0``, the relaxed state): Kuhnen's creep operator (thesis 000_18d138f03f1777c3.txt eqs. 38-41) with
    a zero threshold, its eigenvalues ``1 / tau_j`` kept in 1/s so that the model is the same at any sample rate
   . Returns (len(u), len(tau_s))."""
    u = np.ascontiguousarray(u, dtype=float)
    zs = np.zeros(len(tau_s))
    cols = [_relax(u, -math.expm1(-dt / float(t)), zs, j) for j, t in enumerate(tau_s)]
    return np.column_stack(cols) if cols else np.zeros((u.size, 0))


def relaxation_output(u, dt: float, tau_s, w, state=None) -> np.ndarray:
    """``relaxation_bank(u, dt, tau_s) @ w`` in one pass (memory O(len(u))), columns with a zero weight skipped.
    ``state``: the filter states z_j (one per time constant, zeros = relaxed), continued from and updated in place
    (streaming)."""
    u = np.ascontiguousarray(u, dtype=float)
    zs = np.zeros(len(tau_s)) if state is None else state
    g = np.array([-math.expm1(-dt / float(t)) for t in tau_s])
    return _relax_output(u, g, np.asarray(w, dtype=float)[:len(g)], zs)


@njit(cache=True)
def _relax_output(u, g, w, zs):
    """``sum_j w_j (u - z_j)``, ``z_j += g_j (u - z_j)``, summed in the order of j from 0 (the sum of
    ``w_j * _relax(u, g_j)`` columns, bit for bit)."""
    y = np.zeros(u.size)
    for j in range(g.size):
        if w[j] == 0.0:
            continue
        z = zs[j]
        gj = g[j]
        wj = w[j]
        for k in range(u.size):
            z += gj * (u[k] - z)
            y[k] += wj * (u[k] - z)
        zs[j] = z
    return y


def play_output(u, r, w, state=None):
    """``sum_i w_i P_{r_i}[u]`` (plays from z = 0, or from ``state``, which is updated in place), memory
    O(len(u))."""
    z = np.zeros(len(r)) if state is None else state
    return _play_output(np.ascontiguousarray(u, dtype=np.float64), np.ascontiguousarray(r, dtype=np.float64),
                        np.ascontiguousarray(w, dtype=np.float64), z)


@njit(cache=True)
def _play_output(u, r, w, z):
    y = np.zeros(u.size)
    for k in range(u.size):
        x = u[k]
        acc = 0.0
        for i in range(r.size):
            zi = max(x - r[i], min(x + r[i], z[i]))
            z[i] = zi
            acc += w[i] * zi
        y[k] = acc
    return y


@njit(cache=True)
def play_features(u, r, stride):
    """Plays ``P_{r_i}[u]`` from z = 0, every ``stride``-th row (the state runs over every sample)."""
    z = np.zeros(r.size)
    F = np.zeros(((u.size + stride - 1) // stride, r.size))
    for k in range(u.size):
        x = u[k]
        for i in range(r.size):
            z[i] = max(x - r[i], min(x + r[i], z[i]))
        if k % stride == 0:
            F[k // stride, :] = z
    return F
