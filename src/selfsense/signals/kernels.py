"""The charge integration's scalar kernels, thesis ``000_18d138f03f1777c3.txt`` eq. (57), written once.

``Q = (1/R) int (V_s - offset) dt``: the shunt current and the trapezoidal increment. Each is a scalar kernel
compiled with ``numba.njit(inline="always")`` (the streaming estimator inlines it, via
:mod:`selfsense.sensing.core`), and the NumPy functions evaluate the very same Python expression
(``kernel.py_func``) on arrays, so the batch integration (:func:`selfsense.signals.charge_from_shunt`), the
streaming integrator, the charge link (:mod:`selfsense.chain.charge`) and the plausibility checks round alike.
Units: SI (V, ohm, A, s, C).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["shunt_current", "trapezoid_increment"]


@njit(inline="always")
def _shunt_current(v_s, offset, R):
    """Current through the shunt [A], ``(V_s - offset) / R`` (thesis eq. 57, the integrand)."""
    return (v_s - offset) / R


@njit(inline="always")
def _trapezoid_increment(i_prev, i_k, h):
    """Charge added over one sample [C], trapezoidal rule ``0.5 (i_k + i_{k-1}) (t_k - t_{k-1})`` (thesis eq. 57)."""
    return 0.5 * (i_k + i_prev) * h


def _f(x) -> np.ndarray:
    return np.asarray(x, dtype=float)


def shunt_current(V_s, offset: float, R: float) -> np.ndarray:
    """Shunt current ``(V_s - offset) / R`` [A] (thesis eq. 57)."""
    return _shunt_current.py_func(_f(V_s), offset, R)


def trapezoid_increment(i_prev, i_k, h) -> np.ndarray:
    """Charge increments [C] of the trapezoidal rule, ``0.5 (i_k + i_{k-1}) h`` (thesis eq. 57)."""
    return _trapezoid_increment.py_func(_f(i_prev), _f(i_k), h)
