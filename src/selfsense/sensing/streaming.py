"""Streaming (sample-by-sample or block) self-sensing estimator with all state carried.

The batch pipeline is ``selfsense.stages.ingest`` (raw log -> SI signals, ``V``, ``q``) followed by
``SelfSensingEstimator.estimate``. :class:`SelfSensingStream` reproduces it on raw DAQ samples
(``u_cmd`` [V], ``v_shunt`` [V], ``relay`` 0/1, ``t`` [s]) one sample or one block at a time, in one fused numba
loop per sample:

1. SI conversion (docs/data_format.md): ``V_c = amplifier_gain * u_cmd``, ``V_s = v_shunt / inamp_gain``;
   actuator voltage ``V = V_c - V_s`` (``000_18d138f03f1777c3.txt`` eq. (56)).
2. Charge ``Q = (1/R) int (V_s - offset) dt`` (eq. (57)), trapezoidal rule, reset to 0 while ``relay == 1``,
   written exactly as ``selfsense.signals.charge_from_shunt`` does it: a running cumulative sum ``c`` of the
   increments ``0.5 * (i_k + i_{k-1}) * (t_k - t_{k-1})`` (zero on shorted samples) minus its value at the last
   shorted sample, so that the charge is bit-identical to the batch ``np.cumsum`` formulation. The in-amp offset
   is the mean of ``V_s`` over the FIRST shorted (relay) segment; it is known exactly when that segment ends,
   which is before it is first needed (charge is 0 on shorted samples), so streaming loses nothing -- provided
   the log starts with its relay segment (otherwise pass ``offset=<volts>``).
3. ``V_H = H(Q) = sign * (G[Q] - c Q)`` with ``G`` the modified Prandtl-Ishlinskii operator with creep, eq. (42)
   (play eqs. 29-31, creep eqs. 38-39 with ``g = 1 - exp(-a T_s)``, superposition eq. 33), same recursion as
   ``selfsense.hysteresis._kernels.gamma_kernel`` (state: play states, creep states, previous input), and the
   estimator's gauge (``GaugedH``: ``sign``, ``c``; 1 and 0 for a bare ``ModifiedPI``).
4. ``V_p = V - V_H`` (eq. 27); ``dx_raw = A1 Q + A2 V_p``, ``f_raw = B21 Q + B22 V_p`` (eq. 52), 0 while shorted.
   Steps 2 and 4 call the scalar kernels of ``selfsense.sensing.core`` (inlined), the definitions the batch
   estimator and ``charge_from_shunt`` evaluate on arrays.
5. Post-processing (thesis sec. 5.2, Fig. 24): sliding DC offset on dx (and on f if configured) that resets to the
   current value whenever ``|u_cmd| <= zero_input_v / amplifier_gain``; limiting to the calibrated ranges.

Units: SI (s, V, C, m, N). Supported models: ``h_model = "modified_pi"`` with the thesis' identification and
without drift compensation.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numba import njit

from selfsense.sensing.core import _piezo_voltage, _shunt_current, _tip_linear, _trapezoid_increment

__all__ = ["SelfSensingStream", "StreamError"]

# same fast-math set as selfsense.hysteresis._kernels (reassociation lets LLVM vectorise the operator sums)
_FM = {"reassoc", "nsz", "contract"}
# the streaming kernels: reassociation (vectorised operator sums) but no contraction, see _one
_FM_STREAM = {"reassoc", "nsz"}

# ---- state vector layout (float64) --------------------------------------------------------------------------
_T_LAST, _VS_LAST, _CSUM, _BASE, _NSEEN, _OFF_MODE, _OFF_SUM, _OFF_N, _OFF, _X_LAST, _DX_DC, _F_DC = range(12)
_NS_FIXED = 12
# offset modes
_OFF_WAIT, _OFF_COLLECT, _OFF_FIXED = 0.0, 1.0, 2.0

# ---- parameter vector layout (float64) ----------------------------------------------------------------------
(_P_R, _P_INAMP, _P_GAIN, _P_A1, _P_A2, _P_B21, _P_B22, _P_ZL, _P_DXLO, _P_DXHI, _P_FLO, _P_FHI, _P_DCDX,
 _P_DCF, _P_LIMIT, _P_B, _P_W0, _P_NH, _P_NC, _P_NP, _P_NN, _P_HSIGN, _P_HC) = range(23)
_P_DX0 = 23   # rest closing dx0 [m] of the displacement row (SelfSensingEstimator._rest_offset)
_NP_FIXED = 24

# status codes returned by the kernels
_OK = 0
_ERR_NO_RELAY = 1
_ERR_RELAY_VALUE = 2
_ERR_TIME = 3


class StreamError(ValueError):
    """The samples cannot be processed as a stream (no leading relay segment for the offset, bad relay, time)."""


@njit(inline="always")
def _views(P, S):
    nH = int(P[_P_NH])
    nC = int(P[_P_NC])
    nP = int(P[_P_NP])
    nN = int(P[_P_NN])
    o = _NP_FIXED
    rH = P[o:o + nH]
    wH = P[o + nH:o + 2 * nH]
    o += 2 * nH
    rC = P[o:o + nC]
    wC = P[o + nC:o + 2 * nC]
    gC = P[o + 2 * nC:o + 3 * nC]
    o += 3 * nC
    rSp = P[o:o + nP]
    wSp = P[o + nP:o + 2 * nP]
    o += 2 * nP
    rSn = P[o:o + nN]
    wSn = P[o + nN:o + 2 * nN]
    p = S[_NS_FIXED:_NS_FIXED + nH]
    c = S[_NS_FIXED + nH:_NS_FIXED + nH + nC]
    return rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c


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


@njit(inline="always")
def _gamma_step(P, S, xk, rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c):
    """One sample of the modified PI operator G, eq. (42): play (31), creep (39), superposition (33); the same
    recursion as ``selfsense.hysteresis._kernels.gamma_kernel``. Updates p, c, S[x_last]. Inlined at numba-IR
    level (a real call would pass 14 arrays with reference counting on every sample)."""
    u = P[_P_B]
    for i in range(rH.shape[0]):
        zi = max(xk - rH[i], min(xk + rH[i], p[i]))
        p[i] = zi
        u += wH[i] * zi
    xl = S[_X_LAST]
    if not np.isnan(xl):
        for j in range(rC.shape[0]):
            cj = c[j]
            tt = max(xl - rC[j], min(xl + rC[j], cj))
            cj = cj + gC[j] * (tt - cj)
            c[j] = cj
            u += wC[j] * cj
    else:
        for j in range(rC.shape[0]):
            u += wC[j] * c[j]
    S[_X_LAST] = xk
    g = P[_P_W0] * u
    for i in range(rSp.shape[0]):
        g += wSp[i] * max(u - rSp[i], 0.0)
    for i in range(rSn.shape[0]):
        g += wSn[i] * min(u - rSn[i], 0.0)
    return g


@njit(inline="always")
def _one(P, S, tk, uk, vk, rk, dt, use_t, rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c, aux, k):
    """One sample through the whole chain; returns (status, dx_hat, f_hat). State S, p, c updated in place.

    Compiled with reassociation only (``_FM_STREAM``: lets LLVM vectorise the operator sums) and without FMA
    contraction, so V and the linear combinations round exactly as the NumPy batch code; the charge is computed
    in the strict scalar function ``_charge``."""
    if rk != 0.0 and rk != 1.0:
        return _ERR_RELAY_VALUE, 0.0, 0.0
    shorted = rk == 1.0
    Vs = vk / P[_P_INAMP]
    V = P[_P_GAIN] * uk - Vs
    # --- in-amp offset from the first shorted segment (signals.relay_offset)
    mode = S[_OFF_MODE]
    if mode == _OFF_WAIT:
        if not shorted:
            return _ERR_NO_RELAY, 0.0, 0.0
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
    # --- charge, eq. (57): trapezoid, cumulative sum minus its value at the last reset (signals.charge_from_shunt)
    st, q, csum, base, t_last = _charge(S[_CSUM], S[_BASE], S[_T_LAST], S[_VS_LAST], S[_NSEEN], S[_OFF], P[_P_R],
                                        Vs, shorted, tk, dt, use_t)
    if st != _OK:
        return st, 0.0, 0.0
    S[_CSUM] = csum
    S[_BASE] = base
    S[_T_LAST] = t_last
    S[_VS_LAST] = Vs
    S[_NSEEN] += 1.0
    # --- H(q), eq. (42): fast-math operator step (vectorised sums), as hysteresis._kernels.gamma_kernel
    g = _gamma_step(P, S, q, rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c)
    # gauge of SelfSensingEstimator (GaugedH): H(Q) = sign * (G[Q] - c Q); sign = 1, c = 0 for a bare operator
    VH = P[_P_HSIGN] * (g - P[_P_HC] * q)
    # --- eq. (27) and eq. (52): the kernels of selfsense.sensing.core, as the batch estimator evaluates them
    Vp = _piezo_voltage(V, VH)
    if shorted:
        dxr = 0.0
        fr = 0.0
    else:
        dxr = _tip_linear(q, Vp, P[_P_A1], P[_P_A2], P[_P_DX0])
        fr = _tip_linear(q, Vp, P[_P_B21], P[_P_B22], 0.0)
    # --- sliding DC offset (Fig. 24) and limiting (sec. 5.2)
    dx = dxr
    f = fr
    zero = abs(uk) <= P[_P_ZL]
    if P[_P_DCDX] != 0.0:
        if zero:
            S[_DX_DC] = dxr
        dx = dxr - S[_DX_DC]
    if P[_P_DCF] != 0.0:
        if zero:
            S[_F_DC] = fr
        f = fr - S[_F_DC]
    if P[_P_LIMIT] != 0.0:
        dx = min(max(dx, P[_P_DXLO]), P[_P_DXHI])
        f = min(max(f, P[_P_FLO]), P[_P_FHI])
    if aux.shape[0] > 0:
        aux[k, 0] = q
        aux[k, 1] = V
        aux[k, 2] = VH
        aux[k, 3] = Vp
        aux[k, 4] = dxr
        aux[k, 5] = fr
    return _OK, dx, f


@njit(cache=True, fastmath=_FM_STREAM)
def stream_block_kernel(P, S, t, u, v, relay, dt, use_t, dx_out, f_out, aux):
    """Fused block loop: integrate, H(q), coefficients, post-processing. Returns (status, index of first bad sample).

    P packed parameters, S packed state (updated in place). ``t`` is ignored unless ``use_t``; ``aux`` (N, 6) or
    (0, 6) receives q, V, V_H, V_p, dx_raw, f_raw.
    """
    rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c = _views(P, S)
    for k in range(u.shape[0]):
        tk = t[k] if use_t else 0.0
        st, dx, f = _one(P, S, tk, u[k], v[k], relay[k], dt, use_t, rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c,
                         aux, k)
        if st != _OK:
            return st, k
        dx_out[k] = dx
        f_out[k] = f
    return _OK, u.shape[0]


@njit(cache=True, fastmath=_FM_STREAM)
def stream_step_kernel(P, S, tk, uk, vk, rk, dt, use_t):
    """One sample (same code as the block loop). Returns (status, dx_hat, f_hat)."""
    rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c = _views(P, S)
    aux = np.empty((0, 6))
    return _one(P, S, tk, uk, vk, rk, dt, use_t, rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c, aux, 0)


@njit(cache=True, fastmath=_FM)
def fused_gamma_kernel(x, P, S, out):
    """Modified PI operator alone (eq. 42) on the packed layout; same recursion as ``_kernels.gamma_kernel``.

    Kept for the benchmark (operator throughput of the fused streaming layout vs the hysteresis package kernel).
    """
    rH, wH, rC, wC, gC, rSp, wSp, rSn, wSn, p, c = _views(P, S)
    xl = S[_X_LAST]
    have = not np.isnan(xl)
    nH = rH.shape[0]
    nC = rC.shape[0]
    for k in range(x.shape[0]):
        xk = x[k]
        u = P[_P_B]
        for i in range(nH):
            zi = max(xk - rH[i], min(xk + rH[i], p[i]))
            p[i] = zi
            u += wH[i] * zi
        if have:
            for j in range(nC):
                cj = c[j]
                tt = max(xl - rC[j], min(xl + rC[j], cj))
                cj = cj + gC[j] * (tt - cj)
                c[j] = cj
                u += wC[j] * cj
        else:
            for j in range(nC):
                u += wC[j] * c[j]
            have = True
        xl = xk
        y = P[_P_W0] * u
        for i in range(rSp.shape[0]):
            y += wSp[i] * max(u - rSp[i], 0.0)
        for i in range(rSn.shape[0]):
            y += wSn[i] * min(u - rSn[i], 0.0)
        out[k] = y
    S[_X_LAST] = xl


def _rig_value(rig: Any, key: str) -> float:
    return float(rig[key] if isinstance(rig, Mapping) else getattr(rig, key))


def pack_operator(model) -> tuple[np.ndarray, np.ndarray]:
    """Packed (parameters, initial state) of a ``ModifiedPI`` for :func:`fused_gamma_kernel` (no sensing part)."""
    P, S = _pack(model, {})
    return P, S


def _pack(model, sc: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    m = model
    n, mm = len(m.r_K), len(m.a_K)
    rC = np.repeat(m.r_K, mm)
    wC = np.repeat(m.w_K, mm)
    gC = np.tile(-np.expm1(-m.a_K * m.dt), n)  # 1 - exp(-a T_s), as ModifiedPI._prepare
    r, w = m.r_S, m.w_S
    s0 = float(w[r == 0].sum())
    pos, neg = r > 0, r < 0
    head = np.zeros(_NP_FIXED)
    for key, idx in (("R", _P_R), ("inamp", _P_INAMP), ("gain", _P_GAIN), ("A1", _P_A1), ("A2", _P_A2),
                     ("B21", _P_B21), ("B22", _P_B22), ("zl", _P_ZL), ("dxlo", _P_DXLO), ("dxhi", _P_DXHI),
                     ("flo", _P_FLO), ("fhi", _P_FHI), ("dcdx", _P_DCDX), ("dcf", _P_DCF), ("limit", _P_LIMIT),
                     ("hsign", _P_HSIGN), ("hc", _P_HC), ("dx0", _P_DX0)):
        head[idx] = float(sc.get(key, 1.0 if key in ("R", "inamp", "hsign") else 0.0))
    head[_P_B] = m.offset
    head[_P_W0] = s0
    head[_P_NH], head[_P_NC], head[_P_NP], head[_P_NN] = len(m.r_H), len(rC), int(pos.sum()), int(neg.sum())
    P = np.ascontiguousarray(np.concatenate([head, m.r_H, m.w_H, rC, wC, gC, r[pos], w[pos], r[neg], w[neg]]))
    S = np.zeros(_NS_FIXED + len(m.r_H) + len(rC))
    S[_X_LAST] = np.nan
    S[_NS_FIXED:_NS_FIXED + len(m.r_H)] = m.z_H0
    S[_NS_FIXED + len(m.r_H):] = m.Z_K0.reshape(-1)
    return P, S


_AUX_NAMES = ("q", "V", "V_H", "V_p", "dx_raw", "f_raw")


class SelfSensingStream:
    """Streaming twin of ``stages.ingest`` + ``SelfSensingEstimator.estimate`` on raw DAQ samples.

    Parameters
    ----------
    estimator : a fitted ``SelfSensingEstimator`` (``h_model='modified_pi'``, thesis identification, no drift compensation).
    rig : ``selfsense.io.Rig`` or rig.yaml mapping (default ``estimator.rig``): needs ``shunt_resistance_ohm``,
        ``inamp_gain``, ``amplifier_gain``.
    dt : sample period [s] used when samples come without time stamps (``t=None``).
    offset : ``"relay"`` (default): in-amp offset = mean ``V_s`` of the first shorted segment, which must open
        the stream (as ``charge_from_shunt(offset="relay")``); or a number [V] (``V_s`` units, i.e. after the
        in-amp gain) to subtract from the first sample on.

    ``step(u_cmd, v_shunt, relay=0, t=None) -> (dx_hat [m], f_hat [N])``;
    ``process(u_cmd, v_shunt, relay=None, t=None) -> (dx_hat, f_hat)`` arrays (``full=True``: a dict that also
    holds q, V, V_H, V_p, dx_raw, f_raw). Feeding any split of a log gives the same result as one call.
    """

    def __init__(self, estimator, rig: Any = None, *, dt: float | None = None, offset: str | float = "relay"):
        from selfsense.sensing.estimator import _rig_get

        if estimator.hysteresis_ is None or not estimator.coef_:
            raise ValueError("SelfSensingStream needs a fitted estimator (fit() or from_dict())")
        h = estimator.hysteresis_
        h_sign, h_c = 1.0, 0.0
        if type(h).__name__ == "GaugedH":  # H(Q) = sign * (G[Q] - c Q), selfsense.sensing.estimator.GaugedH
            h, h_sign, h_c = h.inner, float(h.sign), float(h.c)
        if type(h).__name__ != "ModifiedPI":
            raise NotImplementedError(
                f"SelfSensingStream supports h_model='modified_pi' only, got {type(h).__name__}")
        rig = estimator.rig if rig is None else rig
        if rig is None:
            raise ValueError("SelfSensingStream needs the rig (shunt resistance, gains)")
        cfg = estimator.config
        c = estimator.coef_
        gain = _rig_value(rig, "amplifier_gain")
        self.estimator = estimator
        self.rig = rig
        self.dt = None if dt is None else float(dt)
        if self.dt is not None and not self.dt > 0:
            raise ValueError(f"dt must be > 0 s, got {dt!r}")
        if isinstance(offset, str) and offset != "relay":
            raise ValueError(f"offset must be 'relay' or a number [V], got {offset!r}")
        self.offset_arg = offset
        sc = {
            "R": _rig_value(rig, "shunt_resistance_ohm"), "inamp": _rig_value(rig, "inamp_gain"), "gain": gain,
            "A1": c["A1"], "A2": c["A2"], "B21": c["B21"], "B22": c["B22"], "dx0": float(c.get("dx0", 0.0)),
            # exactly the expression of SelfSensingEstimator.estimate
            "zl": cfg.zero_input_v / max(_rig_get(rig, "amplifier_gain"), 1e-12),
            "dxlo": estimator.ranges_["dx"][0], "dxhi": estimator.ranges_["dx"][1],
            "flo": estimator.ranges_["f"][0], "fhi": estimator.ranges_["f"][1],
            "dcdx": float(bool(cfg.dc_offset)), "dcf": float(bool(cfg.dc_offset_force)), "limit": float(bool(cfg.limit)),
            "hsign": h_sign, "hc": h_c,
        }
        if sc["R"] <= 0 or sc["inamp"] <= 0:
            raise ValueError("rig: shunt_resistance_ohm and inamp_gain must be > 0")
        self._P, self._S0 = _pack(h, sc)
        if not isinstance(offset, str):
            self._S0[_OFF_MODE] = _OFF_FIXED
            self._S0[_OFF] = float(offset)
        self.reset()

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_dict(cls, d: Mapping[str, Any], rig: Any, **kw) -> "SelfSensingStream":
        """From ``SelfSensingEstimator.to_dict()`` (the pipeline's model/sensing.json) and the rig."""
        from selfsense.sensing.estimator import SelfSensingEstimator

        return cls(SelfSensingEstimator.from_dict(d, rig), rig, **kw)

    @classmethod
    def from_json(cls, path: str | Path, rig_or_dataset: Any, **kw) -> "SelfSensingStream":
        """From a model JSON file and a rig (``Rig``, mapping, or a dataset directory holding rig.yaml)."""
        rig = rig_or_dataset
        if isinstance(rig, (str, Path)):
            from selfsense import io as sio

            rig = sio.load_rig(rig)
        return cls.from_dict(json.loads(Path(path).read_text()), rig, **kw)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the initial state (no samples seen, operator at its initial states)."""
        self._S = self._S0.copy()

    def get_state(self) -> np.ndarray:
        """Copy of the packed state vector (restore with :meth:`set_state`)."""
        return self._S.copy()

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=np.float64)
        if s.shape != self._S0.shape:
            raise ValueError(f"state must have shape {self._S0.shape}, got {s.shape}")
        self._S = s.copy()

    @property
    def n_samples(self) -> int:
        """Samples processed since the last reset."""
        return int(self._S[_NSEEN])

    @property
    def offset_v(self) -> float:
        """The in-amp offset subtracted from V_s [V] (NaN while still being estimated on the relay segment)."""
        return float(self._S[_OFF]) if self._S[_OFF_MODE] == _OFF_FIXED else float("nan")

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
            st, dx, f = stream_step_kernel(self._P, self._S, 0.0, float(u_cmd), float(v_shunt), float(relay),
                                           self.dt, False)
        else:
            st, dx, f = stream_step_kernel(self._P, self._S, float(t), float(u_cmd), float(v_shunt), float(relay),
                                           0.0, True)
        if st:
            self._raise(st, f"sample {self.n_samples}")
        return dx, f

    def process(self, u_cmd, v_shunt, relay=None, t=None, *, full: bool = False):
        """A block of raw samples (1-D arrays of equal length; relay default 0). Returns (dx_hat, f_hat) arrays,
        or with ``full=True`` a dict with dx_hat, f_hat, q, V, V_H, V_p, dx_raw, f_raw."""
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
        dx = np.empty(n)
        f = np.empty(n)
        aux = np.empty((n, 6)) if full else np.empty((0, 6))
        S = self._S.copy()  # commit the state only if the whole block is valid
        st, k = stream_block_kernel(self._P, S, tt, u, v, r, dt, use_t, dx, f, aux)
        if st:
            self._raise(int(st), f"sample {self.n_samples + int(k)} (block index {int(k)})")
        self._S = S
        if not full:
            return dx, f
        out = {"dx_hat": dx, "f_hat": f}
        for j, name in enumerate(_AUX_NAMES):
            out[name] = aux[:, j].copy()
        return out
