"""The sensing equations, written once (thesis 000_18d138f03f1777c3.txt; paper 001_972cacfaa08ad91a.txt).

Pure functions of arrays in SI units; the batch estimator (``estimator.py``), the streaming estimator's set-up
(``streaming.py``) and the gap diagnostic call these.

* eq. (57): charge from the shunt voltage -> :func:`selfsense.signals.charge_from_shunt` (re-exported);
* eq. (27): ``V_p = V - V_H`` -> :func:`piezo_voltage`;
* eq. (55): H(q) calibration target on a free tip, ``V - slope Q`` -> :func:`h_target` (``slope = 1 / (n_A C_p)``;
  paper eq. (23): ``slope = (1 - alpha B A_q) / (n_A C_p)``);
* eq. (52) / (46): tip displacement and force from charge and V_p -> :func:`tip_displacement`, :func:`tip_force`.
"""
from __future__ import annotations

import numpy as np

from selfsense.signals import charge_from_shunt  # noqa: F401  (eq. 57, re-exported)

__all__ = ["charge_from_shunt", "piezo_voltage", "h_target", "tip_displacement", "tip_force", "force_coefficients"]


def piezo_voltage(V, V_H) -> np.ndarray:
    """``V_p = V - V_H`` [V] (thesis eq. 27: the voltage across the linear part of the Goldfarb-Celanovic model)."""
    return np.asarray(V, dtype=float) - np.asarray(V_H, dtype=float)


def h_target(V, Q, slope: float) -> np.ndarray:
    """Free-tip calibration target of H [V]: ``V - slope * Q`` (thesis eq. 55 with ``slope = 1 / (n_A C_p)``,
    paper eq. 23 with ``slope = (1 - alpha B A_q) / (n_A C_p)``), Q the total charge [C]."""
    return np.asarray(V, dtype=float) - slope * np.asarray(Q, dtype=float)


def tip_displacement(Q, V_p, A1: float, A2: float) -> np.ndarray:
    """Tip closing [m], thesis eq. (52) first row: ``dx = A1 (n_A q) + A2 V_p`` with ``n_A q = Q`` the total charge."""
    return A1 * np.asarray(Q, dtype=float) + A2 * np.asarray(V_p, dtype=float)


def tip_force(Q, V_p, B21: float, B22: float) -> np.ndarray:
    """Tip force [N], thesis eq. (46) second row ``f = B21 Q + B22 V_p``; eq. (52) is the special case
    ``B21 = A3 / n_A``, ``B22 = -C_p A3`` (:func:`force_coefficients`)."""
    return B21 * np.asarray(Q, dtype=float) + B22 * np.asarray(V_p, dtype=float)


def force_coefficients(A3: float, n_A: float, C_p: float) -> tuple[float, float]:
    """(B21, B22) of thesis eq. (52): ``f = (A3 / n_A) (Q - n_A C_p V_p)``."""
    return A3 / n_A, -C_p * A3
