"""``selfsense export-c``: a fitted estimator as dependency-free C99 for a real-time controller.

The generated pair ``<name>.h`` / ``<name>.c`` holds the whole chain of :class:`selfsense.sensing.streaming.
SelfSensingStream` for one model at one sample time, with every parameter as a ``static const double`` table written
with 17 significant digits:

1. front: SI conversion, in-amp offset from the first relay segment, trapezoidal charge reset by the relay
   (``000_18d138f03f1777c3.txt`` eqs. 56-57), the voltage link's slew limit (the delivered command, one state) and lag member (``V - tau gain du/dt``, the backward
   difference over the sample period), the quantiser, absorption and leakage members;
2. H(Q) of any model the estimator holds: the registry's ``linear``, ``pi``, ``preisach`` (the incremental grid of
   ``hysteresis.models._grid``), ``ri`` (``002_7d89b7147aad52e4.txt`` eqs. 8-11, 15-16), ``duhem``, ``modified_pi``
   (Kuhnen's operator, thesis eqs. 29-42, in the sign / linear gauge) and the thesis identification's ``GaugedH``,
   ``RICreepH``, ``RIModel``;
3. back: eq. (27), eq. (52) with the rest offset, the load link's creep member (selfsense.chain.creep: a bank of
   first-order lags on Q and V_p, ``2 * len(taus)`` states from rest, its ``s = K beta`` at the displacement and
   ``kappa s`` at the force, thesis eqs. 46, 52 + the bank), the sliding DC offset and limiting (thesis sec. 5.2).

API (``<name>.h``)::

    typedef struct { ... } ss_state;               /* all state, fixed size: no allocation anywhere */
    void ss_init(ss_state *s);                     /* the relaxed state (before the first sample) */
    int  ss_step(ss_state *s, double u_cmd, double v_shunt, int relay, double *dx, double *f);

``ss_step`` takes one raw DAQ sample at the fixed sample period ``SS_DT`` (control voltage [V], in-amp output [V],
relay 0/1) and writes the tip displacement [m] and force [N]; it returns ``SS_OK`` (0) or an error code
(``SS_ERR_NO_RELAY``: the stream must open with its relay segment; ``SS_ERR_RELAY``: relay not 0/1;
``SS_ERR_STACK``: an extrema stack is full). Double precision, no global state, no allocation, deterministic
(compile without ``-ffast-math``). A model with the offset-drift member (fitted over whole trials in batch) is
refused, naming the member.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Mapping

import numpy as np


__all__ = ["export_c", "ExportError", "c_sources"]


class ExportError(ValueError):
    """The model cannot be exported (unknown kind, wrong shapes, a member the C code does not carry)."""


def _num(x: float) -> str:
    x = float(x)
    if not math.isfinite(x):
        raise ExportError(f"non-finite parameter {x!r}")
    s = repr(x)
    return s if ("e" in s or "." in s or "inf" in s) else s + ".0"


def _table(name: str, values) -> str:
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0:
        return f"static const double {name}[1] = {{0.0}};  /* empty */\n"
    body = ",\n    ".join(", ".join(_num(x) for x in v[i:i + 4]) for i in range(0, v.size, 4))
    return f"static const double {name}[{v.size}] = {{\n    {body}\n}};\n"


def _h_spec(h, dt: float) -> dict:
    """The H model as the C code needs it: kind code, tables and sizes (raises ExportError on unknown kinds)."""
    name = type(h).__name__
    kind = getattr(h, "kind", None) if hasattr(h, "predict") else None
    if kind in ("linear", "pi", "preisach", "ri"):
        c = np.asarray(h.coef_, float)
        nb = h._n_basis()
        ntau = len(h.creep_tau_s) if h.creep and h.creep_tau_s else 0
        spec = {"H": "LP", "q_lo": h.q_lo_, "q_span": h.q_span_, "lin": c[nb], "const": c[-1],
                "relax_g": [-math.expm1(-dt / float(t)) for t in (h.creep_tau_s if ntau else ())],
                "relax_w": list(c[nb + 1:nb + 1 + ntau]), "basis": "none", "play_r": [], "play_w": [], "rev_k": [], "rev_w": [],
                "grid_n": 0,
                "grid_w": [], "ri_b": [], "ri_p": [], "ri_scale": 1.0, "ri_depth": 1024}
        w = c[:nb]
        if kind == "pi":
            spec.update(basis="play", play_r=np.arange(1, h.n_play + 1) / h.n_play, play_w=w)
        elif kind == "preisach":
            nc = h.n_grid * (h.n_grid + 1) // 2
            spec.update(basis="preisach", grid_n=h.n_grid, grid_w=w[:nc],
                        play_r=np.arange(1, h.n_play + 1) / h.n_play * 0.5 if h.n_play else [],
                        play_w=w[nc:nc + h.n_play], rev_k=h._rev_knots(), rev_w=w[nc + h.n_play:])
        elif kind == "ri":
            from selfsense.hysteresis.ri import diagonal_constraint_basis

            spec.update(basis="ri", ri_b=w[:5], ri_p=diagonal_constraint_basis() @ w[5:])
        return spec
    if kind == "duhem":
        nc = len(h.creep_tau_s)
        return {"H": "DUHEM", "q_lo": h.q_lo_, "q_span": h.q_span_, "coef": h.coef_, "deg": h.degree,
                "v_lo": h.v_lo_, "v_span": h.v_span_, "eps": h.eps, "v_min": h.v_lo_ - 1.0 * h.v_span_,
                "v_max": h.v_lo_ + 2.0 * h.v_span_,
                "relax_g": [-math.expm1(-dt / float(t)) for t in h.creep_tau_s], "relax_w": list(h.lin_coef_[:nc]),
                "const": h.lin_coef_[nc], "lin": h.lin_coef_[nc + 1] if len(h.lin_coef_) > nc + 1 else 0.0}
    if kind == "modified_pi" or (name == "GaugedH" and type(h.inner).__name__ == "ModifiedPI"):
        inner, sign, cg = ((h.inner_, h.sign_, h.c_) if kind == "modified_pi" else (h.inner, h.sign, h.c))
        m = inner
        n, mm = len(m.r_K), len(m.a_K)
        r, w = np.asarray(m.r_S, float), np.asarray(m.w_S, float)
        return {"H": "MPI", "sign": sign, "gauge_c": cg, "rH": m.r_H, "wH": m.w_H, "zH0": m.z_H0,
                "rC": np.repeat(m.r_K, mm), "wC": np.repeat(m.w_K, mm), "gC": np.tile(-np.expm1(-m.a_K * dt), n),
                "cC0": np.asarray(m.Z_K0, float).reshape(-1), "offset": m.offset, "w0": float(w[r == 0].sum()),
                "rSp": r[r > 0], "wSp": w[r > 0], "rSn": r[r < 0], "wSn": w[r < 0]}
    if name in ("RICreepH", "RIModel") or (name == "GaugedH" and type(h.inner).__name__ == "RIModel"):
        ri = h.ri if name == "RICreepH" else (h if name == "RIModel" else h.inner)
        spec = {"H": "RIC", "ri_b": ri.b, "ri_p": ri.p, "ri_scale": 1.0 if ri.input_scale is None else ri.input_scale,
                "ri_offset": ri.input_offset, "ri_depth": ri.max_depth, "rK": [], "gK": [], "wK": [], "lin": 0.0,
                "sign": 1.0, "gauge_c": 0.0}
        if name == "RICreepH":
            spec.update(rK=h.r_K, gK=-np.expm1(-np.asarray(h.a_K, float) * h.dt), wK=np.asarray(h.w_K).ravel(),
                        lin=h.c, nK=len(h.r_K), mK=len(h.a_K))
        if name == "GaugedH":
            spec.update(sign=h.sign, gauge_c=h.c)
        return spec
    raise ExportError(f"H model {kind or name!r} has no C export")


_HEADER = """/* {name}.h: self-sensing estimator exported by selfsense {version} (selfsense export-c).
 * Model: {model}; sample period SS_DT = {dt} s. Generated file: regenerate instead of editing.
 * Usage: ss_state s; ss_init(&s); every sample: ss_step(&s, u_cmd, v_shunt, relay, &dx, &f);
 */
#ifndef {guard}
#define {guard}

#define SS_OK 0
#define SS_ERR_NO_RELAY 1   /* relay == 0 before the first relay segment: the in-amp offset is unknown */
#define SS_ERR_RELAY 2      /* relay not 0 or 1 */
#define SS_ERR_STACK 3      /* an extrema stack of the hysteresis operator is full */
#define SS_DT {dt}
{sizes}
typedef struct {{
    double t_n, vs_last, csum, base, v_last, icsum, ibase, off_sum, off_n, off, da_y, m_last, mcsum, mbase, u_last;
    int off_mode;           /* 0 waiting for the relay, 1 averaging it, 2 offset known */
    double dx_dc, f_dc;     /* sliding DC offsets */
{fields}}} ss_state;

void ss_init(ss_state *s);
int ss_step(ss_state *s, double u_cmd, double v_shunt, int relay, double *dx, double *f);

#endif
"""

_FRONT_BACK = r"""
void ss_init(ss_state *s)
{
    int i;
    s->t_n = 0.0; s->vs_last = 0.0; s->csum = 0.0; s->base = 0.0; s->v_last = 0.0; s->icsum = 0.0; s->ibase = 0.0;
    s->da_y = 0.0; s->m_last = 0.0; s->mcsum = 0.0; s->mbase = 0.0; s->u_last = 0.0;
    s->off_sum = 0.0; s->off_n = 0.0; s->off = OFF0; s->off_mode = OFF_MODE0;
    s->dx_dc = 0.0; s->f_dc = 0.0;
#if CR_N > 0
    for (i = 0; i < 2 * CR_N; i++) s->cr_y[i] = 0.0;  /* the creep member's lags from rest */
#endif
    (void)i;
    h_init(s);
}

static double trapz(double a, double b, double h) { return 0.5 * (a + b) * h; }

int ss_step(ss_state *s, double u_cmd, double v_shunt, int relay, double *dx, double *f)
{
    double Vs, V, q, inc, iinc, minc, mk, VH, Vp, dxr, fr, d, ff;
    int shorted, st;
    if (relay != 0 && relay != 1) return SS_ERR_RELAY;
    shorted = relay == 1;
    Vs = v_shunt / INAMP;
    if (SLEW > 0.0 && s->t_n > 0.0) {  /* the amplifier's slew limit: u_last is the delivered command */
        d = GAIN * u_cmd - GAIN * s->u_last;
        if (d > SLEW * SS_DT) u_cmd = (GAIN * s->u_last + SLEW * SS_DT) / GAIN;
        else if (d < -SLEW * SS_DT) u_cmd = (GAIN * s->u_last - SLEW * SS_DT) / GAIN;
    }
    V = GAIN * u_cmd - Vs;
    if (LAG_K != 0.0 && s->t_n > 0.0) V = V - LAG_K * (u_cmd - s->u_last) / SS_DT;  /* lag member: V - tau gain du/dt */
    if (s->off_mode == 0) {
        if (!shorted) return SS_ERR_NO_RELAY;
        s->off_mode = 1; s->off_sum = Vs; s->off_n = 1.0;
    } else if (s->off_mode == 1) {
        if (shorted) { s->off_sum += Vs; s->off_n += 1.0; }
        else { s->off = s->off_sum / s->off_n; s->off_mode = 2; }
    }
    inc = 0.0; iinc = 0.0; minc = 0.0;
    /* quantiser member: m = 1 on open samples more than half an ADC step off the short's mean */
    mk = (!shorted && fabs(Vs - s->off) > Q_HALF) ? 1.0 : 0.0;
    if (s->t_n > 0.0 && !shorted) {
        inc = trapz((s->vs_last - s->off) / R_SHUNT, (Vs - s->off) / R_SHUNT, SS_DT);
        iinc = trapz(s->v_last, V, SS_DT);
        minc = trapz(s->m_last, mk, SS_DT);
    }
    s->csum += inc; s->icsum += iinc; s->mcsum += minc;
    if (shorted) { s->base = s->csum; s->ibase = s->icsum; s->mbase = s->mcsum; q = 0.0; }
    else q = s->csum - s->base;
    if (Q_I != 0.0) q = q - Q_I * (shorted ? 0.0 : s->mcsum - s->mbase);  /* quantiser member: Q - i_q int m dt */
    if (DA_C != 0.0) {  /* absorption member: Q - c LP_tau(V) */
        s->da_y = (1.0 - DA_A) * V + DA_A * s->da_y;
        q = q - DA_C * s->da_y;
    }
    if (G_LEAK != 0.0) q = q - G_LEAK * (shorted ? 0.0 : s->icsum - s->ibase);
    s->vs_last = Vs; s->v_last = V; s->u_last = u_cmd; s->m_last = mk; s->t_n += 1.0;
    st = h_step(s, q, &VH);
    if (st != SS_OK) return st;
    Vp = V - VH;
    if (KS_H != 0.0 || KS_Q != 0.0) {  /* stress member: V_p - w f, f in closed form (ridge) within [F_LO, F_HI] */
        double w = KS_H * (VH - KS_AH) + KS_Q * (q - KS_AQ), a = B21 * q + B22 * Vp, d = 1.0 + B22 * w;
        double den = d * d + KS_RIDGE, fl = den != 0.0 ? a * d / den : 0.0;
        fl = fl < F_LO ? F_LO : (fl > F_HI ? F_HI : fl);
        Vp = Vp - w * fl;
    }
    if (shorted) { dxr = 0.0; fr = 0.0; }
    else { dxr = A1 * q + A2 * Vp + DX0; fr = B21 * q + B22 * Vp + 0.0; }
#if CR_N > 0
    {   /* the load link's creep member (selfsense.chain.creep): s = sum_tau beta (LP_tau[Q] - Q) + beta' (LP_tau[V_p]
         * - V_p), every lag from rest over every sample; s at the displacement, CR_KAPPA s at the force */
        double scr = 0.0, yq, yv;
        int i;
        for (i = 0; i < CR_N; i++) {
            yq = (1.0 - CR_A[i]) * q + CR_A[i] * s->cr_y[2 * i];
            yv = (1.0 - CR_A[i]) * Vp + CR_A[i] * s->cr_y[2 * i + 1];
            s->cr_y[2 * i] = yq; s->cr_y[2 * i + 1] = yv;
            scr += CR_BETA[2 * i] * (yq - q) + CR_BETA[2 * i + 1] * (yv - Vp);
        }
        if (!shorted) { dxr = dxr + scr; fr = fr + CR_KAPPA * scr; }
    }
#endif
    d = dxr; ff = fr;
    if (DC_DX) { if (fabs(u_cmd) <= ZERO_LEVEL) s->dx_dc = dxr; d = dxr - s->dx_dc; }
    if (DC_F) { if (fabs(u_cmd) <= ZERO_LEVEL) s->f_dc = fr; ff = fr - s->f_dc; }
    if (LIMIT) {
        d = d < DX_LO ? DX_LO : (d > DX_HI ? DX_HI : d);
        ff = ff < F_LO ? F_LO : (ff > F_HI ? F_HI : ff);
    }
    *dx = d; *f = ff;
    return SS_OK;
}
"""

_RELAX = r"""
static double relax_step(ss_state *s, double u)
{
    double y = 0.0;
    int j;
    for (j = 0; j < N_RELAX; j++) {
        if (RELAX_W[j] == 0.0) continue;
        s->rz[j] += RELAX_G[j] * (u - s->rz[j]);
        y += RELAX_W[j] * (u - s->rz[j]);
    }
    return y;
}
"""

_REV = r"""
static double rev_sum(double u)
{
    /* reversible part of the Preisach model (hysteresis.models._grid.reversible_output) */
    double acc = 0.0;
    int i;
    for (i = 0; i < N_REV; i++) {
        double x = u - REV_K[i];
        acc += REV_W[i] * (x > 0.0 ? x : 0.0);
    }
    return acc;
}
"""

_PLAY = r"""
static double play_step(ss_state *s, double x)
{
    double acc = 0.0, lo, hi, z;
    int i;
    for (i = 0; i < N_PLAY; i++) {
        lo = x - PLAY_R[i]; hi = x + PLAY_R[i];
        z = s->pz[i];
        z = z < lo ? lo : (z > hi ? hi : z);
        s->pz[i] = z;
        acc += PLAY_W[i] * z;
    }
    return acc;
}
"""

_GRID = r"""
#define GRID_BIG 1e300
static double prim(double x, double b0, double top)
{
    if (x <= b0) return 0.0;
    if (x <= top) return 0.5 * (x - b0) * (x - b0);
    return 0.5 * (top - b0) * (top - b0) + (top - b0) * (x - top);
}

static double cell_fraction(const ss_state *s, double a0, double a1, double b0, double b1, double full)
{
    double area = 0.0, p0, p1, q0, q1, top;
    int jj;
    for (jj = 0; jj < s->gK; jj++) {
        p1 = s->gMs[jj];
        p0 = jj + 1 < s->gK ? s->gMs[jj + 1] : -GRID_BIG;
        if (p1 <= a0) break;
        if (p0 >= a1) continue;
        q0 = p0 > a0 ? p0 : a0;
        q1 = p1 < a1 ? p1 : a1;
        top = s->gms[jj] < b1 ? s->gms[jj] : b1;
        if (top <= b0) continue;
        area += prim(q1, b0, top) - prim(q0, b0, top);
    }
    return area / full;
}

static void grid_mark(ss_state *s, double a_gt, double a_lt, double b_lt, double b_gt)
{
    const double h = 1.0 / GRID_N;
    double a0, a1, b0, b1;
    int i, jb, i0, i1, jlo, jhi, c, jmax;
    i0 = (int)floor(((a_gt > -h ? a_gt : -h) - 0.0) / h) - 1; if (i0 < 0) i0 = 0;
    i1 = (int)ceil(((a_lt < (GRID_N + 1) * h ? a_lt : (GRID_N + 1) * h) - 0.0) / h) + 1;
    if (i1 > GRID_N - 1) i1 = GRID_N - 1;
    jlo = (int)floor(((b_gt > -h ? b_gt : -h) - 0.0) / h) - 1; if (jlo < 0) jlo = 0;
    jhi = (int)ceil(((b_lt < (GRID_N + 1) * h ? b_lt : (GRID_N + 1) * h) - 0.0) / h) + 1;
    for (i = i0; i <= i1; i++) {
        a0 = 0.0 + i * h; a1 = a0 + h;
        if (!(a1 > a_gt && a0 < a_lt)) continue;
        jmax = i < jhi ? i : jhi;
        for (jb = jlo; jb <= jmax; jb++) {
            b0 = 0.0 + jb * h; b1 = b0 + h;
            c = i * (i + 1) / 2 + jb;
            if (b0 < b_lt && b1 > b_gt && !s->gdirty[c]) { s->gdirty[c] = 1; s->glist[s->gnd++] = c; }
        }
    }
}

/* Preisach grid on [0, 1] (hysteresis.models.preisach_grid_kernel, weighted output): the weighted up-fractions */
static int grid_step(ss_state *s, double u, double *out)
{
    const double h = 1.0 / GRID_N;
    double x = u < 0.0 ? 0.0 : (u > 1.0 ? 1.0 : u), top, a0, b0, nw, full;
    int j, c, d, dropped, resync;
    if (!s->gstarted || x > s->gprev) {
        while (s->gK > 0 && s->gMs[s->gK - 1] <= x) s->gK--;
        if (s->gK < GRID_STACK && s->gstarted) {
            s->gMs[s->gK] = x; s->gms[s->gK] = GRID_BIG; s->gK++;
            grid_mark(s, s->gprev, x, x, -GRID_BIG);
        } else {
            if (s->gK < GRID_STACK) { s->gMs[s->gK] = x; s->gms[s->gK] = GRID_BIG; s->gK++; }
            for (c = 0; c < GRID_NC; c++) if (!s->gdirty[c]) { s->gdirty[c] = 1; s->glist[s->gnd++] = c; }
        }
        s->gstarted = 1;
    } else if (x < s->gprev) {
        j = 0;
        while (j < s->gK && s->gms[j] < x) j++;
        if (j < s->gK) {
            dropped = s->gK - 1 > j;
            top = s->gMs[j];
            s->gms[j] = x;
            s->gK = j + 1;
            grid_mark(s, x, top, s->gprev, dropped ? -GRID_BIG : x);
        }
    }
    s->gprev = x;
    resync = fmod(s->gcount, 256.0) == 0.0;
    s->gcount += 1.0;
    for (d = 0; d < s->gnd; d++) {
        c = s->glist[d];
        a0 = 0.0 + GRID_CI[c] * h;
        b0 = 0.0 + GRID_CJ[c] * h;
        full = GRID_CJ[c] < GRID_CI[c] ? h * h : 0.5 * h * h;
        nw = cell_fraction(s, a0, a0 + h, b0, b0 + h, full);
        if (!resync) s->gy += GRID_W[c] * (nw - s->gF[c]);
        s->gF[c] = nw;
        s->gdirty[c] = 0;
    }
    s->gnd = 0;
    if (resync) {
        s->gy = 0.0;
        for (c = 0; c < GRID_NC; c++) s->gy += GRID_W[c] * s->gF[c];
    }
    *out = s->gy;
    return SS_OK;
}
"""

_RI = r"""
static double ri_F(double M) { return RI_B[0] + M * (RI_B[1] + M * (RI_B[2] + M * (RI_B[3] + M * RI_B[4]))); }
static double ri_G(double M, double m)
{
    const double *p = RI_P;
    double m2 = m * m, M2 = M * M;
    return (p[0] + p[1] * m + p[2] * M + p[3] * m2 + p[4] * M * m + p[5] * M2
            + p[6] * m2 * m + p[7] * M * m2 + p[8] * M2 * m + p[9] * M2 * M
            + p[10] * m2 * m2 + p[11] * M * m2 * m + p[12] * M2 * m2 + p[13] * M2 * M * m
            + p[14] * M2 * M2);
}
/* one sample of the RI model (hysteresis._ri_kernels.ri_eval_kernel) on the scaled input u >= 0 */
static int ri_step(ss_state *s, double u, double *y)
{
    double *E = s->rE, *P = s->rP, Mk, mk, Mk1, prev, Mn, mn, pre;
    int L = s->rL, rising = (L % 2) == 1;
    if (rising && u < s->ru_prev) {
        if (L >= RI_DEPTH) return SS_ERR_STACK;
        E[L] = s->ru_prev;
        if (L >= 3) {
            Mk = E[L - 2]; mk = E[L - 1]; Mk1 = E[L];
            prev = L >= 4 ? P[L - 2] : 0.0;
            P[L] = prev + (ri_G(Mk, mk) - ri_G(Mk1, mk));
        } else P[L] = 0.0;
        L++;
    } else if (!rising && u > s->ru_prev) {
        if (L >= RI_DEPTH) return SS_ERR_STACK;
        E[L] = s->ru_prev;
        P[L] = P[L - 1];
        L++;
    }
    if ((L % 2) == 1) { while (L >= 3 && u >= E[L - 2]) L -= 2; }
    else { while (L >= 4 && u <= E[L - 2]) L -= 2; }
    s->rL = L;
    s->ru_prev = u;
    if (L == 1) *y = ri_F(u);
    else if ((L % 2) == 1) {
        Mn = E[L - 2]; mn = E[L - 1];
        pre = L >= 4 ? P[L - 2] : 0.0;
        *y = ri_F(E[1]) - pre - (ri_G(Mn, mn) - ri_G(u, mn));
    } else {
        Mn = E[L - 1];
        pre = L >= 4 ? P[L - 1] : 0.0;
        *y = ri_F(E[1]) - pre - ri_G(Mn, u);
    }
    return SS_OK;
}
"""

_DUHEM = r"""
static int duhem_step(ss_state *s, double un, double *out)
{
    double x, wr, w, g, xi, wj, nw;
    int i, j, m, off;
    if (!s->dstarted) { s->dstarted = 1; s->dext = un; }
    else {
        if (s->ddir > 0) { if (un > s->dext) s->dext = un; else if (s->dext - un > D_EPS) { s->ddir = -1; s->dext = un; } }
        else { if (un < s->dext) s->dext = un; else if (un - s->dext > D_EPS) { s->ddir = 1; s->dext = un; } }
        x = 2.0 * s->dup - 1.0; x = x < -1.5 ? -1.5 : (x > 1.5 ? 1.5 : x);
        wr = 2.0 * (s->dval - D_VLO) / D_VSPAN - 1.0;
        w = wr < -1.5 ? -1.5 : (wr > 1.5 ? 1.5 : wr);
        off = s->ddir > 0 ? 0 : D_NB;
        g = 0.0; m = 0; xi = 1.0;
        for (i = 0; i <= D_DEG; i++) {
            wj = 1.0;
            for (j = 0; j <= D_DEG - i; j++) { g += D_COEF[off + m] * (xi * wj); wj *= w; m++; }
            xi *= x;
        }
        nw = s->dval + g * (un - s->dup);
        s->dval = nw < D_VMIN ? D_VMIN : (nw > D_VMAX ? D_VMAX : nw);
    }
    s->dup = un;
    *out = s->dval;
    return SS_OK;
}
"""

_MPI = r"""
/* Kuhnen's modified PI operator with creep (thesis eq. 42; hysteresis._kernels.gamma_kernel) */
static double mpi_step(ss_state *s, double x)
{
    double u = MPI_OFFSET, lo, hi, z, c, t, xl, g;
    int i;
    for (i = 0; i < N_H; i++) {
        lo = x - MPI_RH[i]; hi = x + MPI_RH[i]; z = s->mp[i];
        z = z < lo ? lo : (z > hi ? hi : z);
        s->mp[i] = z;
        u += MPI_WH[i] * z;
    }
    if (s->mhave) {
        xl = s->mxl;
        for (i = 0; i < N_C; i++) {
            c = s->mc[i]; lo = xl - MPI_RC[i]; hi = xl + MPI_RC[i];
            t = c < lo ? lo : (c > hi ? hi : c);
            c = c + MPI_GC[i] * (t - c);
            s->mc[i] = c;
            u += MPI_WC[i] * c;
        }
    } else {
        for (i = 0; i < N_C; i++) u += MPI_WC[i] * s->mc[i];
    }
    s->mhave = 1; s->mxl = x;
    g = MPI_W0 * u;
    for (i = 0; i < N_SP; i++) g += MPI_WSP[i] * (u - MPI_RSP[i] > 0.0 ? u - MPI_RSP[i] : 0.0);
    for (i = 0; i < N_SN; i++) g += MPI_WSN[i] * (u - MPI_RSN[i] < 0.0 ? u - MPI_RSN[i] : 0.0);
    return g;
}
"""

_KCREEP = r"""
/* Kuhnen's creep operators (thesis eq. 39; operators.creep_operator): output before the update by this input */
static double kcreep_step(ss_state *s, double x)
{
    double y = 0.0, lo, hi, c, t;
    int i, j;
    if (s->khave) {
        for (i = 0; i < N_K; i++) {
            lo = s->kxl - RK_R[i]; hi = s->kxl + RK_R[i];
            for (j = 0; j < M_K; j++) {
                c = s->kc[i * M_K + j];
                t = c < lo ? lo : (c > hi ? hi : c);
                s->kc[i * M_K + j] = c + RK_G[j] * (t - c);
            }
        }
    }
    s->khave = 1; s->kxl = x;
    for (i = 0; i < N_K * M_K; i++) y += RK_W[i] * s->kc[i];
    return y;
}
"""


def c_sources(est, rig, dt: float, name: str = "selfsense_estimator", model_label: str = "") -> tuple[str, str]:
    """(header, source) of the C99 export of the fitted estimator ``est`` at sample period ``dt`` [s]."""
    from selfsense import version
    from selfsense.io.rig import rig_value

    if (getattr(est, "amplifier_", None) or {}).get("applied"):
        raise ExportError("the model carries the amplifier member (the actuator voltage rebuilt where the HV amplifier "
                          "sits at its current limit, up to the sample where the limit lets go), which a controller has "
                          "not seen yet; refit with calibration: amplifier: off to export it")
    if (getattr(est, "temperature_", None) or {}).get("applied"):
        raise ExportError("the model carries the temperature member (a charge scale per trial of the fitted campaign, "
                          "chain.temperature), which a controller running after the campaign cannot know; refit with "
                          "calibration: temperature: off to export it, or stream it in Python with "
                          "SelfSensingStream(..., trial=...)")
    if getattr(est, "offset_drift_", False):
        raise ExportError("the model carries the offset-drift member (offset_drift: true), fitted over the rest "
                          "segments of whole trials, which a controller has not seen yet; refit with calibration: "
                          "drift: off to export it")
    if not (np.isfinite(dt) and dt > 0):
        raise ExportError(f"sample period dt must be > 0 s, got {dt!r}")
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ExportError(f"name {name!r} is not a C identifier")
    cfg, c = est.config, est.coef_
    ab = getattr(est, "absorption_", None) or {}
    qz = getattr(est, "quantiser_", None) or {}
    lag = getattr(est, "amplifier_lag_", None) or {}
    h = _h_spec(est.hysteresis_, float(dt))
    # the load link's creep member (selfsense.chain.creep): its lags at the export's sample period
    cr = getattr(est, "tip_creep_", None) or {}
    cr_taus = [float(x) for x in cr["taus_s"]] if cr.get("applied") else []
    cr_beta = [float(b) for b in cr["beta"]] if cr.get("applied") else []
    if len(cr_beta) != 2 * len(cr_taus):
        raise ExportError(f"tip_creep: beta must hold 2 coefficients per lag ({2 * len(cr_taus)}), got {len(cr_beta)}")
    # the load link's stress member (weights 0 where it is not carried)
    (s_h, s_q), (a_h, a_q) = ((est.stress_weights(), est.stress_offsets()) if hasattr(est, "stress_weights")
                              else ((0.0, 0.0), (0.0, 0.0)))
    consts = {
        "R_SHUNT": rig_value(rig, "shunt_resistance_ohm"), "INAMP": rig_value(rig, "inamp_gain"),
        "GAIN": rig_value(rig, "amplifier_gain"), "G_LEAK": float(est.leakage_s_ or 0.0),
        # the voltage link's lag member (chain.amplifier.lag_column): tau * gain
        "LAG_K": (float(lag["tau_s"]) * rig_value(rig, "amplifier_gain")) if lag.get("applied") else 0.0,
        # the amplifier member's slew limit (chain.amplifier.with_slew) [V/s]
        "SLEW": est.slew_rate() if hasattr(est, "slew_rate") else 0.0,
        "DA_C": float(ab["c_f"]) if ab.get("applied") else 0.0,
        "DA_A": float(np.exp(-float(dt) / float(ab["tau_s"]))) if ab.get("applied") else 0.0,
        "Q_I": float(qz["i_q_a"]) if qz.get("applied") else 0.0,
        "Q_HALF": float(qz["half_step_v"]) if qz.get("applied") else 0.0,
        "A1": c["A1"], "A2": c["A2"], "B21": c["B21"], "B22": c["B22"], "DX0": float(c.get("dx0", 0.0)),
        "KS_H": s_h, "KS_Q": s_q, "KS_AH": a_h, "KS_AQ": a_q,
        "KS_RIDGE": est.stress_ridge() if hasattr(est, "stress_ridge") else 0.0,
        "ZERO_LEVEL": cfg.zero_input_v / max(rig_value(rig, "amplifier_gain"), 1e-12),
        "DX_LO": est.ranges_["dx"][0], "DX_HI": est.ranges_["dx"][1], "F_LO": est.ranges_["f"][0],
        "F_HI": est.ranges_["f"][1],
    }
    flags = {"DC_DX": int(bool(cfg.dc_offset)), "DC_F": int(bool(cfg.dc_offset_force)), "LIMIT": int(bool(cfg.limit)),
             "OFF_MODE0": 0}
    sizes, fields, src = [f"#define CR_N {len(cr_taus)}"], [], []
    src.append("".join(f"#define {k} {_num(v)}\n" for k, v in consts.items()))
    if cr_taus:
        fields.append(f"    double cr_y[{2 * len(cr_taus)}];  /* creep member: LP_tau[Q], LP_tau[V_p] per lag */")
        src.append(_table("CR_A", [float(np.exp(-float(dt) / t)) for t in cr_taus]) + _table("CR_BETA", cr_beta)
                   + f"#define CR_KAPPA {_num(cr['kappa'])}\n")
    src.append("".join(f"#define {k} {v}\n" for k, v in flags.items()) + "#define OFF0 0.0\n")
    H = h["H"]
    parts = []
    if H in ("LP", "DUHEM"):
        nr = len(h["relax_g"])
        sizes.append(f"#define N_RELAX {nr}")
        fields.append(f"    double rz[{max(nr, 1)}];")
        src.append(_table("RELAX_G", h["relax_g"]) + _table("RELAX_W", h["relax_w"]))
        src.append(f"#define Q_LO {_num(h['q_lo'])}\n#define Q_SPAN {_num(h['q_span'])}\n#define H_CONST {_num(h['const'])}\n")
        parts.append(_RELAX)
    if H == "LP":
        src.append(f"#define H_LIN {_num(h['lin'])}\n")
        np_ = len(h["play_r"])
        if np_:
            sizes.append(f"#define N_PLAY {np_}")
            fields.append(f"    double pz[{max(np_, 1)}];")
            src.append(_table("PLAY_R", h["play_r"]) + _table("PLAY_W", h["play_w"]))
            parts.append(_PLAY)
        if h["basis"] == "preisach":
            n = int(h["grid_n"])
            nc = n * (n + 1) // 2
            ci = [i for i in range(n) for _ in range(i + 1)]
            cj = [j for i in range(n) for j in range(i + 1)]
            sizes += [f"#define GRID_N {n}", f"#define GRID_NC {nc}", "#define GRID_STACK 4096"]
            fields += ["    double gMs[GRID_STACK], gms[GRID_STACK], gF[GRID_NC], gprev, gcount, gy;",
                       "    int gK, gstarted, gnd, glist[GRID_NC];", "    unsigned char gdirty[GRID_NC];"]
            src.append(_table("GRID_W", h["grid_w"]))
            src.append(f"static const int GRID_CI[{nc}] = {{{', '.join(map(str, ci))}}};\n"
                       f"static const int GRID_CJ[{nc}] = {{{', '.join(map(str, cj))}}};\n")
            parts.append(_GRID)
        if h["basis"] == "ri":
            sizes.append(f"#define RI_DEPTH {int(h['ri_depth'])}")
            fields += ["    double rE[RI_DEPTH], rP[RI_DEPTH], ru_prev;", "    int rL;"]
            src.append(_table("RI_B", h["ri_b"]) + _table("RI_P", h["ri_p"]))
            parts.append(_RI)
        nr = len(h.get("rev_w", []))
        if nr:   # the Preisach model's reversible part: ramps at the knots i / n_rev (no state)
            sizes.append(f"#define N_REV {nr}")
            src.append(_table("REV_K", h["rev_k"]) + _table("REV_W", h["rev_w"]))
            parts.append(_REV)
        basis = {"none": "0.0", "play": "play_step(s, u)",
                 "preisach": "gy" + (" + play_step(s, u)" if np_ else "") + (" + rev_sum(u)" if nr else ""),
                 "ri": "ry"}[h["basis"]]
        init = ["int i;", "for (i = 0; i < N_RELAX; i++) s->rz[i] = 0.0;"]
        pre = []
        if np_:
            init.append("for (i = 0; i < N_PLAY; i++) s->pz[i] = 0.0;")
        if h["basis"] == "preisach":
            init.append("for (i = 0; i < GRID_NC; i++) { s->gF[i] = 0.0; s->gdirty[i] = 0; }")
            init.append("s->gK = 0; s->gstarted = 0; s->gnd = 0; s->gprev = 0.0; s->gcount = 0.0; s->gy = 0.0;")
            pre.append("double gy; int st = grid_step(s, u, &gy); if (st != SS_OK) return st;")
        if h["basis"] == "ri":
            init.append("s->rL = 1; s->rE[0] = 0.0; s->rP[0] = 0.0; s->ru_prev = 0.0;")
            pre.append("double ry; int st = ri_step(s, u > 0.0 ? u : 0.0, &ry); if (st != SS_OK) return st;")
        body = (f"    double u = (q - Q_LO) / Q_SPAN;\n    {' '.join(pre)}\n"
                f"    double y = ({basis}) + H_LIN * u;\n    y = y + relax_step(s, u);\n    *vh = y + H_CONST;\n"
                "    return SS_OK;\n")
    elif H == "DUHEM":
        nb = (h["deg"] + 1) * (h["deg"] + 2) // 2
        src.append(_table("D_COEF", h["coef"]))
        src.append("".join(f"#define {k} {v}\n" for k, v in (
            ("D_DEG", int(h["deg"])), ("D_NB", nb), ("D_VLO", _num(h["v_lo"])), ("D_VSPAN", _num(h["v_span"])),
            ("D_EPS", _num(h["eps"])), ("D_VMIN", _num(h["v_min"])), ("D_VMAX", _num(h["v_max"])))))
        fields += ["    double dval, dext, dup;", "    int ddir, dstarted;"]
        parts.append(_DUHEM)
        init = ["int i;", "for (i = 0; i < N_RELAX; i++) s->rz[i] = 0.0;",
                "s->dval = 0.0; s->dext = 0.0; s->dup = 0.0; s->ddir = 1; s->dstarted = 0;"]
        src.append(f"#define H_LIN {_num(h['lin'])}\n")
        body = ("    double u = (q - Q_LO) / Q_SPAN, y;\n    duhem_step(s, u, &y);\n    y = y + relax_step(s, u);\n"
                "    *vh = y + H_CONST + H_LIN * u;\n    return SS_OK;\n")
    elif H == "MPI":
        nH, nC, nSp, nSn = len(h["rH"]), len(h["rC"]), len(h["rSp"]), len(h["rSn"])
        sizes += [f"#define N_H {nH}", f"#define N_C {nC}", f"#define N_SP {nSp}", f"#define N_SN {nSn}"]
        fields += [f"    double mp[{max(nH, 1)}], mc[{max(nC, 1)}], mxl;", "    int mhave;"]
        for k in ("rH", "wH", "zH0", "rC", "wC", "gC", "cC0", "rSp", "wSp", "rSn", "wSn"):
            src.append(_table("MPI_" + k.upper(), h[k]))
        src.append(f"#define MPI_OFFSET {_num(h['offset'])}\n#define MPI_W0 {_num(h['w0'])}\n"
                   f"#define H_SIGN {_num(h['sign'])}\n#define H_GAUGE_C {_num(h['gauge_c'])}\n")
        parts.append(_MPI)
        init = ["int i;", "for (i = 0; i < N_H; i++) s->mp[i] = MPI_ZH0[i];",
                "for (i = 0; i < N_C; i++) s->mc[i] = MPI_CC0[i];", "s->mhave = 0; s->mxl = 0.0;"]
        body = "    *vh = H_SIGN * (mpi_step(s, q) - H_GAUGE_C * q);\n    return SS_OK;\n"
    else:  # RIC: RI (+ Kuhnen creep bank + linear) on the input scale of the RI model
        sizes.append(f"#define RI_DEPTH {int(h['ri_depth'])}")
        fields += ["    double rE[RI_DEPTH], rP[RI_DEPTH], ru_prev;", "    int rL;"]
        src.append(_table("RI_B", h["ri_b"]) + _table("RI_P", h["ri_p"]))
        src.append(f"#define RI_SCALE {_num(h['ri_scale'])}\n#define RI_OFFSET {_num(h['ri_offset'])}\n"
                   f"#define H_LIN {_num(h['lin'])}\n#define H_SIGN {_num(h['sign'])}\n"
                   f"#define H_GAUGE_C {_num(h['gauge_c'])}\n")
        parts.append(_RI)
        init = ["s->rL = 1; s->rE[0] = 0.0; s->rP[0] = 0.0; s->ru_prev = 0.0;"]
        kc = ""
        if len(h["rK"]):
            nK, mK = int(h["nK"]), int(h["mK"])
            sizes += [f"#define N_K {nK}", f"#define M_K {mK}"]
            fields += [f"    double kc[{nK * mK}], kxl;", "    int khave;"]
            src.append(_table("RK_R", h["rK"]) + _table("RK_G", h["gK"]) + _table("RK_W", h["wK"]))
            parts.append(_KCREEP)
            init = ["int i;", *init, "for (i = 0; i < N_K * M_K; i++) s->kc[i] = 0.0;", "s->khave = 0; s->kxl = 0.0;"]
            kc = " + kcreep_step(s, q)"
        body = ("    double x = q > 0.0 ? q : 0.0, y;\n    int st = ri_step(s, (x - RI_OFFSET) / RI_SCALE, &y);\n"
                "    if (st != SS_OK) return st;\n"
                f"    y = y{kc};\n    y = y + H_LIN * q;\n    *vh = H_SIGN * (y - H_GAUGE_C * q);\n    return SS_OK;\n")
    h_code = ("static void h_init(ss_state *s)\n{\n    " + "\n    ".join(init) + "\n}\n\n"
              "static int h_step(ss_state *s, double q, double *vh)\n{\n" + body + "}\n")
    guard = name.upper() + "_H"
    header = _HEADER.format(name=name, version=version(), model=model_label or H, dt=_num(dt), guard=guard,
                            sizes="\n".join(sizes), fields="\n".join(fields) + ("\n" if fields else ""))
    source = (f"/* {name}.c: generated by selfsense export-c (see {name}.h). */\n#include <math.h>\n"
              f"#include \"{name}.h\"\n\n" + "".join(src) + "".join(parts) + "\n" + h_code + _FRONT_BACK)
    return header, source


def export_c(model_json: str | Path, rig: Any, out_dir: str | Path, dt: float | None = None,
             name: str = "selfsense_estimator") -> tuple[Path, Path]:
    """Write ``<name>.h`` and ``<name>.c`` for the fitted model in ``model_json`` (``results/<d>/model/sensing.json``)
    with the rig (a ``Rig``, a rig.yaml mapping or a dataset directory) at sample period ``dt`` [s] (default: the
    model's calibration sample time). A file that is not a model the C code can carry raises :class:`ExportError`
    naming it."""
    from selfsense import io as sio
    from selfsense.sensing.estimator import SelfSensingEstimator

    path = Path(model_json)
    if isinstance(rig, (str, Path)):
        rig = sio.load_rig(rig)
    try:
        d = json.loads(path.read_text())
        if not isinstance(d, Mapping):
            raise ExportError("expected a JSON object")
        est = SelfSensingEstimator.from_dict(d, rig)
        if est.hysteresis_ is None or not est.coef_:
            raise ExportError("the model is not fitted (no hysteresis or coef)")
        if dt is None:
            h = est.hysteresis_
            dt = float(getattr(h, "dt_", None) or getattr(getattr(h, "inner", None), "dt", None)
                       or getattr(h, "dt", None) or float("nan"))
        header, source = c_sources(est, rig, float(dt), name, model_label=_label(est.hysteresis_))
    except ExportError as exc:
        raise ExportError(f"{path}: {exc}") from None
    except KeyError as exc:
        raise ExportError(f"{path}: missing key {exc}") from None
    except (TypeError, ValueError, AttributeError, IndexError) as exc:
        raise ExportError(f"{path}: not a model export-c can carry ({exc})") from None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ph, pc = out / f"{name}.h", out / f"{name}.c"
    sio.write_text_atomic(header, ph)
    sio.write_text_atomic(source, pc)
    return ph, pc


def _label(h) -> str:
    return h.label() if hasattr(h, "label") else type(h).__name__
