"""The voltage link of the stage chain: u_cmd -> V (thesis ``000_18d138f03f1777c3.txt`` eq. 56) and its amplifier
member.

The pipeline takes the actuator voltage as ``V = V_c - V_s`` with ``V_c = amplifier_gain * u_cmd`` (eq. 56): the HV
amplifier is assumed to follow its command. An amplifier at its **current limit** does not: it delivers a fixed
current ``I_lim`` and its output voltage is whatever the actuator makes of that charge, so ``V`` lags the command
(tens of volts on a fast drive) while the logged ``V = gain u_cmd - V_s`` still shows the command. The charge stays
right (the shunt measures the current the amplifier delivers).

What the run-time signals show (no reference is read):

* **the limit**: while limited, the shunt current sits on a plateau ``|i| = I_lim`` (flat to the in-amp noise);
  without a limit ``|i|`` only touches its largest values at the peaks of ``C dV/dt``. A command ramp of constant
  slope into a nearly linear capacitance also gives a flat current, but there the actuator follows the command; at
  the limit the command runs ahead of the actuator in the direction of the current. :func:`identify_current_limit`
  takes the plateau over the relay-open samples of every trial and calls the limit *supported* when it holds at
  least :data:`PLATEAU_MIN_FRACTION` of them in runs of at least :data:`RUN_MIN_S` and the command leads the
  actuator voltage rebuilt without H (``V`` linear in ``q`` between anchors) by a median of at least
  :data:`LAG_MIN` of the trial's voltage span over the plateau samples;
* **where V is still known** (*anchors*): every sample off the plateau (the amplifier regulates, ``V = gain u_cmd -
  V_s``), and the instants where the limited current reverses sign: the current reverses when the command crosses
  the actuator voltage (``V_c - V = R i`` changes sign), taken at the middle of the sample interval of the reversal;
* **what V does between anchors**: the Goldfarb-Celanovic actuator (thesis eqs. 24-27) splits
  ``V = V_p + H(q)``. ``V_p`` is the voltage of the linear piezo element and the mechanism is linear at a given tip
  load, so ``V_p`` is affine in the charge while the load does not change; the hysteretic part is the calibrated
  ``H(q)``. Between two anchors :func:`rebuild_voltage` therefore interpolates ``V - H(q)`` linearly in ``q`` and
  adds ``H(q)`` back (with ``H = 0``: ``V`` linear in ``q``, a constant incremental capacitance).

The **slew member** (:func:`identify_slew`): an amplifier at its slew limit ``S`` [V/s] delivers
``V_c = rate_limit(gain u_cmd, S)`` (``V_c,k = V_c,k-1 + clip(gain u_k - V_c,k-1, -S dt, S dt)``), so that on fast command
edges the actuator lags the command by tens of volts and catches up on the hold after the edge, while the logged
``V = gain u_cmd - V_s`` shows the command. The rate is a property of the amplifier, the same in every trial, and the
correction is causal (a stream and the C export carry one state, the delivered command). ``S`` is identified from
the V-Q rows alone (no validation reference is read): the calibration rows of the joint H(q) fit and the rows of every other
free-tip trial (``V - slope Q`` against ``Q``), on which the reference Preisach model (the charge link's) fits best
at the true rate, because only then is the V-Q relation a rate-independent loop again. Candidates are quantiles of
the command's own rate (:data:`SLEW_QUANTILES`); where the two fastest lower the in-sample error by
:data:`SLEW_PROBE_GAIN` the best candidate is refined by a bounded search, and the member is supported where the
rows' blocked-CV error with it is at most :data:`SLEW_CV_RATIO` of the error without it. It is searched only where
the current limit is not supported (a current limit into the actuators' capacitance is a rate limit too, and the
rebuild above follows the actuator closer); the two are never applied together.

The **lag member** (:func:`lag_column`): an HV amplifier of finite bandwidth (a first-order lag of time constant
``tau = 1 / (2 pi f_bw)``, 0.03-0.3 ms for 0.5-5 kHz), or a skew between the DAQ's output and input clocks, delivers
``V_c(t) = gain u_cmd(t - tau)`` to first order in ``tau``, i.e. ``V_c = gain u_cmd - tau gain du_cmd/dt``. On an
amplified actuator the tip estimate is a small difference of large voltages (``V_p = V - H(q)``, thesis eq. 27):
on the devices of the tip campaign a voltage error of 3e-4 of the span moves Table 3 by several points, and a lag
of 0.3 ms at a few hertz is that large. ``tau`` is identified **jointly with H(q)**: the column ``gain du_cmd/dt``
(backward difference, 0 at a trial's first sample, so that a stream computes it from the previous sample) joins
the H fit's extra columns, its coefficient is ``tau`` (the H target carries ``+tau gain du/dt`` where the command
leads the actuator); the member is adopted where the calibration separates the column from the hysteresis
(:func:`lag_r2` at most :data:`LAG_MAX_R2`), the column lowers the selected form's blocked-CV error by at least
:data:`LAG_MIN_GAIN` and ``0 < tau <= LAG_MAX_S``, and the chain is then calibrated on ``V - tau gain
du_cmd/dt``. The same correction applies to every trial estimated with the model (batch, stream, C export).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
from numba import njit

from selfsense.signals import kernels
from selfsense.signals.runs import true_runs

__all__ = ["AmplifierLimit", "SlewLimit", "shunt_current", "rate_limit", "slew_candidates", "with_slew",
           "identify_slew", "identify_current_limit", "limited_mask", "rebuild_voltage",
           "lag_column", "lag_r2", "PLATEAU_MIN_FRACTION", "RUN_MIN_S", "LAG_MIN", "LAG_MAX_S", "LAG_MIN_GAIN",
           "LAG_MAX_R2", "SLEW_QUANTILES", "SLEW_TOP_FRACTION", "SLEW_PROBE_GAIN", "SLEW_CV_RATIO"]

#: the current plateau must hold at least this share of the relay-open samples of all trials (effect-free virtual
#: devices: <= 2 % of samples within the band of their largest current, at the peaks of C dV/dt)
PLATEAU_MIN_FRACTION = 0.05
#: ... in runs of at least this duration [s]
RUN_MIN_S = 0.05
#: ... and the command leads the rebuilt actuator voltage by at least this share of the voltage span (median over the
#: plateau samples, signed with the current): 0.08-0.26 with the amplifier limits of the tip campaign's cases, below
#: 0.002 on effect-free devices and on constant-slope command ramps
LAG_MIN = 0.02
#: the lag member's bound [s]: a first-order amplifier lag of 5 ms is a bandwidth of 32 Hz, below any HV amplifier
#: that drives these actuators; a larger coefficient stands in for another misfit
LAG_MAX_S = 5e-3
#: ... and the lag column must lower the selected H(q) form's blocked-CV error by at least this fraction
LAG_MIN_GAIN = 0.02
#: ... and be identifiable: at most this share of its variance over the calibration rows may be what a rate-independent
#: operator with creep (the charge link's reference Preisach model) and the rows' other columns reproduce. On a
#: calibration of sines at one frequency (the thesis protocol) the column is a loop width like the hysteresis' own
#: (measured 0.990-0.997 on eight devices of the thesis protocol, 0.94-0.96 on tip-protocol devices with a mixed and
#: a stepped calibration trial), and the CV on sine folds cannot tell which extrapolates to holds
LAG_MAX_R2 = 0.98
#: the slew member's candidate rates: these quantiles of the command's rate |gain du_cmd/dt| over the relay-open
#: samples of the rows' trials (the slew binds on the samples faster than it; the fastest two are the first look)
SLEW_QUANTILES = (0.999, 0.99, 0.97, 0.93, 0.85, 0.75, 0.6, 0.45, 0.3)
#: ... and this fraction of the fastest command rate, the first candidate (no candidate above it)
SLEW_TOP_FRACTION = 0.9
#: the first look: one of the two fastest candidates lowers the reference model's in-sample error of the rows by at
#: least this fraction, else the search stops (effect-free devices: every candidate raises it, measured 17x at the
#: 0.9 quantile on the effect-free twin of tip case 38, seed 20261224)
SLEW_PROBE_GAIN = 0.01
#: supported where the rows' blocked-CV error with the slew is at most this fraction of the error without it
#: (tip case 38 of seed 20261224, slew 128 V/s: 14.7 -> 1.5 V at the identified 126.7 V/s)
SLEW_CV_RATIO = 0.8
#: band of the plateau: this many in-amp noise standard deviations, at least BAND_REL of the limit
BAND_SIGMA, BAND_REL = 5.0, 0.005


@dataclass
class AmplifierLimit:
    """The current limit seen in the data: ``i_lim`` [A], the plateau band [A], the plateau's share of the relay-open
    samples, the longest plateau run [s] and whether the data support it."""
    i_lim: float = 0.0
    band: float = 0.0
    fraction: float = 0.0
    longest_run_s: float = 0.0
    lag: float = 0.0
    supported: bool = False
    note: str = ""

    def to_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in asdict(self).items()}


@dataclass
class SlewLimit:
    """The slew limit seen in the V-Q rows: ``rate_v_per_s`` (0: none), the rows' reference errors with and without
    it [V] (None: not computed), whether the data support it (:func:`identify_slew`)."""
    rate_v_per_s: float = 0.0
    insample_v_without: float | None = None
    insample_v_with: float | None = None
    cv_rms_v_without: float | None = None
    cv_rms_v_with: float | None = None
    quantile: float | None = None
    supported: bool = False
    note: str = ""

    def to_dict(self) -> dict:
        """The record with plain floats, None where a number was not computed or is not finite (JSON artefacts)."""
        return {k: (float(v) if np.isfinite(v) else None) if isinstance(v, (float, np.floating)) else v
                for k, v in asdict(self).items()}


@njit(cache=True)
def _rate_limit(x, t, rate):
    y = np.empty_like(x)
    if x.shape[0] == 0:
        return y
    prev = x[0]
    y[0] = prev
    for i in range(1, x.shape[0]):
        lim = rate * (t[i] - t[i - 1])
        d = x[i] - prev
        if d > lim:
            prev = prev + lim
        elif d < -lim:
            prev = prev - lim
        else:
            prev = x[i]
        y[i] = prev
    return y


def rate_limit(x, rate: float, t) -> np.ndarray:
    """``x`` followed at most at ``rate`` [unit/s] at the time stamps ``t`` [s] (an amplifier's slew limit): the
    forward recursion ``y_k = y_k-1 + clip(x_k - y_k-1, -rate (t_k - t_k-1), rate (t_k - t_k-1))`` from ``y_0 = x_0``."""
    x = np.ascontiguousarray(x, dtype=float)
    t = np.ascontiguousarray(t, dtype=float)
    if x.shape != t.shape:
        raise ValueError(f"rate_limit: x has {x.shape} samples, t {t.shape}")
    return _rate_limit(x, t, float(rate))


def with_slew(df: pd.DataFrame, amplifier_gain: float, rate: float) -> pd.DataFrame:
    """The trial as the slew member sees it: ``u_cmd`` replaced by the delivered command
    ``rate_limit(gain u_cmd, rate) / gain`` and ``V`` by ``V + gain (u_delivered - u_cmd)`` (eq. 56 with the delivered
    command; ``V_c`` too where the trial has it). ``rate`` <= 0: unchanged."""
    if not rate > 0:
        return df
    g = float(amplifier_gain)
    u = df["u_cmd"].to_numpy(dtype=float)
    vc = rate_limit(g * u, rate, df["t"].to_numpy(dtype=float))
    out = df.copy()
    out["V"] = df["V"].to_numpy(dtype=float) + (vc - g * u)
    out["u_cmd"] = np.where(vc == g * u, u, vc / g)   # the command itself wherever the limit does not bind
    if "V_c" in out:
        out["V_c"] = vc
    return out


def slew_candidates(trials: Mapping[str, pd.DataFrame], amplifier_gain: float) -> np.ndarray:
    """Candidate slew rates [V/s]: :data:`SLEW_TOP_FRACTION` of the fastest ``|gain du_cmd/dt|`` over the relay-open
    samples of ``trials`` and the :data:`SLEW_QUANTILES` of it below that (a drive's edges run at one rate for many
    samples: the top quantiles are that rate), fastest first (empty where no command moves)."""
    r = []
    for df in trials.values():
        rel = df["relay"].to_numpy(dtype=float) >= 0.5
        w = np.abs(lag_column(df, amplifier_gain))
        r.append(w[~rel & (w > 0)])
    r = np.concatenate(r) if r else np.zeros(0)
    if not r.size:
        return r
    top = float(r.max())
    c = np.unique(np.append(np.quantile(r, SLEW_QUANTILES), SLEW_TOP_FRACTION * top))
    return c[c <= SLEW_TOP_FRACTION * top][::-1]


def identify_slew(trials: Mapping[str, pd.DataFrame], amplifier_gain: float,
                  insample: Callable[[Mapping[str, pd.DataFrame]], float],
                  cv: Callable[[Mapping[str, pd.DataFrame]], float]) -> SlewLimit:
    """The amplifier's slew limit from the V-Q rows of ``trials`` (module docstring, the slew member).

    ``insample(trials)`` / ``cv(trials)``: the reference model's in-sample / blocked-CV error [V] of the rows the
    trials give. Returns the evidence with the best rate found (0 where the first look finds none; the caller applies
    it where ``supported``, or where forced)."""
    from scipy.optimize import minimize_scalar

    cands = slew_candidates(trials, amplifier_gain)
    if not cands.size:
        return SlewLimit(note="no command moves: no slew limit")
    at = lambda s: {t: with_slew(df, amplifier_gain, s) for t, df in trials.items()}  # noqa: E731
    e0 = insample(trials)
    errs = {}
    for s in cands[:2]:
        errs[float(s)] = insample(at(s))
    if not min(errs.values()) <= (1.0 - SLEW_PROBE_GAIN) * e0:
        return SlewLimit(insample_v_without=e0, note=(
            f"the fastest command rates ({cands[0]:.4g}, {cands[min(1, len(cands) - 1)]:.4g} V/s) as slew limits do not "
            f"lower the V-Q rows' reference error ({e0:.4g} V) by {SLEW_PROBE_GAIN * 100:g} %: no slew limit"))
    for s in cands[2:]:
        errs[float(s)] = insample(at(s))
    rates = sorted(errs)
    k = int(np.argmin([errs[s] for s in rates]))
    lo, hi = rates[max(k - 1, 0)], rates[min(k + 1, len(rates) - 1)]
    best = rates[k]
    if hi > lo:
        res = minimize_scalar(lambda z: insample(at(float(np.exp(z)))), bounds=(np.log(lo), np.log(hi)),
                              method="bounded", options={"xatol": 1e-3})
        if float(res.fun) < errs[best]:
            best, errs[float(np.exp(res.x))] = float(np.exp(res.x)), float(res.fun)
    rate = float(best)
    c0, c1 = cv(trials), cv(at(rate))
    q = float(np.mean(np.concatenate([np.abs(lag_column(df, amplifier_gain))[df["relay"].to_numpy(dtype=float) < 0.5]
                                      for df in trials.values()]) > rate))
    ok = bool(c1 <= SLEW_CV_RATIO * c0)
    note = (f"slew limit {rate:.4g} V/s (the command is faster on {q * 100:.1f} % of the relay-open samples): the V-Q "
            f"rows' reference error {e0:.4g} -> {errs[best]:.4g} V in sample, blocked CV {c0:.4g} -> {c1:.4g} V"
            + ("" if ok else f" (needs <= {SLEW_CV_RATIO:g}x): not supported"))
    return SlewLimit(rate_v_per_s=rate, insample_v_without=e0, insample_v_with=errs[best], cv_rms_v_without=c0,
                     cv_rms_v_with=c1, quantile=q, supported=ok, note=note)


def shunt_current(df: pd.DataFrame, shunt_resistance_ohm: float) -> np.ndarray:
    """Shunt current ``i = (V_s - offset) / R`` [A] (thesis eq. 57 before the integral; the relay-segment offset of
    :func:`selfsense.signals.prepare_trial`)."""
    off = float(df.attrs.get("v_s_offset_v", 0.0) or 0.0)
    return kernels.shunt_current(df["V_s"].to_numpy(dtype=float), off, float(shunt_resistance_ohm))


def identify_current_limit(trials: Mapping[str, pd.DataFrame], shunt_resistance_ohm: float,
                           amplifier_gain: float) -> AmplifierLimit:
    """The amplifier's current limit from the shunt current of every trial (V_s and the relay only).

    The top level is the 99.9th percentile of ``|i|`` over the relay-open samples; the band is
    :data:`BAND_SIGMA` in-amp noise standard deviations (from the relay segments, where the current is zero), at least
    :data:`BAND_REL` of that level; ``i_lim`` is the median ``|i|`` inside the band. Supported when the band holds at
    least :data:`PLATEAU_MIN_FRACTION` of the relay-open samples and some run of band samples lasts
    :data:`RUN_MIN_S` and the command leads the actuator by :data:`LAG_MIN` of the voltage span (module docstring)."""
    a, sig, runs_s = [], [], []
    for df in trials.values():
        if "V_s" not in df:
            continue
        rel = df["relay"].to_numpy(dtype=float) >= 0.5
        i = shunt_current(df, shunt_resistance_ohm)
        a.append(np.abs(i[~rel]))
        k = int(rel.sum())
        if k >= 20:
            sig.append(float(np.std(i[rel][k // 4:])))
    if not a or not np.concatenate(a).size:
        return AmplifierLimit(note="no relay-open samples with V_s")
    a_all = np.concatenate(a)
    top = float(np.quantile(a_all, 0.999))
    if not top > 0:
        return AmplifierLimit(note="no current")
    sigma = float(np.median(sig)) if sig else 0.0
    band = max(BAND_SIGMA * sigma, BAND_REL * top)
    i_lim = float(np.median(a_all[a_all >= top - band]))
    frac = float(np.mean(a_all >= i_lim - band))
    trial_lim = AmplifierLimit(i_lim=i_lim, band=band, supported=True)
    leads = []
    for df in trials.values():
        if "V_s" not in df:
            continue
        t = df["t"].to_numpy(dtype=float)
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        m = limited_mask(df, shunt_resistance_ohm, i_lim, band)
        starts, ends = true_runs(m)
        runs_s += ((ends - starts) * dt).tolist()
        if "u_cmd" not in df or not m.any():
            continue
        V = df["V"].to_numpy(dtype=float)
        rel = df["relay"].to_numpy(dtype=float) >= 0.5
        span = float(np.ptp(V[~rel])) or 1.0
        lin = rebuild_voltage(df, shunt_resistance_ohm, amplifier_gain, trial_lim)
        leads.append(np.sign(shunt_current(df, shunt_resistance_ohm)[m]) * (V[m] - lin[m]) / span)
    longest = max(runs_s, default=0.0)
    lag = float(np.median(np.concatenate(leads))) if leads else 0.0
    ok = frac >= PLATEAU_MIN_FRACTION and longest >= RUN_MIN_S and lag >= LAG_MIN
    note = (f"current plateau at {i_lim * 1e3:.4g} mA holds {frac * 100:.1f} % of the relay-open samples, longest run "
            f"{longest:.3g} s, command ahead of the actuator by {lag * 100:.1f} % of the voltage span"
            + ("" if ok else f" (needs >= {PLATEAU_MIN_FRACTION * 100:.0f} %, >= {RUN_MIN_S:g} s and "
                             f">= {LAG_MIN * 100:.0f} %): no current limit"))
    return AmplifierLimit(i_lim=i_lim, band=band, fraction=frac, longest_run_s=longest, lag=lag, supported=ok,
                          note=note)


def limited_mask(df: pd.DataFrame, shunt_resistance_ohm: float, i_lim: float, band: float) -> np.ndarray:
    """Relay-open samples whose shunt current sits on the limit plateau ``|i| >= i_lim - band``."""
    rel = df["relay"].to_numpy(dtype=float) >= 0.5
    return (~rel) & (np.abs(shunt_current(df, shunt_resistance_ohm)) >= i_lim - band)


def rebuild_voltage(df: pd.DataFrame, shunt_resistance_ohm: float, amplifier_gain: float, lim: AmplifierLimit,
                    h_of: Callable[[pd.DataFrame], np.ndarray] | None = None) -> np.ndarray:
    """Actuator voltage of one prepared trial with the current-limited samples rebuilt (module docstring).

    Off the plateau ``V`` is the logged eq. (56) value. At a reversal of the limited current (``+I_lim`` to ``-I_lim``
    between two samples) the command crosses the actuator voltage: the anchor is ``amplifier_gain * u_cmd`` and the
    charge at the middle of the interval. Between anchors ``V - H(q)`` is linear in ``q``; before the first or after
    the last anchor of a trial it continues with the median slope of the trial's bridged runs. ``h_of(df)``: the
    calibrated ``H(q)`` on the trial's samples (None: 0)."""
    V = df["V"].to_numpy(dtype=float).copy()
    if not lim.supported and not lim.i_lim > 0:
        return V
    q = df["q"].to_numpy(dtype=float)
    n = len(V)
    L = limited_mask(df, shunt_resistance_ohm, lim.i_lim, lim.band)
    if not L.any():
        return V
    H = np.zeros(n) if h_of is None else np.asarray(h_of(df), dtype=float)
    u = df["u_cmd"].to_numpy(dtype=float) * float(amplifier_gain)
    i = shunt_current(df, shunt_resistance_ohm)
    s = np.sign(i) * L
    # anchors, in sample order: position in samples, charge, V - H (every sample off the plateau, then every
    # reversal of the limited current at the middle of its interval)
    off = np.flatnonzero(~L)
    rev = np.flatnonzero(L[:-1] & L[1:] & (s[:-1] * s[1:] < 0))
    pos = np.concatenate([off.astype(float), rev + 0.5])
    qa = np.concatenate([q[off], 0.5 * (q[rev] + q[rev + 1])])
    wa = np.concatenate([V[off] - H[off], 0.5 * (u[rev] + u[rev + 1]) - 0.5 * (H[rev] + H[rev + 1])])
    order = np.argsort(pos, kind="stable")
    pos, qa, wa = pos[order], qa[order], wa[order]
    W = V - H
    idx = np.flatnonzero(L)
    j = np.searchsorted(pos, idx)           # anchors left (j-1) and right (j) of each limited sample
    inner = (j > 0) & (j < len(pos))
    slopes = []
    if inner.any():
        lo, hi = j[inner] - 1, j[inner]
        dq = qa[hi] - qa[lo]
        ok = np.abs(dq) > 0
        sl = np.where(ok, (wa[hi] - wa[lo]) / np.where(ok, dq, 1.0), 0.0)
        k_in = idx[inner]
        W[k_in] = np.where(ok, wa[lo] + sl * (q[k_in] - qa[lo]), wa[lo])
        slopes = np.unique(sl[ok])
    s_med = float(np.median(slopes)) if len(slopes) else 0.0
    for m, ref in ((j == 0, 0), (j == len(pos), len(pos) - 1)):   # before the first / after the last anchor
        if m.any() and len(pos):
            k = idx[m]
            W[k] = wa[ref] + s_med * (q[k] - qa[ref])
    return W + H


def lag_column(df: pd.DataFrame, amplifier_gain: float) -> np.ndarray:
    """``gain du_cmd/dt`` [V/s] of one trial (module docstring, the lag member): the backward difference of the
    command over the sample interval of the time stamps, 0 at the first sample. The member's voltage is
    ``V - tau * lag_column``."""
    u = df["u_cmd"].to_numpy(dtype=float) * float(amplifier_gain)
    t = df["t"].to_numpy(dtype=float)
    out = np.zeros(len(u))
    if len(u) > 1:
        dt = np.diff(t)
        out[1:] = np.where(dt > 0, np.diff(u) / np.where(dt > 0, dt, 1.0), 0.0)
    return out


def lag_r2(design: np.ndarray, column: np.ndarray) -> float:
    """Share of the variance of the lag column (rows of :func:`lag_column`) that the columns of ``design`` (a
    rate-independent operator's design with the rows' other columns) reproduce by least squares: near 1 where the
    calibration cannot tell a lag from hysteresis (:data:`LAG_MAX_R2`)."""
    w = np.asarray(column, dtype=float)
    ss = float(np.sum((w - w.mean()) ** 2))
    if not ss > 0:
        return 1.0
    b, *_ = np.linalg.lstsq(design, w, rcond=None)
    return float(1.0 - np.sum((w - design @ b) ** 2) / ss)
