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

__all__ = ["preisach_grid_features", "preisach_grid_rows", "preisach_grid_output", "relaxation_bank",
           "relaxation_output", "GRID_STACK", "grid_state", "play_output", "relaxation_gains", "preisach_grid_kernel",
           "play_output_kernel", "relaxation_output_kernel", "reversible_features", "reversible_output"]

_BIG = 1e300
#: the weighted grid output is updated by the changed cells only and summed over every cell afresh every _RESYNC
#: output samples (counted from the relaxed state, so any split into blocks gives the same bits)
_RESYNC = 256.0
#: capacity of the Preisach grid's stack of dominant extrema (nested reversals beyond it are dropped, as before)
GRID_STACK = 4096


def grid_state(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The relaxed state of an ``n`` x ``n`` Preisach grid (all relays down): stacks of dominant maxima / minima,
    ``[K (stack depth), previous input, started (0/1), output samples so far, weighted output]`` and the cells'
    up-fractions. Streaming callers keep these
    arrays between blocks (:func:`preisach_grid_output`)."""
    return np.empty(GRID_STACK), np.empty(GRID_STACK), np.zeros(5), np.zeros(n * (n + 1) // 2)


@njit(cache=True, nogil=True)
def _prim(x, b0, top):
    """Integral from -inf to x of (clip(a, b0, top) - b0) da (top > b0)."""
    if x <= b0:
        return 0.0
    if x <= top:
        return 0.5 * (x - b0) * (x - b0)
    return 0.5 * (top - b0) * (top - b0) + (top - b0) * (x - top)


def preisach_grid_features(u, lo, hi, n, stride=1, out=None):
    """Cell up-fractions F (see :func:`preisach_grid_kernel`), every ``stride``-th row, from the relaxed state;
    written into ``out`` (``(ceil(len(u) / stride), n (n + 1) / 2)``, any row stride, e.g. the basis columns of a
    design matrix) when given, which is returned."""
    Ms, ms, st, Fc = grid_state(n)
    st[1] = lo
    nc = int(n) * (int(n) + 1) // 2
    rows = (len(u) + int(stride) - 1) // int(stride)
    if out is None:
        out = np.zeros((rows, nc))
    elif out.shape != (rows, nc) or out.dtype != np.float64 or out.strides[1] != 8:
        raise ValueError(f"preisach_grid_features: out must be float64 of shape {(rows, nc)} with contiguous rows, "
                         f"got {out.dtype} {out.shape}")
    preisach_grid_kernel(np.ascontiguousarray(u, dtype=np.float64), float(lo), float(hi), int(n), np.zeros(0), False,
                         int(stride), Ms, ms, st, Fc, out)
    return out


def preisach_grid_rows(u, lo, hi, n, stride, rows, out=None):
    """Rows ``rows`` (sorted, distinct indices of the grid ``0, stride, 2 stride, ...``) of
    :func:`preisach_grid_features` ``(u, lo, hi, n, stride)``, the same values bit for bit, without building the
    others: the state still runs over every sample from the relaxed state, fed block after block
    (:func:`preisach_grid_kernel`), and a block of samples with no requested row writes one scratch row only. The
    same bits because a cell's up-fraction is integrated afresh from the part of the staircase over that cell
    (:func:`_cell_fraction`) whenever an input step marks it, and a step that marks no cell leaves that part
    unchanged: the value at a row does not depend on which earlier rows were written. Used where a few rows of a
    long record are read (the hold rows, :func:`selfsense.hysteresis.models.holds.hold_design`: about a quarter of
    every trial's samples)."""
    rows = np.asarray(rows, dtype=np.int64)
    nc = int(n) * (int(n) + 1) // 2
    stride = int(stride)
    if out is None:
        out = np.zeros((rows.size, nc))
    elif out.shape != (rows.size, nc) or out.dtype != np.float64 or out.strides[1] != 8:
        raise ValueError(f"preisach_grid_rows: out must be float64 of shape {(rows.size, nc)} with contiguous rows, "
                         f"got {out.dtype} {out.shape}")
    n_rows = (len(u) + stride - 1) // stride
    if rows.size and (rows[0] < 0 or rows[-1] >= n_rows or np.any(np.diff(rows) <= 0)):
        raise ValueError(f"preisach_grid_rows: rows must be sorted, distinct and within the {n_rows} grid rows")
    u = np.ascontiguousarray(u, dtype=np.float64)
    Ms, ms, st, Fc = grid_state(n)
    st[1] = lo
    # the row a block without requested rows writes: a strided view, like the basis block of a design matrix that
    # preisach_grid_features fills (numba compiles one variant of preisach_grid_kernel per array layout)
    scratch = np.empty((2, nc + 1))[:, :nc]
    none = np.zeros(0)
    cut = np.flatnonzero(np.diff(rows) != 1) + 1   # runs of consecutive rows
    k0 = 0
    for a, b in zip(np.concatenate([[0], cut]), np.concatenate([cut, [rows.size]])):
        s0 = int(rows[a]) * stride
        if s0 > k0:   # the samples before this run: the state only
            preisach_grid_kernel(u[k0:s0], float(lo), float(hi), int(n), none, False, s0 - k0, Ms, ms, st, Fc, scratch)
        e0 = min(u.size, int(rows[b - 1]) * stride + stride)
        preisach_grid_kernel(u[s0:e0], float(lo), float(hi), int(n), none, False, stride, Ms, ms, st, Fc, out[a:b])
        k0 = e0
    return out


def preisach_grid_output(u, lo, hi, n, w, state=None):
    """``F @ w`` of :func:`preisach_grid_features` without storing F: memory O(len(u)), not O(len(u) n^2).
    ``state`` (from :func:`grid_state`, updated in place): continue from it, so that blocks fed one after the other
    give exactly the output of one call on the whole input."""
    if state is None:
        state = grid_state(n)
    Ms, ms, st, Fc = state
    if Fc.shape != (n * (n + 1) // 2,):
        raise ValueError(f"preisach_grid_output: state for {Fc.shape} cells, the grid has {n * (n + 1) // 2}")
    if st[2] == 0.0:
        st[1] = lo
    F = np.zeros((len(u), 1))
    preisach_grid_kernel(np.ascontiguousarray(u, dtype=np.float64), float(lo), float(hi), int(n),
                         np.ascontiguousarray(w, dtype=np.float64), True, 1, Ms, ms, st, Fc, F)
    return F[:, 0]


@njit(cache=True, nogil=True)
def _cell_fraction(Ms, ms, K, a0, a1, b0, b1, full):
    """Up-fraction of the cell [a0, a1] x [b0, b1] under the staircase (``Ms``, ``ms``, depth ``K``)."""
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
    return area / full


@njit(cache=True, nogil=True)
def _mark(dirty, dl, nd, n, lo, h, a_gt, a_lt, b_lt, b_gt):
    """Mark the cells with a1 > a_gt, a0 < a_lt, b0 < b_lt and b1 > b_gt (the cells an input step can change).
    Only the index ranges around the bounds are visited (one cell of margin); the conditions themselves are
    evaluated on the same expressions as the integration loop. Newly marked cells are appended to the list ``dl``
    (``nd`` entries so far); returns the new count."""
    i0 = max(0, int(math.floor((max(a_gt, lo - h) - lo) / h)) - 1)
    i1 = min(n - 1, int(math.ceil((min(a_lt, lo + (n + 1) * h) - lo) / h)) + 1)
    jlo = max(0, int(math.floor((max(b_gt, lo - h) - lo) / h)) - 1)
    jhi = int(math.ceil((min(b_lt, lo + (n + 1) * h) - lo) / h)) + 1
    for i in range(i0, i1 + 1):
        a0 = lo + i * h
        a1 = a0 + h
        if not (a1 > a_gt and a0 < a_lt):
            continue
        base = i * (i + 1) // 2
        for jb in range(jlo, min(i, jhi) + 1):
            b0 = lo + jb * h
            b1 = b0 + h
            if b0 < b_lt and b1 > b_gt and not dirty[base + jb]:
                dirty[base + jb] = True
                dl[nd] = base + jb
                nd += 1
    return nd


@njit(cache=True, nogil=True)
def preisach_grid_kernel(u, lo, hi, n, w, weighted, stride, Ms, ms, st, Fc, F):
    """Features F (len(u), n (n + 1) / 2) of the Preisach grid on [lo, hi] (inputs are clipped to it), written
    into ``F``; with ``stride`` > 1 only every stride-th row is kept (the state still runs over every sample).
    Weighted, ``F`` is (len(u), 1) and receives the output ``F @ w``. The state (stacks
    ``Ms``, ``ms``; ``st = [K, previous input, started]``; the cells' up-fractions ``Fc``) is read at the start and
    written back at the end.

    Cell (i, j), j <= i, covers a in [g_i, g_i+1], b in [g_j, g_j+1] (half of it when i == j); its feature is the
    up-fraction of its area, in [0, 1]. Only the cells an input step can change are integrated again (the others
    keep their fraction bit for bit, see below), so a sample costs O(cells near the input), not O(n^2):

    * ascending prev -> x: the staircase changes for a in (prev, x] only, and relays with b >= x stay down: cells
      with a1 > prev, a0 < x and b0 < x;
    * descending prev -> x, the first pair with m_j >= x set to x and the pairs after it dropped: relays with
      b >= prev were down and stay down, cells below x keep one piece of the staircase: cells with a1 > x,
      a0 < M_j, b0 < prev and (b1 > x, or any b when pairs were dropped: their breakpoints split cells).

    The first sample, or a full stack, integrates every cell. The weighted output adds ``w_c (F_c_new - F_c_old)``
    of the changed cells to the previous output and is summed over every cell in order every ``_RESYNC`` samples
    (rounding cannot accumulate beyond ~1e-14 of the output's scale)."""
    N = u.size
    nc = n * (n + 1) // 2
    h = (hi - lo) / n
    cap = Ms.shape[0]
    K = int(st[0])
    prev = st[1]
    started = st[2] != 0.0
    dirty = np.zeros(nc, dtype=np.bool_)
    dl = np.empty(nc, dtype=np.int64)   # the marked cells, in marking order
    nd = 0
    ci = np.empty(nc, dtype=np.int64)   # column / row of every cell
    cj = np.empty(nc, dtype=np.int64)
    c = 0
    for i in range(n):
        for jb in range(i + 1):
            ci[c] = i
            cj[c] = jb
            c += 1
    y = st[4]
    for k in range(N):
        x = min(max(u[k], lo), hi)
        if not started or x > prev:
            # ascending: relays with a <= x switch up; pairs with M_j <= x are wiped out
            while K > 0 and Ms[K - 1] <= x:
                K -= 1
            if K < cap and started:
                Ms[K] = x
                ms[K] = _BIG
                K += 1
                nd = _mark(dirty, dl, nd, n, lo, h, prev, x, x, -_BIG)
            else:
                if K < cap:
                    Ms[K] = x
                    ms[K] = _BIG
                    K += 1
                for c in range(nc):
                    if not dirty[c]:
                        dirty[c] = True
                        dl[nd] = c
                        nd += 1
            started = True
        elif x < prev:
            # descending: relays with b >= x switch down: g := min(g, x); pairs after the first m_j >= x go
            j = 0
            while j < K and ms[j] < x:
                j += 1
            if j < K:
                dropped = K - 1 > j
                top = Ms[j]
                ms[j] = x
                K = j + 1
                nd = _mark(dirty, dl, nd, n, lo, h, x, top, prev, -_BIG if dropped else x)
        prev = x
        if k % stride != 0:
            continue
        row = k if weighted else k // stride
        resync = weighted and (st[3] % _RESYNC == 0.0)
        st[3] += 1.0
        for d in range(nd):
            c = dl[d]
            i = ci[c]
            jb = cj[c]
            a0 = lo + i * h
            a1 = a0 + h
            b0 = lo + jb * h
            b1 = b0 + h
            full = h * h if jb < i else 0.5 * h * h
            new = _cell_fraction(Ms, ms, K, a0, a1, b0, b1, full)
            if weighted and not resync:
                y += w[c] * (new - Fc[c])
            Fc[c] = new
            dirty[c] = False
        nd = 0
        if not weighted:
            for c in range(nc):
                F[row, c] = Fc[c]
        if weighted:
            if resync:   # the ordered sum over every cell, so that rounding of the updates cannot accumulate
                y = 0.0
                for c in range(nc):
                    y += w[c] * Fc[c]
            F[row, 0] = y
    # cells marked after the last output row: integrate them now, so that the stored fractions match the state
    for d in range(nd):
        c = dl[d]
        i = ci[c]
        jb = cj[c]
        a0 = lo + i * h
        b0 = lo + jb * h
        full = h * h if jb < i else 0.5 * h * h
        Fc[c] = _cell_fraction(Ms, ms, K, a0, a0 + h, b0, b0 + h, full)
    st[0] = K
    st[1] = prev
    st[2] = 1.0 if started else 0.0
    st[4] = y


@njit(cache=True, nogil=True)
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
    g = relaxation_gains(dt, tau_s)
    return relaxation_output_kernel(u, g, np.asarray(w, dtype=float)[:len(g)], zs)


def relaxation_gains(dt: float, tau_s) -> np.ndarray:
    """The filters' gains ``g_j = 1 - exp(-dt / tau_j)`` of :func:`relaxation_output` at the sample time ``dt`` [s]."""
    return np.array([-math.expm1(-dt / float(t)) for t in tau_s])


@njit(cache=True, nogil=True)
def relaxation_output_kernel(u, g, w, zs):
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
    return play_output_kernel(np.ascontiguousarray(u, dtype=np.float64), np.ascontiguousarray(r, dtype=np.float64),
                              np.ascontiguousarray(w, dtype=np.float64), z)


@njit(cache=True, nogil=True)
def play_output_kernel(u, r, w, z):
    """``sum_i w_i P_{r_i}[u]`` from the play states ``z`` (updated in place): the compiled loop of
    :func:`play_output`, on contiguous float64 arrays."""
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


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def reversible_features(u, k):
    """The reversible (memoryless) part of a Preisach model: ramps ``max(u - k_i, 0)`` at the knots ``k``, so that
    with the model's linear column any continuous piecewise-linear function of ``u`` with these knots is a weighted
    sum. The density of a Preisach model concentrated on the line alpha = beta is a function of the input alone
    (Mayergoyz, "Mathematical Models of Hysteresis", ch. 1: the reversible component); a cell-constant grid can
    resolve it only at its cell size and with the cells' hysteresis, a steep anhysteretic rise (a Langevin curve, a
    thin-loop hysteron) needs it at a finer resolution."""
    F = np.empty((u.size, k.size))
    for j in range(u.size):
        x = u[j]
        for i in range(k.size):
            F[j, i] = max(x - k[i], 0.0)
    return F


@njit(cache=True, nogil=True)
def reversible_output(u, k, w):
    """``sum_i w_i max(u - k_i, 0)`` (:func:`reversible_features` weighted), sample by sample in the order of the
    knots: no state."""
    y = np.empty(u.size)
    for j in range(u.size):
        x = u[j]
        acc = 0.0
        for i in range(k.size):
            acc += w[i] * max(x - k[i], 0.0)
        y[j] = acc
    return y
