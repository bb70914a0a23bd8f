"""The load link of the stage chain: V_p -> tip / load, and its stress member.

The Goldfarb-Celanovic actuator (thesis ``000_18d138f03f1777c3.txt`` eqs. 24-27) splits the actuator voltage into
``V = V_p + H(q)`` with ``H`` a function of the charge history alone. A PZT stack's hysteresis also depends on the
mechanical stress it carries: a tip load presses the stack, and the hysteretic voltage at a given charge grows or
shrinks with it. The **stress member** scales the hysteretic voltage with the tip force ``f``, to first order in
``f`` -- the form of the gap diagnostic's ``load.stress_hysteresis`` member ("H(q) scaled by the tip load",
:mod:`selfsense.gap.stages`)::

    V_H = H(q) + w f,     w = s_H (H(q) - a_H) + s_Q (Q - a_Q)          (s_H [1/N], s_Q [V/(C N)])

The calibrated ``H(q)`` is the actuator's hysteretic voltage only up to a linear term of the charge (the gauge of
thesis eq. 55: on the free tip ``V_p = Q / (n_A C_p)`` is exact only for a mechanism without stiffness), so the part
of ``V_H`` that the stress scales is ``H(q) - gamma Q`` for an unknown ``gamma``: hence the two weights. A term
linear in ``f`` alone is the linear two-port's (the force column of the H fit, then ``B21``, ``B22``): on a blocked
tip ``f`` and ``Q`` move together, so a stress term and the two-port's own load dependence are told apart only by
the part of the stress columns that is not along ``f``. The offsets ``a = <column, f> / <f, f>`` over the loaded
calibration rows take that part out (measured on a Bouc-Wen device of the tip campaign: without them the stress
columns took over the force column, the blocked tip's ``V_p`` fell onto the free tip's and the coefficients A1, A2
grew 15-20x with opposite signs, 7.4 -> 30-65 % of Table 3; with them 7.4 -> 1.7 %).

**Identification.** On a free tip ``f = 0`` and the term vanishes; on a calibration trial with a force reference
(the blocked tip) ``f`` is the load cell's. ``H(q) f`` is bilinear in H's parameters and ``s_H``; to first order its
column is ``H_0(q) f_ref``, with ``H_0`` the charge-link reference model (``_reference_h`` of the estimator) fitted
on the free-tip calibration rows (no load, no stress) and evaluated on the loaded trial's charge; the columns
``(H_0(q) - a_H) f_ref`` and ``(Q - a_Q) f_ref`` (:func:`stress_columns`, then the offsets) join the joint H(q) fit
(``SelfSensingEstimator._h_segments``) beside the force column that the force reference already gives, and their
coefficients are ``s_H`` and ``s_Q``. The member is adopted where the columns lower the calibration rows'
blocked-CV error of the reference model by more than :data:`STRESS_MIN_GAIN`.

**Estimation.** Off the calibration trials ``f`` is what is being estimated. The force row of the two-port model is
linear in ``(Q, V_p)`` (thesis eq. 46 / 52: ``f = B21 Q + B22 V_p``) and ``V_p = V - H(q) - w f``; with
``a = B21 Q + B22 (V - H(q))`` and ``b = B22 w`` the two give ``f = a / (1 + b)`` in closed form, sample by sample,
in batch and in a stream alike (:func:`stress_voltage`). Where ``1 + b`` would fall below :data:`STRESS_MIN_DEN` (a
load far outside the calibration's, where the first-order form no longer holds) the denominator is held there.
"""
from __future__ import annotations

import numpy as np

__all__ = ["STRESS_MIN_GAIN", "STRESS_MIN_DEN", "stress_columns", "stress_weight", "stress_voltage"]

#: the stress column must lower the calibration rows' blocked-CV error by more than this fraction to be adopted
STRESS_MIN_GAIN = 0.01
#: the closed form's denominator ``1 + B22 w`` is held at or above this value
STRESS_MIN_DEN = 0.5


def stress_columns(H0, Q, f) -> np.ndarray:
    """The stress member's columns of the joint H(q) fit, ``[H_0(q) f, Q f]``: 0 on a free tip (``f = 0``)."""
    f = np.asarray(f, dtype=float)
    return np.column_stack([np.asarray(H0, dtype=float) * f, np.asarray(Q, dtype=float) * f])


def stress_weight(H, Q, s_h: float, s_q: float, a_h: float = 0.0, a_q: float = 0.0) -> np.ndarray:
    """``w = s_H (H(q) - a_H) + s_Q (Q - a_Q)`` [V/N]: the hysteretic voltage per newton of tip force (``a``: the
    columns' parts along ``f``, which the two-port's force column carries)."""
    return s_h * (np.asarray(H, dtype=float) - a_h) + s_q * (np.asarray(Q, dtype=float) - a_q)


def stress_voltage(Q, Vp0, w, B21: float, B22: float) -> np.ndarray:
    """``V_p`` with the stress member: ``Vp0 - w f`` with ``f = a / max(1 + B22 w, STRESS_MIN_DEN)``,
    ``a = B21 Q + B22 Vp0`` (``Vp0 = V - H(q)``, thesis eq. 27 without the member; ``w`` from :func:`stress_weight`).
    The force row ``B21 Q + B22 V_p`` of the returned ``V_p`` is the force the stress was evaluated at (up to the
    denominator's floor)."""
    Q = np.asarray(Q, dtype=float)
    Vp0 = np.asarray(Vp0, dtype=float)
    w = np.asarray(w, dtype=float)
    a = B21 * Q + B22 * Vp0
    den = np.maximum(1.0 + B22 * w, STRESS_MIN_DEN)
    return Vp0 - w * (a / den)
