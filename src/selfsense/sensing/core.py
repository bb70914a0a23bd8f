"""The sensing equations, written once (thesis 000_18d138f03f1777c3.txt; paper 001_972cacfaa08ad91a.txt).

Every place that evaluates one of these equations calls the definitions here: the batch estimator
(``estimator.py``), the streaming estimator's per-sample numba kernel (``streaming.py``), the batch charge
integration (:func:`selfsense.signals.charge_from_shunt`) and the gap diagnostic's fast estimator
(``selfsense.gap.standin``). Each equation is one scalar kernel compiled with ``numba.njit(inline="always")``, which
the streaming kernel inlines, and the NumPy functions below evaluate the very same Python expression
(``kernel.py_func``) on arrays, elementwise and in the same order, so batch and streaming round alike.

* eq. (57): charge from the shunt voltage, ``Q = (1/R) int (V_s - offset) dt``: shunt current
  :func:`_shunt_current`, trapezoidal increment :func:`_trapezoid_increment`, defined in
  :mod:`selfsense.signals.kernels` beside :func:`selfsense.signals.charge_from_shunt` (the layer below) and
  re-exported here for the streaming integrator;
* eq. (27): ``V_p = V - V_H`` -> :func:`piezo_voltage`;
* eq. (55): H(q) calibration target on a free tip, ``V - slope Q`` -> :func:`h_target` (``slope = 1 / (n_A C_p)``;
  paper eq. (23): ``slope = (1 - alpha B A_q) / (n_A C_p)``);
* eq. (52) / (46): tip displacement and force from charge and V_p -> :func:`tip_displacement`, :func:`tip_force`
  (one kernel :func:`_tip_linear`), the approximated force row's regressor ``Q - n_A C_p V_p`` ->
  :func:`force_regressor` and its coefficients -> :func:`force_coefficients`.

Units: SI (C, V, A, s, m, N). Note for editing: numba's on-disk cache of ``streaming.py``'s kernels does not see
changes to the kernels here or in ``selfsense.hysteresis._kernels`` (they are compiled into the stream's own
kernels; numba checks only the file a cached kernel is defined in); the streaming tests compare both paths, and
deleting ``sensing/__pycache__`` forces a recompile.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from selfsense.signals import charge_from_shunt  # noqa: F401  (eq. 57, re-exported)
from selfsense.signals.kernels import (_shunt_current, _trapezoid_increment, shunt_current,  # noqa: F401
                                       trapezoid_increment)  # eq. (57), defined with the charge integration

__all__ = ["charge_from_shunt", "piezo_voltage", "h_target", "tip_displacement", "tip_force", "force_regressor",
           "force_coefficients", "shunt_current", "trapezoid_increment"]


# ---- scalar kernels (numba, inlined by the streaming kernel); the NumPy functions call their py_func ----------
@njit(inline="always")
def _piezo_voltage(v, v_h):
    """``V_p = V - V_H`` [V] (thesis eq. 27)."""
    return v - v_h


@njit(inline="always")
def _h_target(v, q, slope):
    """``V - slope Q`` [V] (thesis eq. 55, paper eq. 23)."""
    return v - slope * q


@njit(inline="always")
def _tip_linear(q, vp, a, b, c):
    """``a Q + b V_p + c`` (thesis eq. 52 / eq. 46, one row): displacement with (A1, A2) and the rest closing
    ``c = dx0`` (0 unless the estimator adopted it: eq. 52 on the total charge ``Q + q_0``), force with (B21, B22)
    and ``c = 0``."""
    return a * q + b * vp + c


@njit(inline="always")
def _force_regressor(q, vp, n_A, C_p):
    """``Q - n_A C_p V_p`` [C] (thesis eq. 52, second row: ``f = (A3 / n_A) (Q - n_A C_p V_p)``)."""
    return q - n_A * C_p * vp


def _f(x) -> np.ndarray:
    return np.asarray(x, dtype=float)


# ---- NumPy functions ---------------------------------------------------------------------------------------------
def piezo_voltage(V, V_H) -> np.ndarray:
    """``V_p = V - V_H`` [V] (thesis eq. 27: the voltage across the linear part of the Goldfarb-Celanovic model)."""
    return _piezo_voltage.py_func(_f(V), _f(V_H))


def h_target(V, Q, slope: float) -> np.ndarray:
    """Free-tip calibration target of H [V]: ``V - slope * Q`` (thesis eq. 55 with ``slope = 1 / (n_A C_p)``,
    paper eq. 23 with ``slope = (1 - alpha B A_q) / (n_A C_p)``), Q the total charge [C]."""
    return _h_target.py_func(_f(V), _f(Q), slope)


def tip_displacement(Q, V_p, A1: float, A2: float, dx0: float = 0.0) -> np.ndarray:
    """Tip closing [m], thesis eq. (52) first row: ``dx = A1 (n_A q) + A2 V_p + dx0`` with ``n_A q = Q`` the total
    charge and ``dx0`` the rest closing (``A1 q_0``: remanent charge the integrator never saw)."""
    return _tip_linear.py_func(_f(Q), _f(V_p), A1, A2, dx0)


def tip_force(Q, V_p, B21: float, B22: float) -> np.ndarray:
    """Tip force [N], thesis eq. (46) second row ``f = B21 Q + B22 V_p``; eq. (52) is the special case
    ``B21 = A3 / n_A``, ``B22 = -C_p A3`` (:func:`force_coefficients`)."""
    return _tip_linear.py_func(_f(Q), _f(V_p), B21, B22, 0.0)


def force_regressor(Q, V_p, n_A: float, C_p: float) -> np.ndarray:
    """The one regressor of the approximated force row, thesis eq. (52): ``f = (A3 / n_A) (Q - n_A C_p V_p)``."""
    return _force_regressor.py_func(_f(Q), _f(V_p), n_A, C_p)


def force_coefficients(A3: float, n_A: float, C_p: float) -> tuple[float, float]:
    """(B21, B22) of thesis eq. (52): ``f = (A3 / n_A) (Q - n_A C_p V_p)``."""
    return A3 / n_A, -C_p * A3
