"""Streaming (sample-by-sample or block) self-sensing estimator with all state carried, for every model.

The batch pipeline is ``selfsense.stages.ingest`` (raw log -> SI signals, ``V``, ``q``) followed by
``SelfSensingEstimator.estimate``. :class:`SelfSensingStream` reproduces it on raw DAQ samples
(``u_cmd`` [V], ``v_shunt`` [V], ``relay`` 0/1, ``t`` [s]) one sample or one block at a time, in three links that
each carry their state (O(1) memory per sample):

1. **Front** (one compiled loop, :func:`front_kernel`): SI conversion (docs/data_format.md)
   ``V_c = amplifier_gain * u_cmd``, ``V_s = v_shunt / inamp_gain``, actuator voltage ``V = V_c - V_s``
   (``000_18d138f03f1777c3.txt`` eq. (56)), with ``u_cmd`` the command the amplifier delivered where the model carries
   the amplifier member's **slew limit** (``rate_v_per_s`` in the model JSON's ``amplifier.slew``,
   ``selfsense.chain.amplifier.with_slew``: the previous delivered command plus the step clipped to the rate; every
   later use of the command, the sliding DC reset included, reads it), less ``tau * amplifier_gain * du_cmd/dt``
   (backward difference from the previous sample) where the model carries the voltage link's **lag member** (``tau_s`` in the model JSON's
   ``amplifier_lag``, ``selfsense.chain.amplifier.lag_column``); charge ``Q = (1/R) int (V_s - offset) dt`` (eq. (57)), trapezoidal
   rule, reset to 0 while ``relay == 1``, written exactly as ``selfsense.signals.charge_from_shunt`` does it (a
   running cumulative sum of the increments minus its value at the last shorted sample, so that the charge is
   bit-identical to the batch ``np.cumsum``). The in-amp offset is the mean of ``V_s`` over the FIRST shorted
   segment, known when that segment ends, before it is first needed (charge is 0 on shorted samples) -- provided
   the log starts with its relay segment (otherwise pass ``offset=<volts>``). The **leakage member** (a fitted
   conductance ``g``, ``leakage_s`` in the model JSON) subtracts ``g int V dt``, the same running trapezoid on V
   restarted at the relay (``SelfSensingEstimator._charge``, ``integral_v``). The **absorption member** (``c_f``,
   ``tau_s`` in the model JSON's ``absorption``) subtracts ``c LP_tau(V)`` before it, the recursion of
   ``chain.charge.absorption_column`` at the stream's sample period. The **quantiser member** (``i_q_a``,
   ``half_step_v`` in the model JSON's ``quantiser``) subtracts ``i_q int m dt`` before both, ``m`` = 1 on the open
   samples whose ``V_s`` is more than half an ADC step from the short's mean, the same running trapezoid restarted at
   the relay (``chain.charge.quantiser_column``).
2. **H(Q)** for every model the estimator can hold: the registry kinds ``linear``, ``pi``, ``preisach``, ``ri``,
   ``duhem``, ``modified_pi`` (their ``predict(q, dt, state)`` carries the operators' memory: play and creep states,
   the Preisach grid's stack of dominant extrema, the RI model's extrema memory, the Duhem map's state) and the
   thesis identification's ``GaugedH`` (Kuhnen's modified PI with creep, eq. 42, in the gauge
   ``sign * (G[Q] - c Q)``), ``RICreepH`` and ``RIModel`` (``002_7d89b7147aad52e4.txt`` eqs. 8-11). Batch
   evaluation is the same code fed one block, so the stream equals it on any split of the samples.
3. **Back** (one compiled loop, :func:`back_kernel`): ``V_p = V - V_H`` (eq. 27), less ``w f`` with the load
   link's stress member (``f`` from the force row in closed form with its ridge, kept in the calibrated force
   range, :func:`selfsense.chain.load.stress_load`);
   ``dx_raw = A1 Q + A2 V_p + dx0``
   (the rest offset member), ``f_raw = B21 Q + B22 V_p`` (eq. 52), 0 while shorted (the kernels of
   ``selfsense.sensing.core``, which the batch estimator evaluates on arrays). The load link's creep member
   (selfsense.chain.creep; ``taus_s``, ``beta``, ``kappa`` in the model JSON's ``tip_creep``) adds
   ``s = sum_tau beta_Q,tau (LP_tau[Q] - Q) + beta_V,tau (LP_tau[V_p] - V_p)`` to ``dx_raw`` and ``kappa s`` to
   ``f_raw`` (thesis eqs. 46, 52 + the bank), its lags the recursion of ``chain.creep.creep_columns`` at the
   stream's sample period, two states per lag carried from rest over every sample (the relay's too, as the batch
   runs them over the whole trial); sliding DC offset (thesis sec. 5.2, Fig. 24) on dx (and f if configured), reset
   whenever ``|u_cmd| <= zero_input_v / amplifier_gain``; limiting to the calibrated ranges.

H is evaluated at the sample time ``dt`` given to the stream, or the calibration's when the samples come with time
stamps only (the batch uses the trial's median sample period: the same when the log is sampled at the calibration
rate). The **offset-drift member** (``offset_drift``: the charge drift fitted over the rest segments of the whole
trial, ``SelfSensingEstimator.rest_drift``) looks at samples that have not arrived yet: a model that carries it is
refused, naming the member, unless the stream is asked for ``drift="causal"`` (:class:`CausalOffsetDrift`: the same
ramp fitted on the rest segments seen so far, between links 1 and 2). Units: SI (s, V, C, m, N).
"""
from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numba import njit

from selfsense.hysteresis import creep_kernel, gamma_kernel
from selfsense.hysteresis.models import (DuhemH, LinearH, PlayH, PreisachH, duhem_run, play_output_kernel,
                                         preisach_grid_kernel, relaxation_gains, relaxation_output_kernel)
from selfsense.io.rig import rig_value
from selfsense.sensing.core import _piezo_voltage, _shunt_current, _tip_linear, _trapezoid_increment

__all__ = ["SelfSensingStream", "StreamError", "HStream", "CausalOffsetDrift", "stream_kinds"]

# ---- front state (float64) ------------------------------------------------------------------------------------
(_T_LAST, _VS_LAST, _CSUM, _BASE, _NSEEN, _OFF_MODE, _OFF_SUM, _OFF_N, _OFF, _V_LAST, _ICSUM, _IBASE,
 _DA_Y, _M_LAST, _MCSUM, _MBASE, _U_LAST) = range(17)
_NS_FRONT = 17
_OFF_WAIT, _OFF_COLLECT, _OFF_FIXED = 0.0, 1.0, 2.0
# ---- front parameters
_F_R, _F_INAMP, _F_GAIN, _F_G, _F_CDA, _F_ADA, _F_CQ, _F_QH, _F_TS, _F_LAG, _F_SLEW = range(11)
# ---- back state / parameters
_DX_DC, _F_DC = range(2)
_NS_BACK = 2
# the creep member's lag states follow the fixed back state: [LP_tau[Q], LP_tau[V_p]] per lag, in the order of taus
_CR_Y = _NS_BACK
(_B_A1, _B_A2, _B_B21, _B_B22, _B_DX0, _B_ZL, _B_DXLO, _B_DXHI, _B_FLO, _B_FHI, _B_DCDX, _B_DCF,
 _B_LIMIT, _B_KSH, _B_KSQ, _B_AH, _B_AQ, _B_KRG, _B_KCR, _B_NCR) = range(20)
# the creep member's tables follow the fixed back parameters: a = exp(-dt / tau) per lag, then beta (2 per lag)
_NP_BACK = 20
# ---- one-sample buffers of step(): rows of an (_NB_STEP, 1) array, each row a one-sample block for the kernels
_BUF_U, _BUF_V, _BUF_R, _BUF_T, _BUF_Q, _BUF_VV, _BUF_QM, _BUF_TS, _BUF_VH, _BUF_DX, _BUF_F = range(11)
_NB_STEP = 11
# ---- Kuhnen's operator in its gauge (link 2): offset, s0, sign, c, then the edges of the kernel's parameter arrays
# r_H, w_H, rC, wC, gC, rSp, wSp, rSn, wSn (as indices into the same array), then those arrays
_H_OFFSET, _H_S0, _H_SIGN, _H_C = range(4)
_H_EDGES = 4
# ---- the registry's linear, pi, preisach (_FORM_BASIS) and duhem (_FORM_DUHEM) models (link 2): form, input
# normalisation, Preisach grid size, linear term a, offset b, the Duhem map's scalars, then the edges of the parameter
# arrays w_grid, r_play, w_play, g_creep, w_creep, c_map (as indices into the same array), then those arrays
_R_FORM, _R_QLO, _R_QSPAN, _R_NGRID, _R_A, _R_B, _R_DEG, _R_VLO, _R_VSPAN, _R_EPS, _R_VMIN, _R_VMAX = range(12)
_R_EDGES = 12
_FORM_BASIS, _FORM_DUHEM = 0.0, 1.0

# status codes returned by the kernels
_OK = 0
_ERR_NO_RELAY = 1
_ERR_RELAY_VALUE = 2
_ERR_TIME = 3


class StreamError(ValueError):
    """The samples cannot be processed as a stream (no leading relay segment for the offset, bad relay, time)."""


@njit(cache=True)
def _charge(csum, base, t_last, vs_last, nseen, off, R, Vs, shorted, tk, dt, use_t):
    """Charge update, eq. (57), scalars only and strict IEEE arithmetic (no fast-math), so that the running sum
    is bit-identical to ``np.cumsum`` of the increments ``0.5 * (i_k + i_{k-1}) * (t_k - t_{k-1})`` in
    ``selfsense.signals.charge_from_shunt``: both evaluate ``selfsense.sensing.core._shunt_current`` and
    ``_trapezoid_increment``. Returns (status, q, csum, base, t_last)."""
    inc = 0.0
    if nseen > 0.0:
        if use_t:
            h = tk - t_last
            if not (h > 0.0):
                return _ERR_TIME, 0.0, csum, base, t_last
        else:
            h = dt
        if not shorted:
            inc = _trapezoid_increment(_shunt_current(vs_last, off, R), _shunt_current(Vs, off, R), h)
    csum = csum + inc
    if shorted:
        base = csum
        q = 0.0
    else:
        q = csum - base
    t_last = tk if use_t else t_last + dt
    return _OK, q, csum, base, t_last


@njit(cache=True)
def front_kernel(P, S, t, u, v, relay, dt, use_t, q_out, V_out, qm_out, t_out, u_out):
    """Link 1 on a block: SI conversion, the amplifier's slew limit and lag, relay offset, charge (eq. 57), the
    quantiser, absorption and leakage members. Returns (status, index of the first bad sample). ``P`` = [R,
    inamp_gain, amplifier_gain, g_leak, c_da, a_da, i_q, half_step, temperature scale, tau gain, slew rate [V/s]]
    (``a_da = exp(-dt / tau)`` of the absorption branch; ``i_q`` the quantiser member's current on the samples off the
    short's ADC code, ``half_step`` half that step [V]; a slew rate of 0: none); ``S`` the front state (updated in place); ``t`` ignored
    unless ``use_t``. Writes the charge the model uses (``q_out``, after the members), the measured charge
    (``qm_out``), V, the sample's time (``t_out``: the time stamp, or the sample period accumulated from 0 without
    time stamps) and the command the amplifier delivered (``u_out``: the command, or its slew-limited value where the
    model carries the slew limit; it may be ``u`` itself)."""
    for k in range(u.shape[0]):
        rk = relay[k]
        if rk != 0.0 and rk != 1.0:
            return _ERR_RELAY_VALUE, k
        shorted = rk == 1.0
        Vs = v[k] / P[_F_INAMP]
        uk = u[k]
        sl = P[_F_SLEW]
        if sl > 0.0 and S[_NSEEN] > 0.0:
            # the amplifier member's slew limit: the delivered command follows the command at most at the slew rate
            # (chain.amplifier.with_slew; _U_LAST holds the delivered command)
            h = (t[k] - S[_T_LAST]) if use_t else dt
            lim = sl * h
            dv = P[_F_GAIN] * uk - P[_F_GAIN] * S[_U_LAST]
            if dv > lim:
                uk = (P[_F_GAIN] * S[_U_LAST] + lim) / P[_F_GAIN]
            elif dv < -lim:
                uk = (P[_F_GAIN] * S[_U_LAST] - lim) / P[_F_GAIN]
        V = P[_F_GAIN] * uk - Vs
        kl = P[_F_LAG]
        if kl != 0.0 and S[_NSEEN] > 0.0:
            # the voltage link's lag member: V - tau gain du/dt, the backward difference over the sample interval
            # (chain.amplifier.lag_column; 0 at the first sample)
            h = (t[k] - S[_T_LAST]) if use_t else dt
            if h > 0.0:
                V = V - kl * (uk - S[_U_LAST]) / h
        # in-amp offset from the first shorted segment (signals.relay_offset)
        mode = S[_OFF_MODE]
        if mode == _OFF_WAIT:
            if not shorted:
                return _ERR_NO_RELAY, k
            S[_OFF_MODE] = _OFF_COLLECT
            S[_OFF_SUM] = Vs
            S[_OFF_N] = 1.0
        elif mode == _OFF_COLLECT:
            if shorted:
                S[_OFF_SUM] += Vs
                S[_OFF_N] += 1.0
            else:
                S[_OFF] = S[_OFF_SUM] / S[_OFF_N]
                S[_OFF_MODE] = _OFF_FIXED
        tk = t[k] if use_t else 0.0
        st, q, csum, base, t_last = _charge(S[_CSUM], S[_BASE], S[_T_LAST], S[_VS_LAST], S[_NSEEN], S[_OFF],
                                            P[_F_R], Vs, shorted, tk, dt, use_t)
        if st != _OK:
            return st, k
        qm_out[k] = q
        ts = P[_F_TS]
        if ts != 1.0:
            # temperature member: the trial's campaign charge scale (chain.temperature), before the other members
            q = q / ts
        cq = P[_F_CQ]
        if cq != 0.0:
            # quantiser member: Q - i_q int m dt, m = 1 on open samples off the short's code (the offset is known
            # from the first open sample on), the same trapezoid restarted at the relay (chain.charge.quantiser_column)
            mk = 0.0
            if not shorted and abs(Vs - S[_OFF]) > P[_F_QH]:
                mk = 1.0
            st, mq, mcsum, mbase, _t = _charge(S[_MCSUM], S[_MBASE], S[_T_LAST], S[_M_LAST], S[_NSEEN], 0.0, 1.0,
                                               mk, shorted, tk, dt, use_t)
            S[_MCSUM] = mcsum
            S[_MBASE] = mbase
            S[_M_LAST] = mk
            q = q - cq * mq
        cda = P[_F_CDA]
        if cda != 0.0:
            # absorption member: Q - c LP_tau(V), the recursion of chain.charge.absorption_column (from rest)
            a = P[_F_ADA]
            y = (1.0 - a) * V + a * S[_DA_Y]
            S[_DA_Y] = y
            q = q - cda * y
        g = P[_F_G]
        if g != 0.0:
            # leakage member: Q - g int V dt, the same trapezoid on V (R = 1, no offset: integral_v)
            st, iv, icsum, ibase, _t = _charge(S[_ICSUM], S[_IBASE], S[_T_LAST], S[_V_LAST], S[_NSEEN], 0.0, 1.0,
                                               V, shorted, tk, dt, use_t)
            S[_ICSUM] = icsum
            S[_IBASE] = ibase
            q = q - g * iv
        S[_CSUM] = csum
        S[_BASE] = base
        S[_T_LAST] = t_last
        t_out[k] = t_last
        S[_VS_LAST] = Vs
        S[_V_LAST] = V
        S[_U_LAST] = uk
        u_out[k] = uk
        S[_NSEEN] += 1.0
        q_out[k] = q
        V_out[k] = V
    return _OK, u.shape[0]


@njit(cache=True)
def back_kernel(P, S, u, relay, q, V, VH, dx_out, f_out, aux):
    """Link 3 on a block: eq. (27), eq. (52) with the rest offset, the load link's creep member, sliding DC offset
    (Fig. 24), limiting (sec. 5.2). ``P`` holds the fixed parameters, then the creep member's tables (``P[_B_NCR]``
    lags: their ``a = exp(-dt / tau)``, then ``beta``, two per lag); ``S`` the fixed state, then the lags' states.
    ``aux`` (N, 4) or (0, 4) receives V_p, dx_raw, f_raw, V - V_p."""
    ncr = int(P[_B_NCR])
    for k in range(u.shape[0]):
        shorted = relay[k] == 1.0
        Vp = _piezo_voltage(V[k], VH[k])
        if P[_B_KSH] != 0.0 or P[_B_KSQ] != 0.0:
            # load link's stress member: V_p - w f, w = s_H (V_H - a_H) + s_Q (Q - a_Q), f from the force row in
            # closed form with its ridge, within the force range (chain.load.stress_load)
            w = P[_B_KSH] * (VH[k] - P[_B_AH]) + P[_B_KSQ] * (q[k] - P[_B_AQ])
            a = P[_B_B21] * q[k] + P[_B_B22] * Vp
            d = 1.0 + P[_B_B22] * w
            den = d * d + P[_B_KRG]
            fl = a * d / den if den != 0.0 else 0.0
            Vp = Vp - w * min(max(fl, P[_B_FLO]), P[_B_FHI])
        scr = 0.0
        if ncr > 0:
            # the load link's creep member (chain.creep): s = sum_tau beta (LP_tau[Q] - Q) + beta' (LP_tau[V_p] - V_p),
            # each lag the recursion of chain.charge.absorption_column from rest, run over every sample as the batch
            for j in range(ncr):
                acr = P[_NP_BACK + j]
                yq = (1.0 - acr) * q[k] + acr * S[_CR_Y + 2 * j]
                yv = (1.0 - acr) * Vp + acr * S[_CR_Y + 2 * j + 1]
                S[_CR_Y + 2 * j] = yq
                S[_CR_Y + 2 * j + 1] = yv
                scr += P[_NP_BACK + ncr + 2 * j] * (yq - q[k]) + P[_NP_BACK + ncr + 2 * j + 1] * (yv - Vp)
        if shorted:
            dxr = 0.0
            fr = 0.0
        else:
            dxr = _tip_linear(q[k], Vp, P[_B_A1], P[_B_A2], P[_B_DX0])
            fr = _tip_linear(q[k], Vp, P[_B_B21], P[_B_B22], 0.0)
            if ncr > 0:
                # the creep strain at both tip outputs: s at the displacement, kappa s at the force
                dxr = dxr + scr
                fr = fr + P[_B_KCR] * scr
        dx = dxr
        f = fr
        zero = abs(u[k]) <= P[_B_ZL]
        if P[_B_DCDX] != 0.0:
            if zero:
                S[_DX_DC] = dxr
            dx = dxr - S[_DX_DC]
        if P[_B_DCF] != 0.0:
            if zero:
                S[_F_DC] = fr
            f = fr - S[_F_DC]
        if P[_B_LIMIT] != 0.0:
            dx = min(max(dx, P[_B_DXLO]), P[_B_DXHI])
            f = min(max(f, P[_B_FLO]), P[_B_FHI])
        dx_out[k] = dx
        f_out[k] = f
        if aux.shape[0] > 0:
            aux[k, 0] = Vp
            aux[k, 1] = dxr
            aux[k, 2] = fr
            aux[k, 3] = V[k] - Vp
    return _OK


@njit(cache=True)
def _step_front(P, S, S_next, B, u, v, relay, tk, dt, use_t):
    """Link 1 on one sample: :func:`front_kernel` on the one-sample rows of ``B`` (``_B_*``) and on ``S_next``, a copy
    of the front state ``S`` (left as it was: the caller commits ``S_next`` once the sample is through). Returns the
    kernel's status."""
    B[_BUF_U, 0] = u
    B[_BUF_V, 0] = v
    B[_BUF_R, 0] = relay
    B[_BUF_T, 0] = tk
    for i in range(S.shape[0]):
        S_next[i] = S[i]
    st, _k = front_kernel(P, S_next, B[_BUF_T], B[_BUF_U], B[_BUF_V], B[_BUF_R], dt, use_t, B[_BUF_Q], B[_BUF_VV], B[_BUF_QM],
                          B[_BUF_TS], B[_BUF_U])
    return st


@njit(cache=True)
def _step_back(P, S, B, VH, aux):
    """Link 3 on one sample: :func:`back_kernel` on the rows of ``B`` filled by :func:`_step_front`, H in ``VH``.
    Returns (dx_hat, f_hat)."""
    back_kernel(P, S, B[_BUF_U], B[_BUF_R], B[_BUF_Q], B[_BUF_VV], VH, B[_BUF_DX], B[_BUF_F], aux)
    return B[_BUF_DX, 0], B[_BUF_F, 0]


@njit(cache=True)
def _packed_array(P, edges, i):
    """The i-th array packed in ``P`` by :func:`_pack` (a contiguous view), ``edges`` the index of its edges
    (``_H_EDGES``, ``_R_EDGES``)."""
    return P[int(P[edges + i]):int(P[edges + i + 1])]


@njit(cache=True)
def _gauged_pi(Q, PH, p, c, xl, out):
    """Link 2 for Kuhnen's operator ``G`` (eq. 42) in the gauge ``H = sign * (G[Q] - c Q)`` (the registry
    ``modified_pi``, the thesis ``GaugedH``) on a block: ``gamma_kernel``, the kernel of ``ModifiedPI.apply``,
    on the state arrays ``p``, ``c``, ``xl`` (updated in place), then the gauge. ``PH`` holds the operator's
    parameters (``_H_*``)."""
    gamma_kernel(Q, _packed_array(PH, _H_EDGES, 0), _packed_array(PH, _H_EDGES, 1), p, _packed_array(PH, _H_EDGES, 2),
                 _packed_array(PH, _H_EDGES, 3), _packed_array(PH, _H_EDGES, 4), c, xl, PH[_H_OFFSET], PH[_H_S0],
                 _packed_array(PH, _H_EDGES, 5), _packed_array(PH, _H_EDGES, 6), _packed_array(PH, _H_EDGES, 7),
                 _packed_array(PH, _H_EDGES, 8), out)
    sign = PH[_H_SIGN]
    cg = PH[_H_C]
    for k in range(Q.shape[0]):
        out[k] = sign * (out[k] - cg * Q[k])


@njit(cache=True)
def _registry_h(Q, PR, Ms, ms, gs, Fc, zs, zc, out):
    """Link 2 for the registry's ``linear``, ``pi``, ``preisach`` (``LinearParamH.predict``: ``H = basis(u) w + a u
    + sum_j w_j (u - z_j) + b``, the Preisach basis with its reversible ramps ``max(u - i / n_rev, 0)`` after the grid
    and the plays, the relaxation bank of Kuhnen's creep operator, eqs. 38-41) and ``duhem``
    (``DuhemH.predict``: ``H = v[u] + sum_j w_j (u - z_j) + b + a u``), ``u = (Q - q_lo) / q_span``, on a block:
    the kernels of ``predict`` (``preisach_grid_kernel``, ``play_output_kernel``, ``relaxation_output_kernel``,
    ``duhem_run``) on the state arrays (updated in place: the Preisach grid's ``Ms``, ``ms``, ``gs``, ``Fc``; the
    plays' or the Duhem map's ``zs``; the creep filters' ``zc``), then the sums of ``predict`` in its order, sample by
    sample. ``PR`` holds the model's parameters (``_R_*``)."""
    n = Q.shape[0]
    q_lo = PR[_R_QLO]
    q_span = PR[_R_QSPAN]
    u = np.empty(n)
    for k in range(n):
        u[k] = (Q[k] - q_lo) / q_span
    a = PR[_R_A]
    if PR[_R_FORM] == _FORM_DUHEM:
        v, _J = duhem_run(u, _packed_array(PR, _R_EDGES, 5), int(PR[_R_DEG]), PR[_R_VLO], PR[_R_VSPAN], PR[_R_EPS],
                          PR[_R_VMIN], PR[_R_VMAX], 1, False, zs)
        for k in range(n):
            out[k] = v[k]
    else:
        ng = int(PR[_R_NGRID])
        r = _packed_array(PR, _R_EDGES, 1)
        if ng > 0:   # preisach_grid_output, plus play_output with plays
            if gs[2] == 0.0:
                gs[1] = 0.0
            F = np.zeros((n, 1))
            preisach_grid_kernel(u, 0.0, 1.0, ng, _packed_array(PR, _R_EDGES, 0), True, 1, Ms, ms, gs, Fc, F)
            for k in range(n):
                out[k] = F[k, 0]
            if r.shape[0]:
                yp = play_output_kernel(u, r, _packed_array(PR, _R_EDGES, 2), zs)
                for k in range(n):
                    out[k] = out[k] + yp[k]
        elif r.shape[0]:
            yp = play_output_kernel(u, r, _packed_array(PR, _R_EDGES, 2), zs)
            for k in range(n):
                out[k] = yp[k]
        else:
            for k in range(n):
                out[k] = 0.0
        wr = _packed_array(PR, _R_EDGES, 5)   # the Preisach model's reversible part (reversible_output)
        if wr.shape[0]:
            nk = float(wr.shape[0] + 1)
            for k in range(n):
                acc = 0.0
                for i in range(wr.shape[0]):
                    acc += wr[i] * max(u[k] - float(i + 1) / nk, 0.0)
                out[k] = out[k] + acc
        for k in range(n):
            out[k] = out[k] + a * u[k]
    g = _packed_array(PR, _R_EDGES, 3)
    if g.shape[0]:
        yc = relaxation_output_kernel(u, g, _packed_array(PR, _R_EDGES, 4), zc)
        for k in range(n):
            out[k] = out[k] + yc[k]
    b = PR[_R_B]
    if PR[_R_FORM] == _FORM_DUHEM:
        for k in range(n):
            out[k] = out[k] + b + a * u[k]
    else:
        for k in range(n):
            out[k] = out[k] + b


@njit(cache=True)
def _step_registry(PF, SF, SF_next, PB, SB, B, aux, u, v, relay, tk, dt, use_t, PR, Ms, ms, gs, Fc, zs, zc):
    """One sample through the three links for the registry models of :func:`_registry_h`, in one compiled call, as
    :func:`_step_gauged_pi`. Returns (status, dx_hat, f_hat)."""
    st = _step_front(PF, SF, SF_next, B, u, v, relay, tk, dt, use_t)
    if st != _OK:
        return st, 0.0, 0.0
    _registry_h(B[_BUF_Q], PR, Ms, ms, gs, Fc, zs, zc, B[_BUF_VH])
    dx, f = _step_back(PB, SB, B, B[_BUF_VH], aux)
    for i in range(SF.shape[0]):
        SF[i] = SF_next[i]
    return _OK, dx, f


@njit(cache=True)
def _step_gauged_pi(PF, SF, SF_next, PB, SB, B, aux, u, v, relay, tk, dt, use_t, PH, p, c, xl):
    """One sample through the three links for Kuhnen's operator in its gauge, in one compiled call:
    :func:`_step_front`, :func:`_gauged_pi`, :func:`_step_back` -- the kernels of the block path, so that a sample
    gives the bits of the same sample in a block. Returns (status, dx_hat, f_hat); the front state ``SF`` takes the
    sample only if its status is OK."""
    st = _step_front(PF, SF, SF_next, B, u, v, relay, tk, dt, use_t)
    if st != _OK:
        return st, 0.0, 0.0
    _gauged_pi(B[_BUF_Q], PH, p, c, xl, B[_BUF_VH])
    dx, f = _step_back(PB, SB, B, B[_BUF_VH], aux)
    for i in range(SF.shape[0]):
        SF[i] = SF_next[i]
    return _OK, dx, f


def _creep_advance(Q, r_K, a_K, dt, state):
    """Kuhnen's creep operators (eq. 39, ``operators.creep_operator``) continued from ``state`` = {"c": (n, m)
    states at the last sample, "x": last input or None}; returns (N, n, m) like ``creep_operator``."""
    g = -np.expm1(-np.asarray(a_K, float) * dt)
    c = state["c"]
    if state["x"] is None:
        out = np.empty((len(Q), len(r_K), len(a_K)))
        creep_kernel(np.ascontiguousarray(Q, dtype=float), np.asarray(r_K, float), g, c, out)
    else:   # sample 0 of the block is the update from the previous block's last input
        xx = np.ascontiguousarray(np.concatenate([[state["x"]], Q]), dtype=float)
        out = np.empty((len(xx), len(r_K), len(a_K)))
        creep_kernel(xx, np.asarray(r_K, float), g, c, out)
        out = out[1:]
    if len(Q):
        state["x"] = float(Q[-1])
    return out


def _pack(scalars, arrays) -> np.ndarray:
    """``scalars``, the edges of ``arrays`` in the result (indices), then ``arrays``: the parameters of a compiled
    link-2 function in one array (``_H_*``, ``_R_*``)."""
    edges = len(scalars) + len(arrays) + 1 + np.cumsum([0, *(len(a) for a in arrays)])
    return np.concatenate([np.asarray(scalars, dtype=float), edges, *(np.asarray(a, dtype=float) for a in arrays)])


def _registry_params(model, dt: float) -> np.ndarray | None:
    """The parameters of :func:`_registry_h` (``_R_*``) for a fitted registry ``linear``, ``pi``, ``preisach`` or
    ``duhem`` model at the sample time ``dt``: the values ``predict`` uses, taken once; None for other models."""
    cls = type(model)
    if cls not in (LinearH, PlayH, PreisachH, DuhemH) or model.coef_ is None:
        return None
    none = np.zeros(0)
    q_lo, q_span = float(model.q_lo_), float(model.q_span_)
    if cls is DuhemH:
        nc = len(model.creep_tau_s)
        lin = model.lin_coef_
        if lin.size <= nc:
            return None
        a = lin[nc + 1] if lin.size > nc + 1 else 0.0
        vmin, vmax = model._v_bounds()
        return _pack([_FORM_DUHEM, q_lo, q_span, 0.0, a, lin[nc], model.degree, model.v_lo_, model.v_span_, model.eps,
                      vmin, vmax],
                     [none, none, none, relaxation_gains(dt, model.creep_tau_s) if nc else none, lin[:nc],
                      np.ascontiguousarray(model.coef_, dtype=float)])
    c = model.coef_
    taus = list(model.creep_tau_s) if model.creep and model.creep_tau_s else []
    nb = len(c) - 2 - len(taus)
    ng = model.n_grid if cls is PreisachH else 0
    nw = ng * (ng + 1) // 2
    r = model._play_thresholds() if cls is not LinearH else none
    nr = max(model.n_rev - 1, 0) if cls is PreisachH else 0   # the reversible part's ramps (knots i / n_rev)
    if nb != nw + len(r) + nr:
        return None
    return _pack([_FORM_BASIS, q_lo, q_span, ng, c[nb], c[-1], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                 [c[:nw], r, c[nw:nw + len(r)], relaxation_gains(dt, taus) if taus else none,
                  c[nb + 1:nb + 1 + len(taus)], c[nw + len(r):nb]])


def _float_vector(x, n: int | None = None) -> bool:
    """Whether ``x`` is a C-contiguous float64 vector (of ``n`` elements)."""
    return (isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == 1 and x.flags.c_contiguous
            and (n is None or x.shape[0] == n))


def stream_kinds() -> tuple[str, ...]:
    """The H models the stream evaluates: every registry kind and the thesis identification's types."""
    from selfsense.hysteresis.models import REGISTRY

    return tuple(sorted(REGISTRY)) + ("GaugedH", "RICreepH", "RIModel")


class HStream:
    """H(Q) [V] of any model the estimator holds, block after block with its memory carried (link 2).

    ``HStream(model, dt)``: ``dt`` [s] the sample time at which creep eigenvalues (1/s) are discretised, as the
    batch ``selfsense.sensing.estimator._eval_h(model, Q, dt)``; ``process(Q)`` -> H on the block; ``reset()``,
    ``get_state()`` / ``set_state()`` (deep copies)."""

    def __init__(self, model, dt: float | None):
        self.model = model
        name = type(model).__name__
        if hasattr(model, "predict") and hasattr(model, "kind"):
            self.kind = model.kind
            self.dt = float(model.dt_ if dt is None else dt)
        elif name == "GaugedH":
            self.kind = "GaugedH"
            inner = model.inner
            if type(inner).__name__ == "ModifiedPI":
                self.dt = float(inner.dt if dt is None else dt)
                self._inner = inner.with_dt(self.dt) if self.dt != inner.dt else inner
            elif type(inner).__name__ == "RIModel":
                self.dt = float("nan") if dt is None else float(dt)
                self._inner = inner
            else:
                raise NotImplementedError(f"HStream: GaugedH around {type(inner).__name__} cannot stream")
        elif name in ("RICreepH", "RIModel"):
            self.kind = name
            self.dt = float(getattr(model, "dt", float("nan")))   # evaluated at its own sample time, as in batch
        else:
            raise NotImplementedError(f"HStream: H model {name!r} cannot stream; expected one of {stream_kinds()}")
        if self.kind in ("GaugedH", "RICreepH", "RIModel") or self.kind == "modified_pi":
            pass
        elif not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"HStream: sample time dt must be > 0 s, got {self.dt!r}")
        # Kuhnen's operator (registry modified_pi, thesis GaugedH): the hysteresis kernel called on state arrays held
        # here (ModifiedPI.apply's own state objects cost more than the operator on a one-sample block), with its
        # parameters and the gauge in one array (_H_*: one argument of a compiled call instead of thirteen)
        self._op = None
        if self.kind == "modified_pi" or (self.kind == "GaugedH" and type(self._inner).__name__ == "ModifiedPI"):
            op = model.inner_ if self.kind == "modified_pi" else self._inner
            if self.kind == "modified_pi" and np.isfinite(self.dt) and self.dt != op.dt:
                op = op.with_dt(self.dt)
            self._op = op
            sign, c = ((model.sign_, model.c_) if self.kind == "modified_pi" else (model.sign, model.c))
            s0, rSp, wSp, rSn, wSn = op._sup
            self._PH = _pack([float(op.offset), float(s0), float(sign), float(c)],
                             [op.r_H, op.w_H, op._rC, op._wC, op._gC, rSp, wSp, rSn, wSn])
        # the registry's linear, pi, preisach and duhem models: predict's kernels in one compiled function on the
        # state arrays of the state dict, with the parameters taken once (_R_*)
        self._PR = _registry_params(model, self.dt) if self._op is None else None
        self.reset()

    def reset(self) -> None:
        """Back to the relaxed state (the relay's known initial state, thesis sec. 5.1.1)."""
        m = self.model
        if self._op is not None:
            op = self._op
            self._state = {"p": op.z_H0.copy(), "c": np.ascontiguousarray(op.Z_K0.reshape(-1)).copy(),
                           "xl": np.array([np.nan])}
            self._bind_op_state()
        elif self.kind in ("GaugedH", "RIModel"):
            self._state = {"op": None}
        elif self.kind == "RICreepH":
            self._state = {"ri": None, "creep": {"c": np.zeros((len(m.r_K), len(m.a_K))), "x": None}}
        else:
            self._state = m.initial_state()
        self._bind_registry_state()

    def get_state(self):
        return copy.deepcopy(self._state)

    def set_state(self, state) -> None:
        self._state = copy.deepcopy(state)
        if self._op is not None:
            self._bind_op_state()
        self._bind_registry_state()

    def _bind_op_state(self) -> None:
        """Kuhnen's operator: ``_op_args`` = (parameters, the state arrays p, c, xl), the arguments of
        :func:`_gauged_pi` after the input, bound again whenever the state dict is replaced (reset, set_state)."""
        st = self._state
        self._op_args = (self._PH, st["p"], st["c"], st["xl"])

    def _bind_registry_state(self) -> None:
        """The registry's linear, pi, preisach and duhem models: ``_reg_args`` = (parameters, the state arrays of
        :func:`_registry_h`), bound again whenever the state dict is replaced (reset, set_state); None (``predict``
        on the state dict) for the other models and for a state not of the form ``initial_state`` gives."""
        self._reg_args = None
        PR, st, m = self._PR, self._state, self.model
        if PR is None or not isinstance(st, dict):
            return
        none = np.zeros(0)
        nz = len(m.creep_tau_s) if type(m) is DuhemH else int(PR[_R_EDGES + 4] - PR[_R_EDGES + 3])
        zc = st.get("creep")
        if not _float_vector(zc, nz):
            return
        if type(m) is DuhemH:
            if _float_vector(st.get("map"), 5):
                self._reg_args = (PR, none, none, none, none, st["map"], zc)
            return
        b = st.get("basis")
        if type(m) is LinearH:
            if b is None:
                self._reg_args = (PR, none, none, none, none, none, zc)
        elif type(m) is PlayH:
            if _float_vector(b, m.n_play):
                self._reg_args = (PR, none, none, none, none, b, zc)
        elif isinstance(b, dict) and isinstance(b.get("grid"), tuple) and len(b["grid"]) == 4:
            Ms, ms, gs, Fc = b["grid"]
            if (_float_vector(Ms) and _float_vector(ms, Ms.shape[0]) and _float_vector(gs, 5)
                    and _float_vector(Fc, m.n_grid * (m.n_grid + 1) // 2) and _float_vector(b.get("play"), m.n_play)):
                self._reg_args = (PR, Ms, ms, gs, Fc, b["play"], zc)

    def process(self, Q) -> np.ndarray:
        Q = np.ascontiguousarray(Q, dtype=float)
        m, st = self.model, self._state
        if self._op is not None:   # = ModifiedPI.apply on the held state (same kernel, same bits), then the gauge
            y = np.empty(Q.shape[0])
            _gauged_pi(Q, *self._op_args, y)
            return y
        if self._reg_args is not None:   # = predict on the held state (the same kernels, the same bits)
            y = np.empty(Q.shape[0])
            _registry_h(Q, *self._reg_args, y)
            return y
        if self.kind == "GaugedH":
            if type(self._inner).__name__ == "RIModel":
                g, st["op"] = self._inner.apply(np.maximum(Q, 0.0), st["op"])
            else:
                g, st["op"] = self._inner.apply(Q, st["op"])
            return m.sign * (np.asarray(g, dtype=float) - m.c * Q)
        if self.kind == "RIModel":
            y, st["op"] = m.apply(np.maximum(Q, 0.0), st["op"])
            return np.asarray(y, dtype=float)
        if self.kind == "RICreepH":
            y, st["ri"] = m.ri.apply(np.maximum(Q, 0.0), st["ri"])
            if m.w_K.size:
                K = _creep_advance(Q, m.r_K, m.a_K, m.dt, st["creep"])
                y = y + np.einsum("knm,nm->k", K, m.w_K)
            return y + m.c * Q
        return np.asarray(m.predict(Q, self.dt, st), dtype=float)


@njit(cache=True)
def _drift_accumulate(stats, tt, m, dts):
    """Add the rest samples' pseudo-measurements ``m`` at times ``tt`` (sample intervals ``dts``) to the normal
    equations of ``m = a t + b t^2`` in sample order (any split into blocks gives the same sums): stats = [sum t^2,
    t^3, t^4, t m, t^2 m, min t, max t, count, rest time]."""
    for k in range(tt.shape[0]):
        stats[8] += dts[k]
        t = tt[k]
        t2 = t * t
        stats[0] += t2
        stats[1] += t2 * t
        stats[2] += t2 * t2
        stats[3] += t * m[k]
        stats[4] += t2 * m[k]
        stats[5] = min(stats[5], t)
        stats[6] = max(stats[6], t)
        stats[7] += 1.0


class CausalOffsetDrift:
    """The offset-drift member for a stream: the charge drift ``dQ(t) = a t + b t^2`` (t since the relay opened) of
    ``SelfSensingEstimator.rest_drift`` (thesis 000_18d138f03f1777c3.txt eqs. 52, 55: at rest the free-tip relation
    ``V - H(Q) = slope Q`` holds, so its residual there is charge drift), fitted on the rest samples seen so far
    instead of the whole trial.

    Rest samples are those with the relay open and ``|V| < max(0.5 V, 1 % of the largest |V| so far)``. At each one
    the residual ``r = V - H_d(Q_c) - slope Q_c`` of the corrected charge ``Q_c = Q - dQ(t)`` and its sensitivity
    ``s = dr/dc`` (a second H stream on ``Q_c - 1e-8 C``, the batch's finite difference) give a measurement of the
    drift, ``m = dQ(t) - r / s``; (a, b) are refitted by least squares on all measurements so far whenever a rest
    run ends, provided the rest samples add up to >= 0.3 s and span >= 40 % of the time since the relay opened (the
    batch's rules applied to the record so far), and used from the next sample on. O(1) state; the ramp form only
    (the batch may choose an offset that wanders, which needs the whole trial)."""

    DELTA = 1e-8

    def __init__(self, estimator, dt: float | None):
        hd = estimator.drift_hysteresis_ if estimator.drift_hysteresis_ is not None else estimator.hysteresis_
        self.slope = float(estimator.h_slope_)
        self._hd = HStream(hd, dt) if estimator.drift_hysteresis_ is not None else None
        self._hd_delta = HStream(hd, dt)
        self.reset()

    def reset(self) -> None:
        # [t_open (NaN: relay not yet open), vmax, previous sample at rest (0/1), a, b, n updates]
        self._s = np.array([np.nan, 0.0, 0.0, 0.0, 0.0, 0.0])
        self._stats = np.array([0.0, 0.0, 0.0, 0.0, 0.0, np.inf, -np.inf, 0.0, 0.0])
        self._t_last = np.nan
        if self._hd is not None:
            self._hd.reset()
        self._hd_delta.reset()

    def get_state(self):
        return {"s": self._s.copy(), "stats": self._stats.copy(), "t_last": self._t_last,
                "hd": None if self._hd is None else self._hd.get_state(), "hd_delta": self._hd_delta.get_state()}

    def set_state(self, st) -> None:
        self._s, self._stats, self._t_last = np.array(st["s"], float), np.array(st["stats"], float), float(st["t_last"])
        if self._hd is not None:
            self._hd.set_state(st["hd"])
        self._hd_delta.set_state(st["hd_delta"])

    @property
    def coefficients(self) -> tuple[float, float]:
        """(a [C/s], b [C/s^2]) in use."""
        return float(self._s[3]), float(self._s[4])

    def process(self, t, Q, V, relay, h):
        """Corrected charge and H on it for a block (H from the stream ``h``); updates the fit at rest-run ends."""
        n = len(Q)
        s = self._s
        shorted = relay == 1.0
        opened = ~shorted
        if np.isnan(s[0]) and opened.any():
            s[0] = t[int(np.argmax(opened))]
        tt = np.where(shorted | np.isnan(s[0]), 0.0, t - (0.0 if np.isnan(s[0]) else s[0]))
        absV = np.where(opened, np.abs(V), 0.0)
        vmax = np.maximum.accumulate(np.concatenate([[s[1]], absV]))[1:]
        rest = opened & (np.abs(V) < np.maximum(0.5, 0.01 * vmax))
        prev_rest = np.concatenate([[s[2] != 0.0], rest[:-1]])
        ends = np.flatnonzero(prev_rest & ~rest)   # refit before these samples
        cuts = [0, *[int(e) for e in ends if e > 0], n]
        if len(ends) and ends[0] == 0:
            self._refit(tt[0] if n else 0.0)
        Qc = np.empty(n)
        VH = np.empty(n)
        dts = np.diff(np.concatenate([[self._t_last], t])) if n else np.zeros(0)
        dts[np.isnan(dts)] = 0.0
        for a0, a1 in zip(cuts[:-1], cuts[1:]):
            if a1 <= a0:
                continue
            seg = slice(a0, a1)
            if a0 > 0:
                self._refit(tt[a0])
            dq = np.where(shorted[seg], 0.0, s[3] * tt[seg] + s[4] * tt[seg] * tt[seg])
            qc = Q[seg] - dq
            vh = h.process(qc)
            hd = vh if self._hd is None else self._hd.process(qc)
            hd_d = self._hd_delta.process(qc - self.DELTA)
            rs = rest[seg]
            if rs.any():
                r0 = (V[seg] - hd - self.slope * qc)[rs]
                r1 = (V[seg] - hd_d - self.slope * (qc - self.DELTA))[rs]
                sens = (r1 - r0) / self.DELTA
                ok = np.abs(sens) > 0
                m = np.where(ok, dq[rs] - r0 / np.where(ok, sens, 1.0), dq[rs])
                _drift_accumulate(self._stats, np.ascontiguousarray(tt[seg][rs]), np.ascontiguousarray(m),
                                  np.ascontiguousarray(dts[seg][rs]))
            Qc[seg] = qc
            VH[seg] = vh
        if n:
            self._t_last = float(t[-1])
        s[1] = vmax[-1] if n else s[1]
        s[2] = 1.0 if (n and rest[-1]) else (0.0 if n else s[2])
        return Qc, VH

    def _refit(self, t_now: float) -> None:
        st = self._stats
        if st[7] < 3 or st[8] < 0.3 or (st[6] - st[5]) < 0.4 * max(t_now, 1e-9):
            return
        A = np.array([[st[0], st[1]], [st[1], st[2]]])
        if not np.linalg.cond(A) < 1e12:
            return
        a, b = np.linalg.solve(A, np.array([st[3], st[4]]))
        self._s[3], self._s[4] = float(a), float(b)
        self._s[5] += 1.0


class SelfSensingStream:
    """Streaming twin of ``stages.ingest`` + ``SelfSensingEstimator.estimate`` on raw DAQ samples, for every model
    the estimator can hold (see the module docstring).

    Parameters
    ----------
    estimator : a fitted ``SelfSensingEstimator`` (any H model; leakage, rest offset, the load link's creep member,
        sliding offset, limiting; not the offset-drift member, which is fitted over whole trials).
    rig : ``selfsense.io.Rig`` or rig.yaml mapping (default ``estimator.rig``): needs ``shunt_resistance_ohm``,
        ``inamp_gain``, ``amplifier_gain``.
    dt : sample period [s], used when samples come without time stamps (``t=None``), for H's creep terms and for
        the lags of the absorption and the load link's creep members (default: the calibration's sample time).
    offset : ``"relay"`` (default): in-amp offset = mean ``V_s`` of the first shorted segment, which must open
        the stream (as ``charge_from_shunt(offset="relay")``); or a number [V] (``V_s`` units, i.e. after the
        in-amp gain) to subtract from the first sample on.
    drift : for a model with the offset-drift member: ``"refuse"`` (default; the batch estimate fits the drift over
        the whole trial, which a stream cannot reproduce) or ``"causal"`` (:class:`CausalOffsetDrift`: the same
        ramp fitted on the rest segments seen so far).
    trial : the trial's name in the trials.csv the estimator was fitted with: where the temperature member
        (:mod:`selfsense.chain.temperature`) is applied, the charge is divided by that trial's campaign scale, as in
        ``estimate(df, trial=...)``; None (the default) or a trial not in the fitted campaign: the calibration's
        scale, 1.

    ``step(u_cmd, v_shunt, relay=0, t=None) -> (dx_hat [m], f_hat [N])``;
    ``process(u_cmd, v_shunt, relay=None, t=None) -> (dx_hat, f_hat)`` arrays (``full=True``: a dict that also
    holds q, V, V_H, V_p, dx_raw, f_raw). Feeding any split of a log gives the same result as one call, and a
    sample fed by ``step`` goes through the same code as a block.
    """

    def __init__(self, estimator, rig: Any = None, *, dt: float | None = None, offset: str | float = "relay",
                 drift: str = "refuse", trial: str | None = None):
        if estimator.hysteresis_ is None or not estimator.coef_:
            raise ValueError("SelfSensingStream needs a fitted estimator (fit() or from_dict())")
        if (getattr(estimator, "amplifier_", None) or {}).get("applied"):
            raise NotImplementedError(
                "SelfSensingStream: the model carries the amplifier member (the actuator voltage rebuilt where the HV "
                "amplifier sits at its current limit, interpolated up to the sample where the limit lets go), which "
                "needs samples a stream has not seen yet; refit with calibration: amplifier: off to stream it")
        if getattr(estimator, "offset_drift_", False) and drift != "causal":
            raise NotImplementedError(
                "SelfSensingStream: the model carries the offset-drift member (offset_drift: true), a charge drift "
                "fitted over the rest segments of the whole trial, which a stream has not seen yet; stream it with "
                "drift='causal' (fitted on the rest segments seen so far: docs/realtime.md) or refit with "
                "calibration: drift: off")
        if drift not in ("refuse", "causal"):
            raise ValueError(f"drift must be 'refuse' or 'causal', got {drift!r}")
        rig = estimator.rig if rig is None else rig
        if rig is None:
            raise ValueError("SelfSensingStream needs the rig (shunt resistance, gains)")
        cfg = estimator.config
        c = estimator.coef_
        self.estimator = estimator
        self.rig = rig
        self.dt = None if dt is None else float(dt)
        if self.dt is not None and not self.dt > 0:
            raise ValueError(f"dt must be > 0 s, got {dt!r}")
        if isinstance(offset, str) and offset != "relay":
            raise ValueError(f"offset must be 'relay' or a number [V], got {offset!r}")
        self.offset_arg = offset
        R, inamp, gain = (rig_value(rig, "shunt_resistance_ohm"), rig_value(rig, "inamp_gain"),
                          rig_value(rig, "amplifier_gain"))
        if R <= 0 or inamp <= 0:
            raise ValueError("rig: shunt_resistance_ohm and inamp_gain must be > 0")
        g = float(getattr(estimator, "leakage_s_", 0.0) or 0.0)
        self.h = HStream(estimator.hysteresis_, self.dt)
        c_da, a_da = 0.0, 0.0
        ab = getattr(estimator, "absorption_", None) or {}
        if ab.get("applied"):
            # the branch's recursion at the stream's sample period (the batch: the trial's median period)
            dt_ab = self.dt if self.dt is not None else float(self.h.dt)
            if not (np.isfinite(dt_ab) and dt_ab > 0):
                raise ValueError("SelfSensingStream: the absorption member needs the sample period; pass dt")
            c_da, a_da = float(ab["c_f"]), float(np.exp(-dt_ab / float(ab["tau_s"])))
        # the load link's creep member (selfsense.chain.creep): its lags at the stream's sample period, as the
        # absorption member's (the batch: the trial's median period)
        a_cr, beta_cr, kappa_cr = [], [], 0.0
        cr = getattr(estimator, "tip_creep_", None) or {}
        if cr.get("applied"):
            dt_cr = self.dt if self.dt is not None else float(self.h.dt)
            if not (np.isfinite(dt_cr) and dt_cr > 0):
                raise ValueError("SelfSensingStream: the load link's creep member (tip_creep) needs the sample "
                                 "period; pass dt")
            taus = [float(x) for x in cr["taus_s"]]
            beta_cr = [float(b) for b in cr["beta"]]
            if len(beta_cr) != 2 * len(taus):
                raise ValueError(f"tip_creep: beta must hold 2 coefficients per lag ({2 * len(taus)}), "
                                 f"got {len(beta_cr)}")
            a_cr = [float(np.exp(-dt_cr / tau)) for tau in taus]
            kappa_cr = float(cr["kappa"])
        qz = getattr(estimator, "quantiser_", None) or {}
        i_q, half_q = ((float(qz["i_q_a"]), float(qz["half_step_v"])) if qz.get("applied") else (0.0, 0.0))
        # the temperature member (chain.temperature): the named trial's campaign charge scale (1 where not applied
        # or the trial is not in the fitted campaign), as SelfSensingEstimator.estimate(df, trial=...)
        self.temperature_scale = float(estimator.temperature_scale(trial)) if hasattr(estimator, "temperature_scale") \
            else 1.0
        if trial is None and (getattr(estimator, "temperature_", None) or {}).get("applied"):
            import warnings

            warnings.warn("SelfSensingStream: the model carries the temperature member and no trial was named: the "
                          "charge is taken at the calibration's scale (pass trial= a trial of the fitted trials.csv)",
                          stacklevel=2)
        # the voltage link's lag member (chain.amplifier.lag_column): tau * gain [V s per command volt]
        lag = getattr(estimator, "amplifier_lag_", None) or {}
        k_lag = float(lag["tau_s"]) * gain if lag.get("applied") else 0.0
        # the amplifier member's slew limit (chain.amplifier.with_slew) [V/s], 0 where not carried
        slew = estimator.slew_rate()
        self._PF = np.array([R, inamp, gain, g, c_da, a_da, i_q, half_q, self.temperature_scale, k_lag, slew])
        self._PB = np.array([
            c["A1"], c["A2"], c["B21"], c["B22"], float(c.get("dx0", 0.0)),
            # exactly the expression of SelfSensingEstimator.estimate
            cfg.zero_input_v / max(rig_value(rig, "amplifier_gain"), 1e-12),
            estimator.ranges_["dx"][0], estimator.ranges_["dx"][1], estimator.ranges_["f"][0], estimator.ranges_["f"][1],
            float(bool(cfg.dc_offset)), float(bool(cfg.dc_offset_force)), float(bool(cfg.limit)),
            *estimator.stress_weights(), *estimator.stress_offsets(), estimator.stress_ridge(),
            kappa_cr, float(len(a_cr)), *a_cr, *beta_cr], dtype=float)
        self._SB0 = np.zeros(_NS_BACK + 2 * len(a_cr))
        self.drift = (CausalOffsetDrift(estimator, self.dt) if getattr(estimator, "offset_drift_", False) else None)
        # step(): one-sample buffers and a second front state, allocated once
        self._B = np.zeros((_NB_STEP, 1))
        self._aux0 = np.empty((0, 4))
        self._SF_next = np.zeros(_NS_FRONT)
        self._SF0 = np.zeros(_NS_FRONT)
        if not isinstance(offset, str):
            self._SF0[_OFF_MODE] = _OFF_FIXED
            self._SF0[_OFF] = float(offset)
        self.reset()

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_dict(cls, d: Mapping[str, Any], rig: Any, **kw) -> "SelfSensingStream":
        """From ``SelfSensingEstimator.to_dict()`` (the pipeline's model/sensing.json) and the rig."""
        from selfsense.sensing.estimator import SelfSensingEstimator

        return cls(SelfSensingEstimator.from_dict(d, rig), rig, **kw)

    @classmethod
    def from_json(cls, path: str | Path, rig_or_dataset: Any, **kw) -> "SelfSensingStream":
        """From a model JSON file and a rig (``Rig``, mapping, or a dataset directory holding rig.yaml). A file
        that is not a fitted model (wrong kind, missing keys, wrong shapes) raises ``ValueError`` naming it."""
        rig = rig_or_dataset
        if isinstance(rig, (str, Path)):
            from selfsense import io as sio

            rig = sio.load_rig(rig)
        try:
            d = json.loads(Path(path).read_text())
            return cls.from_dict(d, rig, **kw)
        except NotImplementedError as e:
            raise NotImplementedError(f"{path}: {e}") from None
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as e:
            what = f"missing key {e}" if isinstance(e, KeyError) else str(e)
            raise ValueError(f"{path}: not a model the stream can run ({what})") from None

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the initial state (no samples seen, operators at their relaxed states)."""
        self._SF = self._SF0.copy()
        self._SB = self._SB0.copy()
        self.h.reset()
        if self.drift is not None:
            self.drift.reset()

    def get_state(self) -> dict:
        """Copy of the whole state (restore with :meth:`set_state`)."""
        return {"front": self._SF.copy(), "back": self._SB.copy(), "h": self.h.get_state(),
                "drift": None if self.drift is None else self.drift.get_state()}

    def set_state(self, state: Mapping[str, Any]) -> None:
        if not isinstance(state, Mapping) or set(state) != {"front", "back", "h", "drift"}:
            raise ValueError("state must be a dict from get_state() with keys front, back, h, drift")
        f = np.asarray(state["front"], dtype=np.float64)
        b = np.asarray(state["back"], dtype=np.float64)
        if f.shape != self._SF0.shape or b.shape != self._SB0.shape:
            raise ValueError(f"state: front must have shape {self._SF0.shape} and back {self._SB0.shape}, got "
                             f"{f.shape}, {b.shape}")
        self._SF, self._SB = f.copy(), b.copy()
        self.h.set_state(state["h"])
        if self.drift is not None:
            self.drift.set_state(state["drift"])

    @property
    def n_samples(self) -> int:
        """Samples processed since the last reset."""
        return int(self._SF[_NSEEN])

    @property
    def offset_v(self) -> float:
        """The in-amp offset subtracted from V_s [V] (NaN while still being estimated on the relay segment)."""
        return float(self._SF[_OFF]) if self._SF[_OFF_MODE] == _OFF_FIXED else float("nan")

    # ------------------------------------------------------------------ processing
    def _raise(self, status: int, where: str) -> None:
        if status == _ERR_NO_RELAY:
            raise StreamError(f"{where}: relay == 0 before any shorted (relay == 1) segment: offset='relay' needs "
                              "the log to start with its relay segment (pass offset=<V_s offset in V> instead)")
        if status == _ERR_RELAY_VALUE:
            raise StreamError(f"{where}: relay must contain only 0 and 1")
        if status == _ERR_TIME:
            raise StreamError(f"{where}: t must be strictly increasing")
        raise StreamError(f"{where}: kernel status {status}")

    def step(self, u_cmd: float, v_shunt: float, relay: float = 0.0, t: float | None = None):
        """One raw sample: control voltage u_cmd [V], in-amp output v_shunt [V], relay 0/1, time t [s]
        (or the constructor's dt). Returns (dx_hat [m], f_hat [N])."""
        if t is None:
            if self.dt is None:
                raise ValueError("step: pass t or construct the stream with dt")
            tk, dt, use_t = 0.0, self.dt, False
        else:
            tk, dt, use_t = float(t), 0.0, True
        if self.drift is not None:
            dx, f = self.process(np.array([float(u_cmd)]), np.array([float(v_shunt)]), np.array([float(relay)]),
                                 None if t is None else np.array([tk]))
            return float(dx[0]), float(f[0])
        # the block path for one sample (the same kernels and the same H stream) on buffers allocated once; the front
        # state takes the sample once the whole sample is through, as a block's
        h = self.h
        if h._op is not None or h._reg_args is not None:
            return self._step_compiled(float(u_cmd), float(v_shunt), float(relay), tk, dt, use_t, "")
        st = _step_front(self._PF, self._SF, self._SF_next, self._B, float(u_cmd), float(v_shunt), float(relay), tk,
                         dt, use_t)
        if st:
            self._raise(st, f"sample {self.n_samples}")
        VH = h.process(self._B[_BUF_Q])
        dx, f = _step_back(self._PB, self._SB, self._B, VH, self._aux0)
        self._SF, self._SF_next = self._SF_next, self._SF
        return dx, f

    def _step_compiled(self, u, v, relay, tk, dt, use_t, where):
        """One sample through the three links in one compiled call (:func:`_step_gauged_pi` for Kuhnen's operator,
        :func:`_step_registry` for the registry models of :func:`_registry_h`). Returns (dx_hat, f_hat); a rejected
        sample raises :class:`StreamError` naming it ``sample <n><where>``."""
        h = self.h
        if h._op is not None:
            st, dx, f = _step_gauged_pi(self._PF, self._SF, self._SF_next, self._PB, self._SB, self._B, self._aux0,
                                        u, v, relay, tk, dt, use_t, *h._op_args)
        else:
            st, dx, f = _step_registry(self._PF, self._SF, self._SF_next, self._PB, self._SB, self._B, self._aux0,
                                       u, v, relay, tk, dt, use_t, *h._reg_args)
        if st:
            self._raise(st, f"sample {self.n_samples}{where}")
        return dx, f

    def process(self, u_cmd, v_shunt, relay=None, t=None, *, full: bool = False):
        """A block of raw samples (1-D arrays of equal length; relay default 0). Returns (dx_hat, f_hat) arrays,
        or with ``full=True`` a dict with dx_hat, f_hat, q (measured charge), q_model (after the charge members),
        V, V_H, V_p, dx_raw, f_raw. A block with a bad sample
        raises :class:`StreamError` and leaves the state as it was before the block."""
        u = np.ascontiguousarray(u_cmd, dtype=np.float64).ravel()
        v = np.ascontiguousarray(v_shunt, dtype=np.float64).ravel()
        n = u.shape[0]
        r = np.zeros(n) if relay is None else np.ascontiguousarray(relay, dtype=np.float64).ravel()
        if v.shape[0] != n or r.shape[0] != n:
            raise ValueError(f"u_cmd, v_shunt, relay must have equal lengths, got {n}, {v.shape[0]}, {r.shape[0]}")
        if t is None:
            if self.dt is None:
                raise ValueError("process: pass t or construct the stream with dt")
            tt, use_t, dt = np.zeros(0), False, self.dt
        else:
            tt = np.ascontiguousarray(t, dtype=np.float64).ravel()
            if tt.shape[0] != n:
                raise ValueError(f"t must have length {n}, got {tt.shape[0]}")
            use_t, dt = True, 0.0
        if n == 1 and not full and self.drift is None and (self.h._op is not None or self.h._reg_args is not None):
            # a one-sample block: the compiled step (the same kernels on the same values)
            dx, f = self._step_compiled(float(u[0]), float(v[0]), float(r[0]), float(tt[0]) if use_t else 0.0, dt,
                                        use_t, " (block index 0)")
            return np.array([dx]), np.array([f])
        q = np.empty(n)
        qm = np.empty(n)
        V = np.empty(n)
        ts = np.empty(n)
        SF = self._SF.copy()  # commit the state only if the whole block is valid
        ud = np.empty(n)
        st, k = front_kernel(self._PF, SF, tt, u, v, r, dt, use_t, q, V, qm, ts, ud)
        if st:
            self._raise(int(st), f"sample {self.n_samples + int(k)} (block index {int(k)})")
        if self.drift is not None:
            q, VH = self.drift.process(ts, q, V, r, self.h)
        else:
            VH = self.h.process(q)
        dx = np.empty(n)
        f = np.empty(n)
        aux = np.empty((n, 4)) if full else np.empty((0, 4))
        back_kernel(self._PB, self._SB, ud, r, q, V, VH, dx, f, aux)
        self._SF = SF
        if not full:
            return dx, f
        return {"dx_hat": dx, "f_hat": f, "q": qm, "q_model": q, "V": V, "V_H": aux[:, 3].copy(), "V_p": aux[:, 0].copy(),
                "dx_raw": aux[:, 1].copy(), "f_raw": aux[:, 2].copy()}
