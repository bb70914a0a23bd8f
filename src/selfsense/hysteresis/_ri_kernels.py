"""numba kernels of the one-sided rate-independent (RI) hysteresis model.

Seed: ``002_7d89b7147aad52e4.txt`` eqs. (10)-(11) (output), (15) F polynomial, (16) G trend surface,
with the modified wiping-out rule of Sect. 2 (m0 = 0 and M_max are never wiped out).

Memory representation (shared by the kernels and the pure-Python reference in ``ri.py``)
----------------------------------------------------------------------------------------
``E[0..L-1]`` is the alternating list of historical extrema that are not wiped out,
``E = [m0 = 0, M1 = M_max, m1, M2, m2, ...]``. ``E[L-1]`` is the last reversal point: if it is a
minimum (``L`` odd) the input is rising, if it is a maximum (``L`` even) it is falling. ``L == 1`` means
the input is on the initial ascending curve, f = F(u). ``u_prev`` is the previous input.
``P[k]`` (k >= 1) is the prefix sum  sum_{j=1..k} [G(M_j, m_j) - G(M_{j+1}, m_j)]  of eqs. (10)/(11),
defined once M_{k+1} is on the stack (stored at the index of M_{k+1}).

All inputs are the scaled, non-negative input u (dimensionless); negativity is checked by the caller.
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: number of monomials of the trend surface (16)
N_G = 15
#: number of coefficients of the quartic (15)
N_F = 5

# Error codes returned by the kernels
OK = 0
ERR_OVERFLOW = 1


@njit(cache=True)
def F_poly(b, M):
    """Eq. (15): F(M) = b0 + b1 M + b2 M^2 + b3 M^3 + b4 M^4 (Horner)."""
    return b[0] + M * (b[1] + M * (b[2] + M * (b[3] + M * b[4])))


@njit(cache=True)
def G_basis(M, m, out):
    """Eq. (16) monomials in the paper's order p1..p15 (0-based here):
    1, m, M, m^2, Mm, M^2, m^3, Mm^2, M^2 m, M^3, m^4, Mm^3, M^2 m^2, M^3 m, M^4."""
    m2 = m * m
    M2 = M * M
    out[0] = 1.0
    out[1] = m
    out[2] = M
    out[3] = m2
    out[4] = M * m
    out[5] = M2
    out[6] = m2 * m
    out[7] = M * m2
    out[8] = M2 * m
    out[9] = M2 * M
    out[10] = m2 * m2
    out[11] = M * m2 * m
    out[12] = M2 * m2
    out[13] = M2 * M * m
    out[14] = M2 * M2


@njit(cache=True)
def G_surf(p, M, m):
    """Eq. (16): G(M, m) = sum_i p_i * monomial_i(M, m)."""
    m2 = m * m
    M2 = M * M
    return (p[0] + p[1] * m + p[2] * M + p[3] * m2 + p[4] * M * m + p[5] * M2
            + p[6] * m2 * m + p[7] * M * m2 + p[8] * M2 * m + p[9] * M2 * M
            + p[10] * m2 * m2 + p[11] * M * m2 * m + p[12] * M2 * m2 + p[13] * M2 * M * m
            + p[14] * M2 * M2)


@njit(cache=True)
def _update_memory(u, E, P, L, u_prev, p, G_vec, PV, tmp, want_vec):
    """Advance the extrema memory by one sample; returns the new L (or -1 on overflow).

    Reversal detection, push of the reversal point, then the modified wiping-out rule.
    When ``want_vec`` the prefix sums of the G monomials (``PV``, shape (cap, 15)) are kept
    instead of / in addition to the scalar ones (``P``).
    """
    cap = E.shape[0]
    rising = (L % 2) == 1
    if rising and u < u_prev:
        # reversal at a maximum: push u_prev as M_{n+1}
        if L >= cap:
            return -1
        E[L] = u_prev
        if L >= 3:
            # completes the term k = n for M_k = E[L-2], m_k = E[L-1], M_{k+1} = E[L]
            Mk = E[L - 2]
            mk = E[L - 1]
            Mk1 = E[L]
            prev = P[L - 2] if L >= 4 else 0.0
            P[L] = prev + (G_surf(p, Mk, mk) - G_surf(p, Mk1, mk))
            if want_vec:
                G_basis(Mk, mk, G_vec)
                G_basis(Mk1, mk, tmp)
                for i in range(G_vec.shape[0]):
                    base = PV[L - 2, i] if L >= 4 else 0.0
                    PV[L, i] = base + (G_vec[i] - tmp[i])
        else:
            P[L] = 0.0
            if want_vec:
                for i in range(PV.shape[1]):
                    PV[L, i] = 0.0
        L += 1
    elif (not rising) and u > u_prev:
        # reversal at a minimum: push u_prev as m_n
        if L >= cap:
            return -1
        E[L] = u_prev
        P[L] = P[L - 1]
        if want_vec:
            for i in range(PV.shape[1]):
                PV[L, i] = PV[L - 1, i]
        L += 1
    # modified wiping-out rule
    if (L % 2) == 1:
        # rising: a maximum M_n = E[L-2] is wiped (with m_n) when u >= M_n; m0 survives
        while L >= 3 and u >= E[L - 2]:
            L -= 2
    else:
        # falling: a minimum m_{n-1} = E[L-2] (index >= 2, never m0) is wiped (with M_n) when u <= m_{n-1}
        while L >= 4 and u <= E[L - 2]:
            L -= 2
    return L


@njit(cache=True)
def ri_eval_kernel(u, b, p, E, P, L, u_prev):
    """Evaluate eqs. (10)/(11) along ``u``; memory (E, P, L, u_prev) is updated in place / returned.

    Returns (y, L, u_prev, err). err != 0 means the fixed-size extrema stack overflowed.
    """
    n = u.shape[0]
    y = np.empty(n)
    dummy_vec = np.empty(1)
    dummy_pv = np.empty((1, 1))
    for t in range(n):
        ut = u[t]
        L = _update_memory(ut, E, P, L, u_prev, p, dummy_vec, dummy_pv, dummy_vec, False)
        if L < 0:
            return y, 0, u_prev, ERR_OVERFLOW
        u_prev = ut
        if L == 1:
            y[t] = F_poly(b, ut)  # initial ascending curve
        elif (L % 2) == 1:
            # rising, eq. (10): E = [m0, M1, m1, ..., M_n, m_n], L = 2n + 1
            Mn = E[L - 2]
            mn = E[L - 1]
            pre = P[L - 2] if L >= 4 else 0.0  # sum over k = 1..n-1 (stored at index of M_n)
            y[t] = F_poly(b, E[1]) - pre - (G_surf(p, Mn, mn) - G_surf(p, ut, mn))
        else:
            # falling, eq. (11): E = [m0, M1, m1, ..., m_{n-1}, M_n], L = 2n
            Mn = E[L - 1]
            pre = P[L - 1] if L >= 4 else 0.0
            y[t] = F_poly(b, E[1]) - pre - G_surf(p, Mn, ut)
    return y, L, u_prev, OK


@njit(cache=True)
def ri_regressor_kernel(u, E, P, PV, L, u_prev):
    """Regressor of the RI model, linear in (b, p): y[t] = Phi[t, :5] @ b + Phi[t, 5:] @ p.

    Same memory logic as ``ri_eval_kernel`` (P unused apart from bookkeeping).
    Returns (Phi, L, u_prev, err).
    """
    n = u.shape[0]
    Phi = np.zeros((n, N_F + N_G))
    g = np.empty(N_G)
    h = np.empty(N_G)
    pz = np.zeros(N_G)
    for t in range(n):
        ut = u[t]
        L = _update_memory(ut, E, P, L, u_prev, pz, g, PV, h, True)
        if L < 0:
            return Phi, 0, u_prev, ERR_OVERFLOW
        u_prev = ut
        if L == 1:
            Mf = ut
        else:
            Mf = E[1]
        v = 1.0
        for i in range(N_F):
            Phi[t, i] = v
            v *= Mf
        if L == 1:
            continue
        if (L % 2) == 1:
            Mn = E[L - 2]
            mn = E[L - 1]
            G_basis(Mn, mn, g)
            G_basis(ut, mn, h)
            for i in range(N_G):
                pre = PV[L - 2, i] if L >= 4 else 0.0
                Phi[t, N_F + i] = -pre - (g[i] - h[i])
        else:
            Mn = E[L - 1]
            G_basis(Mn, ut, g)
            for i in range(N_G):
                pre = PV[L - 1, i] if L >= 4 else 0.0
                Phi[t, N_F + i] = -pre - g[i]
    return Phi, L, u_prev, OK


@njit(cache=True)
def abg_filter_kernel(z, dt, alpha, beta, gamma):
    """alpha-beta-gamma tracking filter (position, velocity, acceleration estimates).

    Used as in 002_7d89b7147aad52e4.txt Sect. 4.3 to estimate x1', x1'' from measured x1.
    Gains in the form x += alpha r, v += beta r / dt, acc += gamma r / (2 dt^2) (r = innovation); with
    the paper gains this form is stable (the 2 gamma / dt^2 form is not: gamma > 4 alpha beta / (2 - alpha)).
    """
    n = z.shape[0]
    x = np.empty(n)
    v = np.empty(n)
    a = np.empty(n)
    xp = z[0]
    vp = 0.0
    ap = 0.0
    for k in range(n):
        # predict
        xk = xp + dt * vp + 0.5 * dt * dt * ap
        vk = vp + dt * ap
        ak = ap
        r = z[k] - xk
        xk += alpha * r
        vk += beta * r / dt
        ak += gamma * r / (2.0 * dt * dt)
        x[k] = xk
        v[k] = vk
        a[k] = ak
        xp, vp, ap = xk, vk, ak
    return x, v, a


@njit(cache=True)
def bouc_wen_kernel(u, d, alpha, beta, gamma, c2, n_sub, h0, u0):
    """Asymmetric one-sided Bouc-Wen hysteresis (rate independent) used by the virtual single stack.

    x_h = d * u + c2 * d * u^2 - h,   dh = (alpha d - beta sign(du) h - gamma |h|) du  (n = 1 Bouc-Wen),
    integrated with ``n_sub`` explicit sub-steps per sample. Returns (x_h, h_end).
    """
    n = u.shape[0]
    out = np.empty(n)
    h = h0
    up = u0
    for k in range(n):
        du = (u[k] - up) / n_sub
        for _ in range(n_sub):
            s = 1.0 if du >= 0 else -1.0
            h += (alpha * d - beta * s * h - gamma * abs(h)) * du
        up = u[k]
        out[k] = d * up + c2 * d * up * up - h
    return out, h


@njit(cache=True)
def dss_kernel(Ad, Bd, C, D, u, x0):
    """Discrete state space x[k+1] = Ad x[k] + Bd u[k], y[k] = C x[k] + D u[k] (single input/output).

    Returns (y, x_end)."""
    n = u.shape[0]
    ns = Ad.shape[0]
    y = np.empty(n)
    x = x0.copy()
    xn = np.empty(ns)
    for k in range(n):
        acc = D * u[k]
        for i in range(ns):
            acc += C[i] * x[i]
        y[k] = acc
        for i in range(ns):
            s = Bd[i] * u[k]
            for j in range(ns):
                s += Ad[i, j] * x[j]
            xn[i] = s
        for i in range(ns):
            x[i] = xn[i]
    return y, x
