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
``a = B21 Q + B22 (V - H(q))`` and ``d = 1 + B22 w`` the two give ``f d = a``, solved sample by sample, in batch
and in a stream alike (:func:`stress_voltage`), kept within the calibration references' force range
``[f_lo, f_hi]`` (the range the estimate is limited to, ``SelfSensingEstimator.ranges_``). ``d`` is not near 1 in
general: ``B22 w`` is the change of the force row per newton of load through the stress (the loop gain of the
inversion), and a strong stress dependence takes it through -1 inside the operating range. There ``f d = a`` holds
for any ``f``: V and Q do not determine the load, and ``a / d`` is the division of two small numbers. The load is
therefore the least-squares solution with a ridge on the load, ``a d / (d^2 + r)`` (:func:`stress_load`), ``r``
chosen from a fixed grid on the calibration trials, where the load is known (0 on a free tip, the force reference on
a loaded one: :func:`choose_load_ridge`; no validation reference is read). Measured on the tip cases of the gap
campaign that have the effect (seed 20261206, development cases; ``benchmarks/gap_tip/stress_solve_20261206.md``):
on Preisach case 104 (stress 11 % of ``V_H`` per 0.1 N, ``B22 w`` from -3.3 to 2.5) the first form, ``d`` held at 0.5
or above, made the member give back 2.75 of the effect's 12.59 points of Table 3, and 9.69 with the ridge; the load
kept in the range without a ridge gave 8.79 there but ran away on Preisach case 124 (Table 3 36.8 points worse; 1.87
points better with the ridge).
"""
from __future__ import annotations

import numpy as np

__all__ = ["STRESS_MIN_GAIN", "LOAD_RIDGE_GRID", "stress_columns", "stress_weight", "stress_load", "stress_voltage",
           "choose_load_ridge"]

#: the stress column must lower the calibration rows' blocked-CV error by more than this fraction to be adopted
STRESS_MIN_GAIN = 0.01


def stress_columns(H0, Q, f) -> np.ndarray:
    """The stress member's columns of the joint H(q) fit, ``[H_0(q) f, Q f]``: 0 on a free tip (``f = 0``)."""
    f = np.asarray(f, dtype=float)
    return np.column_stack([np.asarray(H0, dtype=float) * f, np.asarray(Q, dtype=float) * f])


def stress_weight(H, Q, s_h: float, s_q: float, a_h: float = 0.0, a_q: float = 0.0) -> np.ndarray:
    """``w = s_H (H(q) - a_H) + s_Q (Q - a_Q)`` [V/N]: the hysteretic voltage per newton of tip force (``a``: the
    columns' parts along ``f``, which the two-port's force column carries)."""
    return s_h * (np.asarray(H, dtype=float) - a_h) + s_q * (np.asarray(Q, dtype=float) - a_q)


#: the ridge grid of the load solve (:func:`stress_load`), chosen on the calibration trials (:func:`choose_load_ridge`)
LOAD_RIDGE_GRID = (0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0)


def stress_load(a, d, f_lo: float, f_hi: float, ridge: float = 0.0):
    """The load that solves the force row with the stress member, ``f d = a`` (``a = B21 Q + B22 (V - H(q))``,
    ``d = 1 + B22 w``), in the least-squares sense with a ridge on the load, ``argmin (f d - a)^2 + ridge f^2 =
    a d / (d^2 + ridge)``, kept in ``[f_lo, f_hi]``. With ``ridge`` 0 it is ``a / d``; where ``d`` nears 0 the row
    no longer determines the load and the ridge takes it towards 0 instead of dividing two small numbers (where
    ``d^2 + ridge`` is exactly 0 the load is 0, then held in the range). Scalars or arrays."""
    a = np.asarray(a, dtype=float)
    d = np.asarray(d, dtype=float)
    den = d * d + ridge
    return np.minimum(np.maximum(a * d / np.where(den == 0.0, 1.0, den), f_lo), f_hi)


def stress_voltage(Q, Vp0, w, B21: float, B22: float, f_lo: float, f_hi: float, ridge: float = 0.0) -> np.ndarray:
    """``V_p`` with the stress member: ``Vp0 - w f`` with ``f`` the load of :func:`stress_load`
    (``a = B21 Q + B22 Vp0``, ``Vp0 = V - H(q)``, thesis eq. 27 without the member; ``w`` from :func:`stress_weight`;
    ``[f_lo, f_hi]`` the calibration references' force range). With ``ridge`` 0, wherever ``f`` is inside the range,
    the force row ``B21 Q + B22 V_p`` of the returned ``V_p`` is ``f``."""
    Q = np.asarray(Q, dtype=float)
    Vp0 = np.asarray(Vp0, dtype=float)
    w = np.asarray(w, dtype=float)
    f = stress_load(B21 * Q + B22 * Vp0, 1.0 + B22 * w, f_lo, f_hi, ridge)
    return Vp0 - w * f


def choose_load_ridge(rows, f_lo: float, f_hi: float, grid=LOAD_RIDGE_GRID) -> tuple[float, list[float]]:
    """The ridge of :func:`stress_load` from the calibration trials, where the load is known (0 on a free tip, the
    force reference on a loaded one): ``rows`` holds per trial ``(a, d, f_known)``; the score of a ridge is the mean
    over the trials of the mean ``|f - f_known|`` over the range ``f_hi - f_lo``; the smallest score wins (the first
    on a tie). Returns the ridge and the scores over ``grid``. No validation reference is read."""
    span = max(f_hi - f_lo, np.finfo(float).tiny)
    scores = [float(np.mean([np.mean(np.abs(stress_load(a, d, f_lo, f_hi, r) - fk)) / span for a, d, fk in rows]))
              for r in grid]
    return float(grid[int(np.argmin(scores))]), scores
