"""Compiled kernel of the generic Duhem (Coleman-Hodgdon) H(q) model of the registry (``kind = "duhem"``).

The state ``v`` follows ``dv = g_s(u, v) du`` with ``s`` the direction of the input (ascending / descending) and
``g_s`` a polynomial of total degree ``deg`` in ``x = 2 u - 1`` and ``w = 2 (v - v_lo) / v_span - 1`` (both clipped to
[-1.5, 1.5], so that the slope stays bounded outside the identified region). Discretised as the map
``v_{k+1} = v_k + g_{s_k}(u_k, v_k) (u_{k+1} - u_k)`` on the samples; the direction switches only after the input
has moved ``eps`` away from its last extremum (a dead band, so that sensor noise at a hold does not ratchet the
state). The kernel also returns the forward sensitivities ``dv_k / dc`` (exact derivatives of the discrete map) for
the Gauss-Newton / trust-region output-error fit.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["n_terms", "duhem_run", "duhem_state", "duhem_terms"]

_CLIP = 1.5


def n_terms(deg: int) -> int:
    """Number of monomials x^i w^j with i + j <= deg."""
    return (deg + 1) * (deg + 2) // 2


@njit(cache=True, nogil=True)
def duhem_terms(x, w, deg, out, dout_dw):
    """Monomials ``x^i w^j`` (i + j <= deg, ordered by i then j) and their derivatives in w."""
    m = 0
    xi = 1.0
    for i in range(deg + 1):
        wj = 1.0
        wjm1 = 0.0   # w^(j-1)
        for j in range(deg + 1 - i):
            out[m] = xi * wj
            dout_dw[m] = xi * j * wjm1
            wjm1 = wj
            wj *= w
            m += 1
        xi *= x


def duhem_state() -> np.ndarray:
    """The relaxed state of :func:`duhem_run`: ``[v, direction (+1 ascending), last extremum, previous input,
    started (0/1)]`` with v = 0, ascending first. Streaming callers keep it between blocks."""
    return np.array([0.0, 1.0, 0.0, 0.0, 0.0])


@njit(cache=True, nogil=True)
def duhem_run(u, c, deg, v_lo, v_span, eps, v_min, v_max, stride, jac, st):
    """Run the map from the state ``st`` (:func:`duhem_state`: v = 0, ascending first, for the relaxed state),
    which is updated in place. ``c`` = [ascending | descending] coefficients.

    Each incoming sample u_k first moves the state from the previous input (direction with its dead band, then
    ``v += g_s(u_{k-1}, v) (u_k - u_{k-1})``), then V_k = v; the first sample ever only starts the map (V_0 = v).
    Returns ``V`` (every ``stride``-th sample) and, with ``jac``, ``J = dV / dc`` at the same rows (the
    sensitivities start from zero at the first sample of the call: ``jac`` is for fits from the relaxed state)."""
    n = u.size
    nb = (deg + 1) * (deg + 2) // 2
    p = 2 * nb
    nr = (n + stride - 1) // stride
    V = np.empty(nr)
    J = np.zeros((nr if jac else 1, p))
    sens = np.zeros(p)
    phi = np.empty(nb)
    dphi = np.empty(nb)
    val = st[0]
    s = 1 if st[1] > 0 else -1
    ext = st[2]
    up = st[3]
    started = st[4] != 0.0
    for k in range(n):
        un = u[k]
        if not started:
            started = True
            ext = un
        else:
            if s > 0:
                if un > ext:
                    ext = un
                elif ext - un > eps:
                    s = -1
                    ext = un
            else:
                if un < ext:
                    ext = un
                elif un - ext > eps:
                    s = 1
                    ext = un
            du = un - up
            x = min(max(2.0 * up - 1.0, -_CLIP), _CLIP)
            wr = 2.0 * (val - v_lo) / v_span - 1.0
            w = min(max(wr, -_CLIP), _CLIP)
            duhem_terms(x, w, deg, phi, dphi)
            off = 0 if s > 0 else nb
            g = 0.0
            dg_dw = 0.0
            for m in range(nb):
                g += c[off + m] * phi[m]
                dg_dw += c[off + m] * dphi[m]
            new = val + g * du
            clipped = new < v_min or new > v_max
            if jac:
                dw_dv = 2.0 / v_span if (wr > -_CLIP and wr < _CLIP) else 0.0
                a = 1.0 + dg_dw * dw_dv * du
                if clipped:
                    for m in range(p):
                        sens[m] = 0.0
                else:
                    for m in range(p):
                        x_ = sens[m] * a
                        # flush to zero: a decaying sensitivity would otherwise turn subnormal (slow arithmetic)
                        sens[m] = x_ if abs(x_) > 1e-150 else 0.0
                    for m in range(nb):
                        sens[off + m] += phi[m] * du
            val = min(max(new, v_min), v_max)
        up = un
        if k % stride == 0:
            V[k // stride] = val
            if jac:
                for m in range(p):
                    J[k // stride, m] = sens[m]
    st[0] = val
    st[1] = 1.0 if s > 0 else -1.0
    st[2] = ext
    st[3] = up
    st[4] = 1.0 if started else 0.0
    return V, J
