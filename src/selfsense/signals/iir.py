"""Recursive (IIR) filtering of one record: ``lfilter(b, a, x, zi)``, the difference equation
``a[0] y[n] = sum_k b[k] x[n-k] - sum_{k>=1} a[k] y[n-k]`` in the transposed direct form II, with the arithmetic of
:func:`scipy.signal.lfilter` (coefficients divided by ``a[0]``, the delays updated in the same order), so the two
give the same bits. It stands in for SciPy's because importing :mod:`scipy.signal` costs about a second of start-up
in every job process, and the chain uses only these low-order filters (the first-order low-pass of the charge
link's absorption branch and temperature lag, thesis ``000_18d138f03f1777c3.txt`` eq. 57's leaky integral, the
gap diagnostic's resonator)."""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["lfilter"]


@njit(cache=True, nogil=True)
def _df2t(b, a, x, z):
    n_c = b.size
    y = np.empty(x.size)
    for k in range(x.size):
        xn = x[k]
        if n_c > 1:
            yn = z[0] + b[0] * xn
            for n in range(n_c - 2):
                z[n] = z[n + 1] + xn * b[n + 1] - yn * a[n + 1]
            z[n_c - 2] = xn * b[n_c - 1] - yn * a[n_c - 1]
        else:
            yn = xn * b[0]
        y[k] = yn
    return y


def lfilter(b, a, x, zi=None):
    """Filter the 1-D record ``x`` with numerator ``b`` and denominator ``a`` (``a[0] != 0``), from the delay state
    ``zi`` (length ``max(len(a), len(b)) - 1``; zeros when None). Returns ``y``, or ``(y, zf)`` with ``zi`` given,
    as :func:`scipy.signal.lfilter` does for a 1-D float record."""
    b = np.atleast_1d(np.asarray(b, dtype=float))
    a = np.atleast_1d(np.asarray(a, dtype=float))
    x = np.ascontiguousarray(np.asarray(x, dtype=float))
    if b.ndim != 1 or a.ndim != 1 or x.ndim != 1:
        raise ValueError("lfilter: b, a and x must be one-dimensional")
    if a.size == 0 or a[0] == 0.0:
        raise ValueError("lfilter: the first denominator coefficient a[0] must be nonzero")
    n_c = max(a.size, b.size)
    bb = np.zeros(n_c)
    aa = np.zeros(n_c)
    bb[:b.size] = b
    aa[:a.size] = a
    a0 = aa[0]
    bb = bb / a0
    aa = aa / a0
    z = np.zeros(max(n_c - 1, 1))
    if zi is not None:
        zi = np.atleast_1d(np.asarray(zi, dtype=float))
        if zi.shape != (n_c - 1,):
            raise ValueError(f"lfilter: zi has shape {zi.shape}, expected ({n_c - 1},)")
        z[:n_c - 1] = zi
    y = _df2t(bb, aa, x, z)
    return y if zi is None else (y, z[:n_c - 1].copy())
