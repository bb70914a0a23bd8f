"""Goldfarb-Celanovic piezo model combined with the mechanism two-port.

Seeds: thesis ``000_18d138f03f1777c3.txt`` eqs. (24)-(27), (44)-(55), (58)-(59), Tables 1-2;
paper ``001_972cacfaa08ad91a.txt`` eqs. (13)-(23), Table I.

Conventions (see also :mod:`selfsense.mechanics.twoport` and docs/mechanics.md):

* ``alpha`` [N/V], ``Cp`` [F], ``k`` [N/m] are PER ACTUATOR; ``n_A`` actuators are
  electrically in parallel and each drives its own rhomboid (identical inputs).
* ``q`` in the seeds' equations (24), (44) is the per-actuator charge. The input vector of
  (45)-(46) is ``[n_A q_per, V_p]`` = ``[q_total, V_p]``, i.e. the CONTRACT charge
  (total charge seen by the shunt) can be fed directly to :func:`tip_matrix`.
* ``S1, S2, S3`` [N/m] form the symmetric PSD stiffness of the whole mechanism with forces
  applied ON the mechanism: ``F_in = S1 x_pzt + S3 dx_tip`` (F_in = total force of the n_A
  PZTs), ``F_out = S3 x_pzt + S2 dx_tip`` where ``F_out`` is the force the object exerts on
  the tip. Hence ``S3 < 0`` and the contract pinching force is ``f_tip = -F_out``.
* The literal eq. (45) second row is ``F_out`` (= ``-f_tip`` pinch-positive). This is an
  internal inconsistency of the thesis, whose eq. (51) uses pinch-positive f_tip.
  ``convention="thesis"`` returns the literal (45); ``convention="contract"`` negates the
  force row so that f_tip is positive when pinching (docs/dev/CONTRACTS.md).
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "piezo_matrix",
    "charge",
    "pzt_displacement",
    "pzt_force",
    "actuator_voltage",
    "tip_matrix",
    "tip_matrix_closed_form",
    "a_coefficients",
    "approximation_terms",
    "S_from_measurements",
    "THESIS_TABLE2",
    "table2_recompute",
    "onsite_B",
    "onsite_h_slope",
    "onsite_A_q",
    "free_blocked_response",
    "static_response",
    "pzt_to_tip_sensitivity",
]


# ----------------------------------------------------------------------------- eqs. 24-27, 44
def piezo_matrix(alpha: float, Cp: float, k: float) -> np.ndarray:
    """Thesis eq. (44): ``[x, F] = M [q, V_p]`` for ONE actuator.

    ``x`` [m] stack elongation, ``F`` [N] force supplied BY the actuator on its
    environment (``F = alpha V_p - k x``), ``q`` [C] per-actuator charge, ``V_p`` [V].
    ``M = [[1/alpha, -Cp/alpha], [-k/alpha, alpha + Cp k/alpha]]`` (det M = 1).
    """
    return np.array([[1.0 / alpha, -Cp / alpha], [-k / alpha, alpha + Cp * k / alpha]], dtype=float)


def charge(alpha, x, Cp, Vp):
    """Per-actuator charge [C], thesis eq. (24): ``q = alpha x + C_p V_p``."""
    return alpha * np.asarray(x, dtype=float) + Cp * np.asarray(Vp, dtype=float)


def pzt_displacement(alpha, F_ext, Vp, k):
    """Stack elongation [m], thesis eq. (26): ``x = (F_ext + alpha V_p)/k``.

    ``F_ext`` [N] is the external force on the actuator, positive in the +x (tension)
    direction; the force supplied by the actuator is ``-F_ext``.
    """
    return (np.asarray(F_ext, dtype=float) + alpha * np.asarray(Vp, dtype=float)) / k


def pzt_force(alpha, x, Vp, k):
    """Force supplied by the actuator [N] (negated eq. 26, as in eq. 44): ``alpha V_p - k x``."""
    return alpha * np.asarray(Vp, dtype=float) - k * np.asarray(x, dtype=float)


def actuator_voltage(Vp, V_H):
    """Thesis eq. (27): ``V = V_p + V_H`` [V]."""
    return np.asarray(Vp, dtype=float) + np.asarray(V_H, dtype=float)


# ----------------------------------------------------------------------------- eqs. 45-48, 53
def _check_conv(convention: str) -> float:
    if convention == "thesis":
        return 1.0
    if convention == "contract":
        return -1.0
    raise ValueError(f"convention must be 'thesis' or 'contract', got {convention!r}")


def tip_matrix(S1, S2, S3, alpha, Cp, k, n_A, convention: str = "thesis") -> np.ndarray:
    """Thesis eq. (45): ``[dx_tip, f] = M [n_A q, V_p]`` (``n_A q`` = total charge [C]).

    Computed as the product printed in (45): ``T(S) @ P`` with
    ``T(S) = [[-S1/S3, 1/S3], [S3 - S1 S2/S3, S2/S3]]`` (eq. 21) and
    ``P = [[1/(n_A alpha), -Cp/alpha], [-k/alpha, n_A alpha + n_A Cp k/alpha]]``;
    the closed form printed in (45) equals this product (checked in tests).

    ``convention="thesis"``: second row is the literal (45) force = force exerted by the
    object on the tip (``= -f_tip`` pinch-positive when S3 < 0). ``"contract"``: second row
    negated, i.e. pinch-positive ``f_tip`` (docs/dev/CONTRACTS.md). Units: M11 [m/C], M12 [m/V],
    M21 [N/C], M22 [N/V].
    """
    sgn = _check_conv(convention)
    T = np.array([[-S1 / S3, 1.0 / S3], [S3 - S1 * S2 / S3, S2 / S3]], dtype=float)
    P = np.array([[1.0 / (n_A * alpha), -Cp / alpha],
                  [-k / alpha, n_A * alpha + n_A * Cp * k / alpha]], dtype=float)
    M = T @ P
    M[1, :] *= sgn
    return M


def tip_matrix_closed_form(S1, S2, S3, alpha, Cp, k, n_A) -> np.ndarray:
    """The closed form printed in thesis eq. (45) (thesis sign convention)."""
    num1 = -n_A * k - S1
    num2 = n_A * Cp * k + Cp * S1 + n_A * alpha ** 2
    return np.array([
        [num1 / (n_A * S3 * alpha), num2 / (S3 * alpha)],
        [(S2 * num1 + S3 ** 2) / (n_A * S3 * alpha), (S2 * num2 - Cp * S3 ** 2) / (S3 * alpha)],
    ], dtype=float)


def force_row(A1: float, A2: float, A3: float, S2: float, n_A: float, Cp: float) -> tuple[float, float]:
    """(B21, B22) of the unapproximated force row of thesis eq. (46): ``B21 = S2 A1 + A3 / n_A``,
    ``B22 = S2 A2 - Cp A3`` with ``A3 = S3 / alpha`` (eq. 53). That is ``f = S3 x_pzt + S2 dx_tip``: the
    eq. (52) force plus the tip port's own stiffness ``S2`` [N/m] times the displacement row; eq. (52) is ``S2 = 0``."""
    return S2 * A1 + A3 / n_A, S2 * A2 - Cp * A3


def a_coefficients(S1, S2, S3, alpha, Cp, k, n_A) -> dict:
    """Thesis eqs. (46)-(48), (53) (thesis sign convention of the force row).

    ``A1 = (-n_A k - S1)/(n_A S3 alpha)`` [m/C], ``A2 = (n_A Cp k + Cp S1 + n_A alpha^2)/(S3 alpha)``
    [m/V], ``A3 = S3/alpha`` [V/m = N/C], ``B21 = S2 A1 + S3/(n_A alpha)`` [N/C],
    ``B22 = S2 A2 - Cp S3/alpha`` [N/V] (unapproximated second row of (46)).
    """
    A1 = (-n_A * k - S1) / (n_A * S3 * alpha)
    A2 = (n_A * Cp * k + Cp * S1 + n_A * alpha ** 2) / (S3 * alpha)
    A3 = S3 / alpha
    B21, B22 = force_row(A1, A2, A3, S2, n_A, Cp)
    return dict(A1=A1, A2=A2, A3=A3, B21=B21, B22=B22)


def approximation_terms(S1, S2, S3, alpha, Cp, k, n_A) -> dict:
    """Size of every term of eq. (46) and what the approximation (52)-(53) neglects.

    (52) keeps ``S3/(n_A alpha)`` (= A3/n_A) in B21 and ``-Cp S3/alpha`` (= -Cp A3) in B22,
    dropping ``S2 A1`` and ``S2 A2``. Returned fractions:
    ``neglected_frac_21 = |S2 A1| / |B21|`` (relative error of (52) on B21) and
    ``ratio_21 = |S2 A1| / |S3/(n_A alpha)|`` (neglected vs kept); same for 22.
    Note ``S2 (A1 n_A q + A2 V_p) = S2 dx_tip`` exactly, so (52) amounts to
    ``f = S3 x_pzt`` (drops the tip-stiffness force ``S2 dx_tip``), exact only when blocked.
    """
    c = a_coefficients(S1, S2, S3, alpha, Cp, k, n_A)
    S2A1 = S2 * c["A1"]
    S2A2 = S2 * c["A2"]
    kept21 = S3 / (n_A * alpha)
    kept22 = Cp * S3 / alpha
    return dict(
        A1=c["A1"], A2=c["A2"], A3=c["A3"], S2A1=S2A1, S2A2=S2A2,
        S3_over_nA_alpha=kept21, Cp_S3_over_alpha=kept22, B21=c["B21"], B22=c["B22"],
        neglected_frac_21=abs(S2A1) / abs(c["B21"]) if c["B21"] != 0 else np.inf,
        neglected_frac_22=abs(S2A2) / abs(c["B22"]) if c["B22"] != 0 else np.inf,
        ratio_21=abs(S2A1) / abs(kept21), ratio_22=abs(S2A2) / abs(kept22),
    )


# ----------------------------------------------------------------------------- eqs. 49-51
def S_from_measurements(f_in_block, dx_pzt_block, dx_tip_free, dx_pzt_free, f_tip_block,
                        *, n_A: int = 1, eq50: str = "corrected") -> tuple[float, float, float]:
    """Mechanism stiffness from free/blocked-tip data, thesis eqs. (49)-(51).

    ``f_in_block`` [N] PZT force on the mechanism with blocked tip, PER ACTUATOR if
    ``n_A > 1`` (total = ``n_A f_in_block``; thesis Table 2(b)'s S1 = 2e8 N/m is
    ``5 * 200 N / 5 um``). ``f_tip_block`` [N] pinch-positive blocked tip force.
    Displacements [m]. Returns (S1, S2, S3) [N/m] in the PSD convention:

    * (49) ``S1 = n_A f_in_block / dx_pzt_block``
    * (51) ``S3 = -f_tip_block / dx_pzt_block``
    * (50) ``eq50="corrected"`` (default): from ``F_out = S3 x_pzt + S2 dx_tip = 0`` at the
      free tip, ``S2 = -S3 dx_pzt_free/dx_tip_free
      = f_tip_block dx_pzt_free / (dx_pzt_block dx_tip_free)`` [N/m].
      ``eq50="printed"``: the printed ``dx_tip_free dx_pzt_block/(dx_pzt_free f_tip_block)``,
      which is the reciprocal and has units m/N (dimensionally wrong).
    """
    S1 = n_A * f_in_block / dx_pzt_block
    S3 = -f_tip_block / dx_pzt_block
    if eq50 == "corrected":
        S2 = f_tip_block * dx_pzt_free / (dx_pzt_block * dx_tip_free)
    elif eq50 == "printed":
        S2 = dx_tip_free * dx_pzt_block / (dx_pzt_free * f_tip_block)
    else:
        raise ValueError(f"eq50 must be 'corrected' or 'printed', got {eq50!r}")
    return float(S1), float(S2), float(S3)


#: Thesis 000_18d138f03f1777c3.txt Table 2 as printed (SI units).
THESIS_TABLE2 = {
    "a": dict(dx_tip_free=6.4e-3, dx_pzt_free=7e-6, dx_pzt_block=5e-6, f_in_block=200.0, f_tip_block=0.1),
    "b": dict(S1=2e8, S2=4.5e-3, S3=-2e5, alpha=1.6, k=24e6, Cp=0.25e-6),
    "c": dict(A1=-1000.0, A2=1.7e-3, S2A1=45.7, S2A2=7.5e-5, S3_over_nA_alpha=-2500.0, Cp_S3_over_alpha=3.1e-3),
    "n_A": 5,
}


def table2_recompute() -> dict:
    """Recompute thesis Table 2(b)/(c) from Table 2(a) (and from printed 2(b)).

    Returns ``{"S": {...}, "c": {column: {term: value}}}`` with columns
    ``printed`` (Table 2(c)), ``from_printed_b`` (eqs. 47-48, 53 on printed 2(b)),
    ``from_a_printed50`` (S from 2(a) via printed (49)-(51)), ``from_a_corrected50``
    (S from 2(a) with the dimensionally corrected (50)); alpha, k, Cp from printed 2(b).
    """
    t = THESIS_TABLE2
    a, b, nA = t["a"], t["b"], t["n_A"]
    S_pr = S_from_measurements(n_A=nA, eq50="printed", **a)
    S_co = S_from_measurements(n_A=nA, eq50="corrected", **a)
    keys = list(t["c"].keys())

    def terms(S):
        r = approximation_terms(S[0], S[1], S[2], b["alpha"], b["Cp"], b["k"], nA)
        return {kk: r[kk] for kk in keys}

    return {
        "S": {"printed_b": (b["S1"], b["S2"], b["S3"]), "from_a_printed50": S_pr, "from_a_corrected50": S_co},
        "c": {
            "printed": dict(t["c"]),
            "from_printed_b": terms((b["S1"], b["S2"], b["S3"])),
            "from_a_printed50": terms(S_pr),
            "from_a_corrected50": terms(S_co),
        },
    }


# ----------------------------------------------------------------------------- paper eqs. 16-23
def onsite_B(dx_pzt_free, dx_tip_free):
    """Paper ``001_972cacfaa08ad91a.txt`` eq. (20): ``B = dx_pzt_free / dx_tip_free`` [-].

    From the free-tip force balance ``0 = S3 x_pzt + S2 dx_tip`` one gets ``S2 = -B S3``
    (paper eq. 18). Table I: 10 um / 6.3 mm = 1.59e-3.
    """
    return np.asarray(dx_pzt_free, dtype=float) / np.asarray(dx_tip_free, dtype=float)


def onsite_A_q(dx_tip_free, q_free_per_actuator):
    """Free-tip scale factor A_q = dx_tip / q [m/C] (paper text before eq. 23).

    ``q`` is the PER-ACTUATOR charge (paper eq. 4 / thesis eq. 24 convention). With the
    contract total charge ``q_total`` use ``q_total / n_A``; equivalently
    ``A_q = n_A * A_q_total`` where ``A_q_total = dx_tip / q_total``.
    """
    return np.asarray(dx_tip_free, dtype=float) / np.asarray(q_free_per_actuator, dtype=float)


def onsite_h_slope(alpha, B, A_q, Cp):
    """Slope factor ``(1 - alpha B A_q)/C_p`` [V/C] of paper eq. (23).

    Paper eq. (23): ``H(q) = V - (1 - alpha B A_q) q / C_p`` on the free-tip trial, derived
    from (16)-(22): free tip => ``q - C_p V_p = alpha B dx_tip`` (eq. 19) and
    ``dx_tip = A_q q`` (free tip, A_q [m/C] = tip closing displacement per unit charge).

    Units/consistency: ``alpha`` [N/V], ``B`` [-], ``A_q`` [m/C], ``C_p`` [F]; ``alpha B A_q``
    is dimensionless (0.314 with paper Table I: 2.35 * 1.59e-3 * 84). All of alpha, C_p, q
    and A_q must refer to ONE actuator (the paper's q, eq. 4). With the contract's total
    charge ``q_total = n_A q`` and ``C_p_total = n_A C_p``:
    ``H = V - (1 - alpha B A_q) q_total / C_p_total`` with the same per-actuator
    ``alpha B A_q`` (equivalently ``alpha_total B A_q_total`` with ``alpha_total = n_A alpha``,
    ``A_q_total = A_q / n_A``). Mixing per-actuator alpha with total-charge A_q is off by n_A.
    """
    return (1.0 - alpha * B * A_q) / Cp


# ----------------------------------------------------------------------------- static solves
def static_response(S1, S2, S3, alpha, Cp, k, n_A, Vp, *, k_env=0.0, gap=0.0, blocked=False) -> dict:
    """Static equilibrium of n_A actuators + mechanism + tip environment (contract signs).

    Equations: ``n_A (alpha V_p - k x) = S1 x + S3 y`` (eqs. 21, 26, 44) and
    ``f_tip = -(S3 x + S2 y)``; environment ``f_tip = k_env * max(y - gap, 0)``
    (``k_env=0``: free; ``blocked=True``: y = 0; ``k_env``/``gap`` may be arrays
    broadcast against ``Vp``, ``k_env=np.inf`` = rigid object). ``x`` [m] stack elongation per actuator,
    ``y`` = dx_tip [m] closing, ``f_tip`` [N] pinch-positive, ``q`` [C] TOTAL charge
    ``n_A (alpha x + C_p V_p)``. Vectorised over ``Vp`` [V].
    """
    Vp = np.asarray(Vp, dtype=float)
    g = n_A * alpha * Vp
    a11 = n_A * k + S1
    if blocked:
        x = g / a11
        y = np.zeros_like(x)
    else:
        k_env = np.asarray(k_env, dtype=float)
        gap = np.asarray(gap, dtype=float)
        if np.any(k_env < 0):
            raise ValueError("k_env must be >= 0 (np.inf = rigid object)")
        det_f = a11 * S2 - S3 * S3
        x_f = g * S2 / det_f
        y_f = -S3 * g / det_f
        contact = (y_f > gap) & (k_env > 0)
        rigid = np.isinf(k_env)
        ke = np.where(rigid, 0.0, k_env)          # finite spring branch (rigid handled below)
        a22 = S2 + ke
        det_c = a11 * a22 - S3 * S3
        x_c = (g * a22 - S3 * ke * gap) / det_c
        y_c = (a11 * ke * gap - S3 * g) / det_c
        x_r = (g - S3 * gap) / a11                # rigid object: dx_tip = gap
        x_c = np.where(rigid, x_r, x_c)
        y_c = np.where(rigid, gap, y_c)
        x = np.where(contact, x_c, x_f)
        y = np.where(contact, y_c, y_f)
    f_tip = -(S3 * x + S2 * y)
    q = n_A * (alpha * x + Cp * Vp)
    return dict(x_pzt=x, dx_tip=y, f_tip=f_tip, q=q, F_in=n_A * (alpha * Vp - k * x))


def free_blocked_response(S1, S2, S3, alpha, Cp, k, n_A, V) -> dict:
    """Free-tip stroke, blocked tip force and the PZT displacement in both cases at V_p = V.

    Thesis ``000_18d138f03f1777c3.txt`` sec. 5.3, eqs. (58)-(59), Fig. 38: the PZT sees
    the input stiffness ``S1 - S3^2/S2`` with the tip free and ``S1`` with the tip blocked;
    ``rel_diff_x_pzt = (x_free - x_block)/x_free`` (= ``rel_diff_q_alpha``: relative change of
    the mechanical charge alpha x) is the small signal that must cover the whole
    free-to-blocked range. Contract signs; ``q`` total charge [C].
    """
    fr = static_response(S1, S2, S3, alpha, Cp, k, n_A, V)
    bl = static_response(S1, S2, S3, alpha, Cp, k, n_A, V, blocked=True)
    x_f, x_b = fr["x_pzt"], bl["x_pzt"]
    return dict(
        dx_tip_free=fr["dx_tip"], f_tip_block=bl["f_tip"], x_pzt_free=x_f, x_pzt_block=x_b,
        rel_diff_x_pzt=(x_f - x_b) / x_f, q_free=fr["q"], q_block=bl["q"],
        rel_diff_q=(fr["q"] - bl["q"]) / fr["q"],
        k_in_free=S1 - S3 * S3 / S2, k_in_block=S1,
    )


def pzt_to_tip_sensitivity(S1, S2, S3, alpha, Cp, k, n_A, dV_p=0.0, dq=0.0) -> dict:
    """Tip errors caused by a V_p error ``dV_p`` [V] and a TOTAL-charge error ``dq`` [C].

    Uses the exact (unapproximated) contract-sign tip matrix (eq. 45 with the force row
    pinch-positive): ``[d dx_tip, d f_tip] = M [dq, dV_p]``. Returns the four
    sensitivities (``dx_per_V`` [m/V], ``f_per_V`` [N/V], ``dx_per_C`` [m/C], ``f_per_C`` [N/C])
    and the errors ``d_dx_tip`` [m], ``d_f_tip`` [N] for the given ``dV_p``, ``dq``.
    """
    M = tip_matrix(S1, S2, S3, alpha, Cp, k, n_A, convention="contract")
    dV_p = np.asarray(dV_p, dtype=float)
    dq = np.asarray(dq, dtype=float)
    return dict(
        dx_per_C=M[0, 0], dx_per_V=M[0, 1], f_per_C=M[1, 0], f_per_V=M[1, 1],
        d_dx_tip=M[0, 0] * dq + M[0, 1] * dV_p, d_f_tip=M[1, 0] * dq + M[1, 1] * dV_p,
    )
