"""numba kernels for the modified Prandtl-Ishlinskii operators.

All kernels loop over samples outside and over operators inside (sample-outer layout; independent
operator recurrences interleave, see design/notes/snakemake_ecosystem.md section 4). They write into
preallocated outputs and update their state arrays in place, so a caller can stream blocks.

Seed: ``000_18d138f03f1777c3.txt`` eqs. (29)-(31) play, (33)-(34) superposition (third case
corrected to ``min(x - r, 0)``), (38)-(39) creep, (42) fused modified PI operator.

The creep update is written in the algebraically identical form
``c + g * (clamp(c, x - r, x + r) - c)`` with ``g = 1 - exp(-a T_s)``: ``clamp(c, x - r, x + r)`` is the
play operator value, so the three cases of eq. (39) collapse into one branch-free line, and inside the
dead zone the state is returned bit-exactly unchanged.

Note for editing: ``selfsense.sensing.streaming`` compiles ``gamma_kernel`` into its own cached kernels (one call per
streamed sample), and numba's on-disk cache checks only the file a kernel is defined in: after a change here, delete
``src/selfsense/sensing/__pycache__`` (or set an empty ``NUMBA_CACHE_DIR``) so that the stream is compiled again.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# reassociation lets LLVM vectorise the operator sums; results stay deterministic for a given build.
_FM = {"reassoc", "nsz", "contract"}


@njit(cache=True)
def play_kernel(x, r, z, out):
    """Play operators, eq. (31): ``z <- max(x - r, min(x + r, z))``; ``out[k, i]`` (N, n); z updated."""
    n = r.shape[0]
    for k in range(x.shape[0]):
        xk = x[k]
        for i in range(n):
            zi = max(xk - r[i], min(xk + r[i], z[i]))
            z[i] = zi
            out[k, i] = zi


@njit(cache=True)
def superposition_kernel(x, r, out):
    """Superposition operators, eq. (33) two-sided (corrected): r>0 max(x-r,0); r=0 x; r<0 min(x-r,0)."""
    n = r.shape[0]
    for k in range(x.shape[0]):
        xk = x[k]
        for i in range(n):
            ri = r[i]
            if ri > 0.0:
                out[k, i] = max(xk - ri, 0.0)
            elif ri < 0.0:
                out[k, i] = min(xk - ri, 0.0)
            else:
                out[k, i] = xk


@njit(cache=True)
def creep_kernel(x, r, g, c, out):
    """Elementary creep operators, eq. (39) (exact ZOH of eq. 38).

    ``out[0] = c`` (initial state), ``out[k] = update(out[k-1], x[k-1])``; r (n,), g = 1 - exp(-a T_s) (m,),
    c (n, m) state updated in place to the value at the last sample.
    """
    n = r.shape[0]
    m = g.shape[0]
    N = x.shape[0]
    for k in range(N):
        if k > 0:
            xl = x[k - 1]
            for i in range(n):
                lo = xl - r[i]
                hi = xl + r[i]
                for j in range(m):
                    cj = c[i, j]
                    t = max(lo, min(hi, cj))
                    c[i, j] = cj + g[j] * (t - cj)
        for i in range(n):
            for j in range(m):
                out[k, i, j] = c[i, j]


@njit(cache=True, fastmath=_FM)
def gamma_kernel(x, rH, wH, p, rC, wC, gC, c, xlast, b, w0, rSp, wSp, rSn, wSn, out):
    """Fused modified PI operator, eq. (42): y = S[w_H^T H[x] + w_K^T K[x] i + b].

    p (nH,) play states, c (nC,) flattened creep states with per-element threshold rC, weight wC and
    gain gC; xlast (1,) previous input (NaN: no previous sample, the creep states are the initial ones).
    Superposition split into identity weight w0, positive thresholds (rSp, wSp), negative (rSn, wSn).
    """
    nH = rH.shape[0]
    nC = rC.shape[0]
    nP = rSp.shape[0]
    nN = rSn.shape[0]
    xl = xlast[0]
    have = not np.isnan(xl)
    for k in range(x.shape[0]):
        xk = x[k]
        u = b
        for i in range(nH):
            zi = max(xk - rH[i], min(xk + rH[i], p[i]))
            p[i] = zi
            u += wH[i] * zi
        if have:
            for j in range(nC):
                cj = c[j]
                t = max(xl - rC[j], min(xl + rC[j], cj))
                cj = cj + gC[j] * (t - cj)
                c[j] = cj
                u += wC[j] * cj
        else:
            for j in range(nC):
                u += wC[j] * c[j]
            have = True
        xl = xk
        y = w0 * u
        for i in range(nP):
            y += wSp[i] * max(u - rSp[i], 0.0)
        for i in range(nN):
            y += wSn[i] * min(u - rSn[i], 0.0)
        out[k] = y
    xlast[0] = xl


@njit(cache=True)
def _play_sum_at(xv, rH, wH, p):
    s = 0.0
    for i in range(rH.shape[0]):
        s += wH[i] * max(xv - rH[i], min(xv + rH[i], p[i]))
    return s


@njit(cache=True)
def _solve_play(target, rH, wH, p, bp):
    """Exact solve of sum_i w_i clamp(p_i, x - r_i, x + r_i) = target for x (piecewise linear, increasing).

    Breakpoints p_i +- r_i are sorted; binary search for the bracketing segment, then linear interpolation.
    """
    n = rH.shape[0]
    wsum = 0.0
    for i in range(n):
        bp[2 * i] = p[i] - rH[i]
        bp[2 * i + 1] = p[i] + rH[i]
        wsum += wH[i]
    bp.sort()
    M = 2 * n
    f0 = _play_sum_at(bp[0], rH, wH, p)
    if target <= f0:
        return bp[0] + (target - f0) / wsum
    f1 = _play_sum_at(bp[M - 1], rH, wH, p)
    if target >= f1:
        return bp[M - 1] + (target - f1) / wsum
    lo = 0
    hi = M - 1
    flo = f0
    fhi = f1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        fm = _play_sum_at(bp[mid], rH, wH, p)
        if fm <= target:
            lo = mid
            flo = fm
        else:
            hi = mid
            fhi = fm
    # f strictly increasing on [bp[lo], bp[hi]] (the r = 0 operator has positive weight)
    xa = bp[lo]
    xb = bp[hi]
    if fhi > flo:
        # slope from the midpoint (exact for a linear segment)
        xm = 0.5 * (xa + xb)
        s = 0.0
        for i in range(n):
            if xm - rH[i] > p[i] or xm + rH[i] < p[i]:
                s += wH[i]
        if s > 0.0:
            return xa + (target - flo) / s
        return xa + (target - flo) * (xb - xa) / (fhi - flo)
    return xa


@njit(cache=True)
def gamma_inverse_kernel(y, rH, wH, p, rC, wC, gC, c, xlast, b, w0, rSp, wSp, rSn, wSn, out):
    """Inverse of gamma_kernel: the superposition arguments are the INVERSE superposition's parameters.

    Per sample: u = S^{-1}[y]; creep states advance with the previous input (they depend on the past only,
    eq. 39); then the play part is solved exactly for x; play states are updated with x.
    """
    nH = rH.shape[0]
    nC = rC.shape[0]
    nP = rSp.shape[0]
    nN = rSn.shape[0]
    bp = np.empty(2 * nH)
    xl = xlast[0]
    have = not np.isnan(xl)
    for k in range(y.shape[0]):
        yk = y[k]
        u = w0 * yk
        for i in range(nP):
            u += wSp[i] * max(yk - rSp[i], 0.0)
        for i in range(nN):
            u += wSn[i] * min(yk - rSn[i], 0.0)
        cs = 0.0
        if have:
            for j in range(nC):
                cj = c[j]
                t = max(xl - rC[j], min(xl + rC[j], cj))
                cj = cj + gC[j] * (t - cj)
                c[j] = cj
                cs += wC[j] * cj
        else:
            for j in range(nC):
                cs += wC[j] * c[j]
            have = True
        xk = _solve_play(u - b - cs, rH, wH, p, bp)
        for i in range(nH):
            p[i] = max(xk - rH[i], min(xk + rH[i], p[i]))
        xl = xk
        out[k] = xk
    xlast[0] = xl
