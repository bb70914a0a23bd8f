"""Sub-step integrator of the virtual tweezer (numba).

Per sub-step (default 10 per DAQ sample, i.e. 10 kHz) the kernel
1. advances the HV amplifier (dead zone, first-order bandwidth, slew limit) from the DAQ output
   u_cmd, reconstructed linearly between the 1 kHz AO samples (a smoothing AO filter; a bare
   zero-order hold would put a +-20 % sawtooth on the shunt current that synchronous sampling
   turns into a ~9 % charge bias);
2. solves the implicit (backward-Euler) node equation of the charge circuit (thesis
   000_18d138f03f1777c3.txt sec. 5.1.1, Fig. 18, eqs. 56-57) for the actuator charge q_act:

       (V_c - V)/R  - g_relay V  =  dq_act/dt + V/R_leak + (V - v_da)/(R_da + dt/C_da),
       V = V_p + V_H,   V_H = H_true(q_act, history) (Preisach + electrical creep + stress; the stress
       factor follows the tip force of the previous sub-step, so that V_H moves as smoothly as the load),

   by a secant-Newton iteration (R/dt dominates the Jacobian, convergence in a few iterations);
   inside each iterate, the Goldfarb-Celanovic actuators (thesis eqs. 24-27, n_A in parallel, eq. 45)
   and the two-port mechanism are solved exactly for V_p, x_pzt and the tip closing d, including
   the tip environment (free / load cell / object with linear or Hertz contact), backlash and the
   implicit tip modal mass;
3. if the shunt current exceeds the amplifier current limit, re-solves with the current fixed;
4. commits the hysteresis state and the slow states (electrical creep, mechanical creep, DA,
   second mode).

Mechanics (actuator set + mechanism, all linear except contact):
    actuators:  f_in = n alpha V_p - n k (x - x_cr),     q_act = n alpha (x - x_cr) + n C_p V_p
    mechanism:  f_in = k11 x + k12 d,                    -f_tip = k12 x + k22 d  (+ m d'' + c d')
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .preisach import MAXS, U_BOTTOM, _fill_l, demagnetise, preisach_commit, preisach_eval
from .truth import NSTATE, truth_commit, truth_eval, truth_init

# parameter vector layout --------------------------------------------------------------------
PNAMES = (
    "dt_sample", "n_sub", "N", "alpha", "cp", "k", "tc_alpha", "tc_cp", "k11", "k12", "k22",
    "q_ref", "h_lin", "ec_c0", "ec_c1", "ec_c2", "ec_t0", "ec_t1", "ec_t2",
    "R_s", "R_relay", "g_leak", "C_da", "R_da",
    "amp_gain", "amp_tau", "slew", "i_max", "dead_zone",
    "m_tip", "c_tip",
    "mc_m", "mc_t0", "mc_t1", "mc_t2", "mc_w0", "mc_w1", "mc_w2",
    "stress_m", "f_stress_ref",
    "env_contact", "gap", "k_env", "hertz_m", "delta_ref",
    "backlash_r", "sm_m", "sm_omega", "sm_zeta", "preload_u", "demag_amp", "demag_cycles",
    "h_family", "h_sign",
)
PI = {n: i for i, n in enumerate(PNAMES)}
OUTS = ("V_c", "V", "V_p", "V_H", "q", "q_act", "x_pzt", "dx_tip", "f_tip", "arm", "i_s")
NOUT = len(OUTS)


@njit(cache=True)
def _f_env(dtip, contact, gap, kenv, hm, dref):
    """Contact force [N] and its derivative for tip closing dtip."""
    if contact == 0.0:
        return 0.0, 0.0
    de = dtip - gap
    if de <= 0.0:
        return 0.0, 0.0
    if hm == 0.0:
        return kenv * de, kenv
    sq = math.sqrt(de / dref)
    f = kenv * de * ((1.0 - hm) + hm * sq)
    df = kenv * ((1.0 - hm) + 1.5 * hm * sq)
    return f, df


@njit(cache=True)
def _solve_tip(kk, rhs, contact, gap, kenv, hm, dref, zb, br):
    """Solve kk d + f_env(tip(d)) = rhs for the mechanism coordinate d (monotone);
    tip(d) = clamp(zb, d - br, d + br) (backlash, br = half width).  Returns (d, tip, f)."""
    d = rhs / kk
    if br > 0.0:
        tip = min(max(zb, d - br), d + br)
    else:
        tip = d
    f, df = _f_env(tip, contact, gap, kenv, hm, dref)
    if f == 0.0:
        return d, tip, 0.0
    hi = d
    lo = gap - br - 1e-3
    for it in range(100):
        if br > 0.0:
            tip = min(max(zb, d - br), d + br)
            moving = (tip != zb) or (d - br == zb) or (d + br == zb)
        else:
            tip = d
            moving = True
        f, df = _f_env(tip, contact, gap, kenv, hm, dref)
        g = kk * d + f - rhs
        if g > 0.0:
            hi = d
        else:
            lo = d
        jac = kk + (df if moving else 0.0)
        dn = d - g / jac
        if not (lo < dn < hi):
            dn = 0.5 * (lo + hi)
        if abs(dn - d) < 1e-13:
            d = dn
            break
        d = dn
    if br > 0.0:
        tip = min(max(zb, d - br), d + br)
    else:
        tip = d
    f, df = _f_env(tip, contact, gap, kenv, hm, dref)
    return d, tip, f


@njit(cache=True)
def run_kernel(u_cmd, relay, dT, P, comps, hp, out):
    """Integrate one trial.  u_cmd [V] (DAQ output, held), relay (0/1), dT [K] per sample,
    P parameter vector (PNAMES), comps Preisach components (ncomp, 4) (family 0), hp the parameters of the other
    truth families (selfsense.sim.truth), out (NOUT, n) filled with
    the state at each sample instant t_k (before the interval [t_k, t_k+1) is integrated)."""
    n = u_cmd.size
    nsub = int(P[1])
    dts = P[0] / nsub
    N = P[2]
    alpha0 = P[3]
    cp0 = P[4]
    kact = P[5]
    k11 = P[8]
    k12 = P[9]
    k22 = P[10]
    qref = P[11]
    hlin = P[12]
    ecc = np.array([P[13], P[14], P[15]])
    ecb = np.array([1.0 - math.exp(-dts / P[16]), 1.0 - math.exp(-dts / P[17]), 1.0 - math.exp(-dts / P[18])])
    Rs = P[19]
    grel = 1.0 / P[20]
    gleak = P[21]
    Cda = P[22]
    Rda = P[23]
    gda = Cda / (Rda * Cda + dts) if Cda > 0.0 else 0.0   # 1/(R_da + dt/C_da)
    gain = P[24]
    atau = dts / P[25]
    slew = P[26]
    imax = P[27]
    dz = P[28]
    mt = P[29]
    ct = P[30]
    mcm = P[31]
    mcb = np.array([1.0 - math.exp(-dts / P[32]), 1.0 - math.exp(-dts / P[33]), 1.0 - math.exp(-dts / P[34])])
    mcw = np.array([P[35], P[36], P[37]])
    sm = P[38]
    fsr = P[39]
    contact = P[40]
    gap = P[41]
    kenv = P[42]
    hm = P[43]
    dref = P[44]
    br = 0.5 * P[45]
    smm = P[46]
    smw = P[47]
    smz = P[48]
    preload = P[49]
    nc = comps.shape[0]
    # hysteresis state
    tp = np.zeros(MAXS)
    ty = np.zeros(MAXS)
    tl = np.zeros((MAXS, nc, 2))
    tp[0] = U_BOTTOM
    iv = np.zeros(1, np.int64)
    fv = np.array([U_BOTTOM, 0.0])
    cl = np.zeros((nc, 2))
    _fill_l(U_BOTTOM, comps, cl)
    tl[0, :, :] = cl
    fam = int(P[52])
    hsign = P[53]
    hs = np.zeros(NSTATE)
    lu = np.zeros((nc, 2))
    if fam == 0:
        ydm = demagnetise(P[50], int(P[51]), tp, ty, tl, iv, fv, cl, comps)
        if preload > 0.0:
            _fill_l(preload, comps, lu)
            preisach_commit(preload, lu, tp, ty, tl, iv, fv, cl, comps)
            _fill_l(0.0, comps, lu)
            preisach_commit(0.0, lu, tp, ty, tl, iv, fv, cl, comps)
    else:
        ydm = truth_init(fam, hs, hp)
        if preload > 0.0:
            truth_commit(fam, preload, hs, hp, 0.0)
            truth_commit(fam, 0.0, hs, hp, 0.0)
    # states
    Vc = 0.0
    q = 0.0          # actuator charge
    qs = 0.0         # charge through the shunt
    z = np.zeros(3)  # electrical creep
    zc = np.zeros(3)  # mechanical creep
    vda = 0.0
    d = 0.0
    vd = 0.0
    zb = 0.0
    ftip = 0.0
    x = 0.0
    xcr = 0.0
    V = 0.0
    Vp = 0.0
    VH = 0.0
    tip = 0.0
    sw = 0.0
    sv = 0.0
    arm = 0.0
    bprev = 0.0
    i_s = 0.0
    iact = 0.0
    for kk_ in range(n):
        out[0, kk_] = Vc
        out[1, kk_] = V
        out[2, kk_] = Vp
        out[3, kk_] = VH
        out[4, kk_] = qs
        out[5, kk_] = q
        out[6, kk_] = x
        out[7, kk_] = tip
        out[8, kk_] = ftip
        out[9, kk_] = arm
        out[10, kk_] = i_s
        al = alpha0 * (1.0 + P[6] * dT[kk_])
        cpt = cp0 * (1.0 + P[7] * dT[kk_])
        A = N * al
        Cn = N * cpt
        Kn = N * kact
        D = Kn + k11
        den = A * A / D + Cn
        p1 = A * k12 / D / den
        x1 = (A * p1 - k12) / D
        kk = k12 * x1 + k22
        kke = kk + mt / (dts * dts) + ct / dts
        rel = relay[kk_] != 0
        g_r = grel if rel else 0.0
        u0 = u_cmd[kk_]
        u1 = u_cmd[kk_ + 1] if kk_ + 1 < n else u0
        dVdq0 = 1.0 / den / qref * qref + hlin / qref
        for s in range(nsub):
            # the tip load's stress on the hysteresis follows the tip force of the previous sub-step; held over a whole
            # DAQ sample it jumped at every sample, and the RC transient of the shunt current each jump drove was
            # over before the sampled current saw it: charge that flowed but never reached the DAQ record
            stress = 1.0 + sm * abs(ftip) / fsr
            # DAQ analog output with reconstruction filter: linear between the AO samples
            v_t = gain * (u0 + (u1 - u0) * (s + 1) / nsub)
            if dz > 0.0:
                if v_t > dz:
                    v_t -= dz
                elif v_t < -dz:
                    v_t += dz
                else:
                    v_t = 0.0
            Vc_new = (Vc + atau * v_t) / (1.0 + atau)
            if slew > 0.0:
                dv = Vc_new - Vc
                lim = slew * dts
                if dv > lim:
                    Vc_new = Vc + lim
                elif dv < -lim:
                    Vc_new = Vc - lim
            fixed_i = False
            Ifix = 0.0
            for attempt in range(2):
                # secant-Newton on q_new
                qn = q + dts * iact
                qa = 0.0
                ra = 0.0
                have_a = False
                for it in range(40):
                    u = qn / qref
                    if fam == 0:
                        _fill_l(u, comps, lu)
                        y = preisach_eval(u, lu, tp, ty, tl, iv, fv, cl, comps)
                    else:
                        y = truth_eval(fam, u, hs, hp, dts)
                    vh = (hlin * u - hsign * (y - ydm)) * stress
                    for j in range(3):
                        vh += ecc[j] * (1.0 - ecb[j]) * (u - z[j])
                    p0 = (qn + A * xcr - A * Kn * xcr / D) / den
                    x0 = (A * p0 + Kn * xcr) / D
                    rhs = -k12 * x0 + mt * (d + dts * vd) / (dts * dts) + ct * d / dts
                    dn, tipn, fn = _solve_tip(kke, rhs, contact, gap, kenv, hm, dref, zb, br)
                    vpn = p0 + p1 * dn
                    Vn = vpn + vh
                    iload = (qn - q) / dts + gleak * Vn + gda * (Vn - vda)
                    if fixed_i:
                        r = Ifix - g_r * Vn - iload
                    else:
                        r = (Vc_new - Vn) / Rs - g_r * Vn - iload
                    if have_a and qn != qa:
                        jac = (r - ra) / (qn - qa)
                    else:
                        jac = -((0.0 if fixed_i else 1.0 / Rs) + g_r + gleak + gda) * dVdq0 - 1.0 / dts
                    if jac >= 0.0:
                        jac = -((0.0 if fixed_i else 1.0 / Rs) + g_r + gleak + gda) * dVdq0 - 1.0 / dts
                    qa = qn
                    ra = r
                    have_a = True
                    step = -r / jac
                    if abs(step) < 2e-13 or it == 39:
                        break   # accept the values evaluated at qn (|step| < 2e-13 C, ~1e-7 V)
                    qn = qn + step
                # shunt current from KCL at the actuator node (actuators + leak + DA + relay), so that
                # the charge through the shunt is conserved exactly; the converged residual
                # (|dq| < 2e-13 C per sub-step) stays in V_c - R i - V (< 1e-6 V)
                isn = iload + g_r * Vn
                if rel and not fixed_i:
                    # relay closed: the secant's stopping rule (|dq| < 2e-13 C) leaves a residual
                    # current of up to (g_relay / C) 2e-13 C, about 1 uA at 0.1 ohm, that KCL would
                    # book on the shunt; the shunt carries (V_c - V) / R only, the rest flows in
                    # the relay, which nobody measures
                    isn = (Vc_new - Vn) / Rs
                if fixed_i:
                    Vc_new = Vn + Rs * Ifix
                if imax > 0.0 and not fixed_i and abs(isn) > imax:
                    fixed_i = True
                    Ifix = imax if isn > 0.0 else -imax
                    continue
                break
            # commit
            if fam == 0:
                preisach_commit(u, lu, tp, ty, tl, iv, fv, cl, comps)
            else:
                truth_commit(fam, u, hs, hp, dts)
            for j in range(3):
                z[j] += (u - z[j]) * ecb[j]
            xn = x0 + x1 * dn
            xel = xn - xcr
            for j in range(3):
                zc[j] += (xel - zc[j]) * mcb[j]
            xcr = mcm * (mcw[0] * zc[0] + mcw[1] * zc[1] + mcw[2] * zc[2])
            vda += (Vn - vda) * (dts * gda / Cda) if Cda > 0.0 else 0.0
            iact = (qn - q) / dts
            vd = (dn - d) / dts
            d = dn
            zb = tipn
            q = qn
            qs += dts * isn
            i_s = isn
            Vc = Vc_new
            V = Vn
            Vp = vpn
            VH = vh
            x = xn
            tip = tipn
            ftip = fn
            b = 0.5 * tipn
            if smm > 0.0:
                bd = (b - bprev) / dts
                sv += dts * (-2.0 * smz * smw * (sv - bd) - smw * smw * (sw - b))
                sw += dts * sv
                arm = (1.0 - smm) * b + smm * sw
            else:
                sw = b
                arm = b
            bprev = b
    return ydm
