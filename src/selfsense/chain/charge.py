"""The charge link of the stage chain: V_s -> Q (thesis ``000_18d138f03f1777c3.txt`` eq. 57) and its members.

The shunt integrates every current that flows into the actuator node, not only the one that polarises the
actuators. Three members of this link are carried by the estimator (:class:`selfsense.sensing.SelfSensingEstimator`)
and tested by the gap diagnostic (:mod:`selfsense.gap.stages`) through the *same* functions of this module:

* **leakage**: a parallel conductance g [S] (the insulation of the actuator set): the shunt also carries ``g V``, so
  the actuators' charge is ``Q - g int V dt`` (:func:`leak_column`);
* **offset drift**: an in-amp input offset that drifts after the relay opened integrates into the charge as
  ``a t + b t^2`` (the estimator estimates each trial's own from its rests).
* **absorption**: a series R-C branch in parallel with the actuators (dielectric absorption) parks the charge
  ``c LP_tau(V)`` (:func:`absorption_column`), identified on the free-tip calibration laser (:func:`fit_absorption`).

Reference-free evidence (:func:`hold_evidence`). During a hold of the drive (V constant within its noise) the
actuators' charge is constant whatever the tip does (free, blocked or in contact: the force is constant too),
except for the relaxation of the material after the preceding step (electrical creep, dielectric absorption),
which decays. A charge ramp that persists through the hold and scales with the held voltage is leakage; one that
does not scale with V is the offset drift of that trial. Every trial has holds to offer (mixed drives, the 0 V
rests, the relay short), validation trials included: only V, Q and the relay are read, never a reference, so
nothing Table 3 scores is fitted on its own reference.

Per hold window h (the hold after its first 30 %, at least 0.2 s, so that the fast part of the relaxation is gone)
the charge slope s_h [A] is regressed on

    s_h = g V_h + a_k + b_k t_h + sum_j c_j r_j,h

with a_k, b_k the offset-drift charge rate of trial k (its offset voltage over the shunt resistance, linear in
time), and r_j,h the mean rate of a first-order relaxation of V with time constant tau_j (the decaying creep /
absorption current after the steps before the hold). Holds are weighted by their duration. The uncertainty of g is
that of the weighted regression; the evidence is "supported" when g > 0 with g / se >= :data:`Z_SUPPORT` over at
least two trials and two hold levels, the median of the leave-one-trial-out estimates agrees with g within 50 %,
and g moves by at most 25 % (or one standard error) when a slower relaxation (:data:`SLOW_TAU_S`) joins the
regression (over holds short against a relaxation, its current cannot be told from a leakage current).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

__all__ = ["ABSORPTION_MIN_GAIN", "ABSORPTION_OVER_LEAK", "ABSORPTION_TAUS_S", "DITHER_MIN_STEPS", "RELAX_TAUS_S",
           "Z_SUPPORT", "AbsorptionFit", "ChargeResolution", "HoldEvidence", "absorption_column", "charge_resolution",
           "find_holds", "fit_absorption", "hold_evidence", "leak_column", "quantisation_step", "QUANTISER_AT_BOUND",
           "QUANTISER_CV_RATIO", "QUANTISER_FOLD_SPREAD", "QUANTISER_BLOCKS", "QUANTISER_LAGS_S", "QuantiserFit",
           "fit_quantiser", "quantiser_column"]

#: z-score of the hold-estimated leakage conductance above which the holds support the member
Z_SUPPORT = 4.0
#: relaxation time constants [s] of the creep / absorption columns of the hold regression
RELAX_TAUS_S = (0.3, 1.0, 3.0)
#: the slower relaxation added for the identifiability check: g must not depend on it
SLOW_TAU_S = 10.0
#: shortest hold [s] used as evidence
MIN_HOLD_S = 0.5


def leak_column(V: np.ndarray, dt: float) -> np.ndarray:
    """``int_0^t V dtau`` [V s] by the trapezoidal rule of the charge integral (thesis eq. 57): the charge a
    leakage conductance g draws through the shunt is ``g * leak_column(V, dt)``."""
    from selfsense.signals.kernels import trapezoid_increment

    V = np.asarray(V, float)
    if len(V) == 0:
        return np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(trapezoid_increment(V[:-1], V[1:], dt))])


def _lowpass(x: np.ndarray, tau: float, dt: float) -> np.ndarray:
    from selfsense.signals.iir import lfilter

    x = np.asarray(x, float)
    if len(x) == 0:
        return np.zeros(0)
    a = float(np.exp(-dt / tau))
    return lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])[0]  # starts settled at x[0]


def find_holds(t: np.ndarray, V: np.ndarray, min_s: float = MIN_HOLD_S) -> list[tuple[int, int]]:
    """Index ranges ``[a, b)`` where V stays within a band of ``max(0.5 % of its range, 4 noise sd, 20 mV)``
    for at least ``min_s`` seconds (drive holds and rests)."""
    t = np.asarray(t, float)
    V = np.asarray(V, float)
    n = len(V)
    if n < 10:
        return []
    dt = float(np.median(np.diff(t)))
    noise = 1.4826 * float(np.median(np.abs(np.diff(V) - np.median(np.diff(V))))) / np.sqrt(2.0)
    tol = max(0.005 * float(np.ptp(V)), 4.0 * noise, 0.02)
    w = max(2, round(0.05 / dt))
    # stationary where the 50 ms change is inside the band
    d = np.abs(V[w:] - V[:-w]) < tol
    st = np.zeros(n, bool)
    st[:-w] |= d
    st[w:] &= d
    edges = np.flatnonzero(np.diff(np.concatenate([[0], st.astype(int), [0]])))
    out = []
    for a, b in zip(edges[::2], edges[1::2]):
        if (b - a) * dt < min_s:
            continue
        seg = V[a:b]
        if np.ptp(seg) > 4.0 * tol:  # a slow ramp, not a hold
            continue
        out.append((int(a), int(b)))
    return out


@dataclass
class HoldEvidence:
    """Leakage and offset-drift evidence of the holds of every trial (reference-free)."""

    n_holds: int = 0
    n_trials: int = 0
    n_levels: int = 0
    g_s: float = 0.0
    g_se_s: float = float("inf")
    z: float = 0.0
    g_loto_s: list = field(default_factory=list)
    g_slow_s: float = float("nan")
    #: standard error of ``g_slow_s`` (the slow column and g share the holds' ramps: it is wider than ``g_se_s``)
    g_slow_se_s: float = float("inf")
    longest_hold_s: float = 0.0
    #: an ADC step [A] of the shunt channel where the noise does not dither it (0: dithered or not known): the
    #: holds' resolution
    resolution_floor_a: float = 0.0
    #: the leakage current across the hold levels is above that floor (Z_SUPPORT x): the holds resolve g
    resolved: bool = True
    offset_f: float = 0.0
    offset_supported: bool = False
    supported: bool = False
    note: str = ""

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("g_se_s", "g_slow_s", "g_slow_se_s"):
            d[k] = float(d[k]) if np.isfinite(d[k]) else None
        return d


def leakage_upper_bound(ev: Mapping) -> float | None:
    """The largest conductance [S] the holds of every trial leave possible (``ev``: :meth:`HoldEvidence.to_dict`):
    the larger of ``g + Z_SUPPORT se`` and the same with the slow relaxation column (``g_slow + Z_SUPPORT se_slow``,
    so that a relaxation that could hide leakage over holds short against it widens the bound instead of lowering
    it). None where the holds cannot bound it: fewer than 2 trials or 2 voltage levels, no standard error, a shunt
    channel that does not resolve the current (an undithered ADC step, docs/method.md 1b), or an estimate below zero
    by more than ``Z_SUPPORT`` standard errors (a conductance cannot be negative: the holds' model misses what moves
    their charge, a relaxation or an offset, and says nothing about leakage)."""
    def num(k, default):
        v = ev.get(k)
        return default if v is None else float(v)

    g, se = num("g_s", 0.0), num("g_se_s", float("inf"))
    gs, se_s = num("g_slow_s", float("nan")), num("g_slow_se_s", float("inf"))
    if (int(ev.get("n_trials") or 0) < 2 or int(ev.get("n_levels") or 0) < 2 or not ev.get("resolved", True)
            or num("resolution_floor_a", 0.0) > 0.0 or not (np.isfinite(se) and se > 0)):
        return None
    b = [g + Z_SUPPORT * se]
    if np.isfinite(gs):
        if not (np.isfinite(se_s) and se_s > 0):
            return None
        b.append(gs + Z_SUPPORT * se_s)
    return float(max(b)) if min(b) >= 0.0 else None


def _hold_rows(name: str, k: int, t: np.ndarray, V: np.ndarray, Q: np.ndarray) -> list[dict]:
    dt = float(np.median(np.diff(t)))
    lps = [_lowpass(V, tau, dt) for tau in RELAX_TAUS_S + (SLOW_TAU_S,)]
    rows = []
    for a, b in find_holds(t, V):
        a2 = a + max(int(0.3 * (b - a)), round(0.2 / dt))
        if b - a2 < 20:
            continue
        tt = t[a2:b] - t[a2]
        dur = float(tt[-1])
        if dur <= 0:
            continue
        A = np.column_stack([np.ones_like(tt), tt])
        s = float(np.linalg.lstsq(A, Q[a2:b], rcond=None)[0][1])
        relax = [float((lp[b - 1] - lp[a2]) / dur) for lp in lps]
        rows.append({"trial": name, "k": k, "s": s, "V": float(np.mean(V[a2:b])), "t": float(np.mean(t[a2:b])),
                     "w": dur, "relax": relax})
    return rows


def _design(rows: list[dict], trials: list[int], offset: bool, slow: bool = False
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    idx = {k: i for i, k in enumerate(trials)}
    nk = len(trials)
    X, y, w = [], [], []
    for r in rows:
        x = [r["V"]]
        if offset:
            o = np.zeros(2 * nk)
            o[2 * idx[r["k"]]] = 1.0
            o[2 * idx[r["k"]] + 1] = r["t"]
            x.extend(o)
        x.extend(r["relax"] if slow else r["relax"][:-1])
        X.append(x)
        y.append(r["s"])
        w.append(r["w"])
    return np.asarray(X, float), np.asarray(y, float), np.asarray(w, float)


def _wls(X, y, w):
    sw = np.sqrt(w)
    Xs = X * sw[:, None]
    scale = np.linalg.norm(Xs, axis=0)
    scale[scale == 0] = 1.0
    c, *_ = np.linalg.lstsq(Xs / scale, y * sw, rcond=None)
    c = c / scale
    r = (y - X @ c) * sw
    return c, float(r @ r)


#: results kept per memoised function (:func:`_memo_by_content`): each is a small record (KB), not the trials
MEMO_ENTRIES = 8
#: the caches of every memoised function, for :func:`clear_memos`
_MEMO_CACHES: list = []


def clear_memos() -> None:
    """Empty the caches of the memoised functions (:func:`_memo_by_content`). The key holds the inputs and the
    module constants a function reads, not the functions it calls: code that replaces one of those (a test's
    monkeypatch, an interactive session redefining a helper) clears the caches first, or it is served the result
    computed before (the test suite does so before every test, ``tests/conftest.py``)."""
    for c in _MEMO_CACHES:
        c.clear()


def _frames_digest(trials: Mapping[str, pd.DataFrame]) -> str:
    """SHA-256 of the trials as a function of them can see them: in order, each trial's name, and each column's
    name, dtype, shape and bytes (the index is not read by the memoised functions)."""
    import hashlib

    h = hashlib.sha256()
    for name, df in trials.items():
        h.update(repr(("trial", name, len(df))).encode())
        for c in df.columns:
            a = np.ascontiguousarray(df[c].to_numpy())
            h.update(repr((c, a.dtype.str, a.shape)).encode())
            h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())
    return h.hexdigest()


def _memo_by_content(fn):
    """Memoise ``fn(trials, *args, **kwargs)``, a pure function of the trials' columns and the other arguments, on the
    content of the trials (:func:`_frames_digest`), the arguments' repr and the module constants ``fn`` reads: the gap
    diagnostic's recalibrations that change a member but not the inputs fit the same trials again in one process
    (measured on tweezer_sim: 5 of its 8 recalibrations). At most :data:`MEMO_ENTRIES`
    results, the oldest dropped first; each call gets its own deep copy, so a caller that changes its result cannot
    change another's."""
    import copy
    import functools
    from collections import OrderedDict

    cache: OrderedDict = OrderedDict()

    def names(code) -> set:
        out = set(code.co_names)
        for c in code.co_consts:
            if hasattr(c, "co_names"):
                out |= names(c)
        return out

    # the module's constants the function reads at call time (thresholds such as Z_SUPPORT) join the key
    consts = sorted(n for n in names(fn.__code__) if n.isupper() and n in fn.__globals__)

    @functools.wraps(fn)
    def wrapper(trials, *args, **kwargs):
        key = (_frames_digest(trials), repr(args), repr(sorted(kwargs.items())),
               repr([(n, fn.__globals__[n]) for n in consts]))
        if key in cache:
            cache.move_to_end(key)
        else:
            cache[key] = fn(trials, *args, **kwargs)
            while len(cache) > MEMO_ENTRIES:
                cache.popitem(last=False)
        return copy.deepcopy(cache[key])

    wrapper.cache = cache
    _MEMO_CACHES.append(cache)
    return wrapper


@_memo_by_content
def hold_evidence(trials: Mapping[str, pd.DataFrame], R: float | None = None) -> HoldEvidence:
    """Leakage conductance g [S] and offset-drift evidence from the holds of every trial (module docstring).

    ``trials``: trial id -> prepared frame with ``t``, ``V``, ``q`` and ``relay`` (and ``V_s``, read with the shunt
    resistance ``R`` [ohm] for the resolution of the channel; other columns are not read). Where the shunt channel
    is not dithered in a trial (:func:`charge_resolution`), a hold's charge slope is off by up to half an ADC step
    whatever its length, and the difference of two holds' by up to a whole step: the evidence is supported only if
    the leakage current across the hold levels, ``g`` times their voltage span, is at least :data:`Z_SUPPORT` ADC
    steps (``step / R``). (Measured on a clean 13-bit whole-device Preisach device: holds at 0 and 148 V gave
    g = 7.3 nS with z >> 4, 1.4 steps across the levels, from quantisation and relaxation currents the channel
    does not resolve.)
    """
    rows = []
    for k, (name, df) in enumerate(trials.items()):
        relay = df["relay"].to_numpy(float) >= 0.5
        on = np.flatnonzero(relay)
        a = int(on[-1] + 1) if len(on) else 0
        t = df["t"].to_numpy(float)[a:]
        if len(t) < 50:
            continue
        rows.extend(_hold_rows(str(name), k, t, df["V"].to_numpy(float)[a:], df["q"].to_numpy(float)[a:]))
    ev = HoldEvidence(n_holds=len(rows))
    if R:
        for df in trials.values():
            if "V_s" in df:
                res, _ = charge_resolution(df, R)
                if not res.dithered and res.current_step_a > 0:
                    ev.resolution_floor_a = max(ev.resolution_floor_a, res.current_step_a)
    if not rows:
        ev.note = "no hold of at least 0.5 s in any trial: leakage cannot be seen without a hold"
        return ev
    ks = sorted({r["k"] for r in rows})
    vr = np.array([r["V"] for r in rows])
    vspan = float(np.ptp(vr))
    ev.n_trials = len(ks)
    ev.n_levels = len(np.unique(np.round(vr / max(0.05 * (np.max(np.abs(vr)) or 1.0), 1e-9))))
    # trials with a single hold cannot separate their offset rate from g V: they enter only through g
    per = {k: sum(r["k"] == k for r in rows) for k in ks}
    use = [r for r in rows if per[r["k"]] >= 3]
    kk = sorted({r["k"] for r in use})
    if len(use) < 6 or len(kk) < 1 or vspan <= 0:
        ev.note = (f"{len(rows)} holds in {len(ks)} trials, too few (need >= 3 holds at two levels in a trial) "
                   "to separate leakage from the offset drift")
        return ev
    X, y, w = _design(use, kk, True)
    c, rss = _wls(X, y, w)
    ev.g_s = float(c[0])
    X0, y0, w0 = _design(use, kk, False)
    _, rss0 = _wls(X0, y0, w0)
    dof = max(len(y) - X.shape[1], 1)
    ev.offset_f = float(((rss0 - rss) / max(2 * len(kk), 1)) / max(rss / dof, 1e-300))
    from scipy.special import fdtri   # the F quantile (scipy.stats.f.ppf's own; scipy.stats costs ~0.8 s to import)

    ev.offset_supported = bool(dof >= 3 and ev.offset_f > fdtri(2 * len(kk), dof, 0.999))
    if len(kk) >= 2:
        loto = []
        for k in kk:
            sub = [r for r in use if r["k"] != k]
            ks2 = sorted({r["k"] for r in sub})
            Xs, ys, ws = _design(sub, ks2, True)
            if len(ys) <= Xs.shape[1]:
                continue
            loto.append(float(_wls(Xs, ys, ws)[0][0]))
        ev.g_loto_s = loto
        # standard error of g from the weighted residuals (holds of one trial share its offset columns, so the
        # residuals are close to independent between holds); the leave-one-trial-out estimates must agree with g
        # (their median within 50 %): no single trial may carry the evidence
        XtWX = (X * w[:, None]).T @ X
        cov = np.linalg.pinv(XtWX) * rss / dof
        ev.g_se_s = float(np.sqrt(max(cov[0, 0], 0.0)))
        ev.z = float(ev.g_s / ev.g_se_s) if ev.g_se_s > 0 else float("inf")
        loto_ok = bool(len(loto) >= 2 and abs(float(np.median(loto)) - ev.g_s) <= 0.5 * abs(ev.g_s))
    else:
        loto_ok = False
    # identifiability: over holds short against a relaxation, a slow relaxation current is indistinguishable from
    # a leakage current; g must not move when a slower relaxation column is added
    Xs_, ys_, ws_ = _design(use, kk, True, slow=True)
    if len(ys_) > Xs_.shape[1]:
        cs_, rss_s = _wls(Xs_, ys_, ws_)
        ev.g_slow_s = float(cs_[0])
        if len(kk) >= 2:
            # on the columns scaled to unit norm (the slow column and the offset ramps are nearly collinear over
            # short holds: unscaled, pinv's cut-off drops the direction that carries g's variance)
            Z_ = Xs_ * np.sqrt(ws_)[:, None]
            sc_ = np.linalg.norm(Z_, axis=0)
            sc_[sc_ == 0] = 1.0
            cov_s = np.linalg.pinv((Z_ / sc_).T @ (Z_ / sc_)) * rss_s / max(len(ys_) - Xs_.shape[1], 1)
            ev.g_slow_se_s = float(np.sqrt(max(cov_s[0, 0], 0.0))) / float(sc_[0])
    stable = bool(np.isfinite(ev.g_slow_s) and abs(ev.g_slow_s - ev.g_s) <= max(0.25 * abs(ev.g_s), ev.g_se_s))
    ev.longest_hold_s = float(max(r["w"] for r in rows) / 0.7)
    resolved = bool(ev.resolution_floor_a == 0.0 or abs(ev.g_s) * vspan >= Z_SUPPORT * ev.resolution_floor_a)
    ev.resolved = resolved
    ev.supported = bool(ev.g_s > 0 and ev.z >= Z_SUPPORT and len(kk) >= 2 and ev.n_levels >= 2 and stable
                        and loto_ok and resolved)
    why = []
    if not resolved:
        why.append(f"a leakage current the shunt channel resolves: g x {vspan:.3g} V of hold levels = "
                   f"{abs(ev.g_s) * vspan * 1e9:.3g} nA against {Z_SUPPORT:g} x {ev.resolution_floor_a * 1e9:.3g} nA, "
                   f"an ADC step that the noise does not dither (docs/method.md 1b)")
    if not (ev.g_s > 0 and ev.z >= Z_SUPPORT):
        why.append(f"g > 0 with z >= {Z_SUPPORT:g} (z = {ev.z:.2f})")
    if len(kk) < 2 or ev.n_levels < 2:
        why.append(">= 2 trials with holds at >= 2 voltage levels")
    elif not loto_ok:
        why.append("leave-one-trial-out estimates of g whose median agrees with g within 50 %")
    if not stable:
        why.append(f"g independent of a {SLOW_TAU_S:g} s relaxation ({ev.g_slow_s * 1e9:.3g} nS with it); holds of "
                   f"~{ev.longest_hold_s:.1g} s are short against it: holds of >= {3 * SLOW_TAU_S:g} s at two "
                   "voltage levels would separate leakage from slow relaxation")
    ev.note = (f"{len(use)} holds in {len(kk)} trials: g = {ev.g_s * 1e9:.3g} nS, z = {ev.z:.2f}: "
               + ("supported" if ev.supported else "not supported; needs " + "; ".join(why)))
    return ev


# ------------------------------------------------------------------------------------------------ offset drift
#: interior knots of the wandering-offset candidates (cubic-in-charge B-spline families, see :func:`offset_bases`)
WANDER_KNOTS = (2, 4, 8)
#: a wandering form replaces the thermal ramp only if its held-out rest error is this much lower
WANDER_GAIN = 0.9


def offset_bases(tt: np.ndarray, dur: float) -> dict[str, np.ndarray]:
    """Candidate forms of the charge an in-amp offset integrates after the relay opened (``tt`` [s] since then):

    * ``ramp``: ``a t + b t^2``, a constant plus a linearly drifting offset (a thermal ramp);
    * ``wander<k>``: an offset that wanders, piecewise linear in time over ``k`` interior knots spread evenly over
      the trial (hat functions), integrated into charge (so the charge drift is C1, piecewise quadratic).

    Columns are scaled to a maximum of 1 (fit coefficients in coulombs)."""
    tt = np.asarray(tt, float)
    dur = max(float(dur), 1e-9)
    out = {"ramp": np.column_stack([tt / dur, (tt / dur) ** 2])}
    for k in WANDER_KNOTS:
        knots = np.linspace(0.0, dur, k + 2)
        h = knots[1] - knots[0]
        cols = []
        for j, kn in enumerate(knots):
            # integral from 0 to t of the hat function centred at kn (width h each side), closed form
            lo, hi = kn - h, kn + h
            a = np.clip(tt, lo, kn)
            b = np.clip(tt, kn, hi)
            up = np.where(tt >= max(lo, 0.0), ((a - lo) ** 2 - (max(lo, 0.0) - lo) ** 2) / (2 * h), 0.0)
            down = np.where(tt >= kn, (b - kn) - ((b - kn) ** 2) / (2 * h), 0.0)
            c = up + down
            m = float(np.max(np.abs(c))) or 1.0
            cols.append(c / m)
        out[f"wander{k}"] = np.column_stack(cols)
    return out


def select_offset_form(r0: np.ndarray, sens: np.ndarray, bases_rest: Mapping[str, np.ndarray],
                       groups: np.ndarray, n_folds: int = 4) -> tuple[str, dict]:
    """Choose the offset-drift form by blocked CV over the rest segments (linearised): the rest residual ``r0`` is
    explained by ``sens * B c`` (``sens`` the residual's sensitivity to a charge shift at each rest sample);
    contiguous groups of rest segments are left out in turn. A wandering form is chosen only if its held-out RMS is
    below :data:`WANDER_GAIN` times the ramp's. Returns (name, CV RMS per form)."""
    g = np.asarray(groups)
    ug = np.unique(g)
    if len(ug) < n_folds + 1:
        return "ramp", {}
    fold_of = {u: min(n_folds - 1, i * n_folds // len(ug)) for i, u in enumerate(ug)}
    fold = np.array([fold_of[x] for x in g])
    cv = {}
    for name, B in bases_rest.items():
        J = sens[:, None] * B
        err = []
        for f in range(n_folds):
            tr, te = fold != f, fold == f
            if tr.sum() <= J.shape[1]:
                err.append(np.inf)
                continue
            # a light ridge keeps the knots without rest samples near them at zero instead of free
            A = np.vstack([J[tr], 1e-3 * np.linalg.norm(J[tr]) / np.sqrt(J.shape[1]) * np.eye(J.shape[1])])
            c, *_ = np.linalg.lstsq(A, np.concatenate([-r0[tr], np.zeros(J.shape[1])]), rcond=None)
            err.append(float(np.mean((r0[te] + J[te] @ c) ** 2)))
        cv[name] = float(np.sqrt(np.mean(err)))
    best = min((n for n in cv if n != "ramp"), key=cv.get, default="ramp")
    name = best if cv.get(best, np.inf) < WANDER_GAIN * cv["ramp"] else "ramp"
    return name, cv


# ------------------------------------------------------------------------------------------ dielectric absorption
#: time constants [s] of the absorption branch searched (log-spaced over the range the gap library's member spans)
ABSORPTION_TAUS_S = tuple(float(x) for x in np.geomspace(0.2, 30.0, 12))
#: blocked-CV gain of the free-tip laser rows above which the absorption member is supported
ABSORPTION_MIN_GAIN = 0.3
#: contiguous blocks per calibration trial of the blocked CV
ABSORPTION_BLOCKS = 6
#: the absorption column must beat the leakage column int V dt on the same rows by this ratio of blocked-CV RMS: a slow
#: charge path of another form (leakage, a remanent state relaxing) is fitted almost as well by LP_tau(V) at a long tau
ABSORPTION_OVER_LEAK = 0.9


def absorption_column(V: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """``LP_tau(V)`` [V] from rest (the relay short holds V at 0): the voltage across the capacitor of a series
    R-C absorption branch with ``tau = R C`` in parallel with the actuators, exact for a piecewise-constant V. The
    charge that branch draws through the shunt is ``c * absorption_column(V, dt, tau)`` with ``c`` its capacitance
    [F]; it polarises nothing, so the actuators' charge is ``Q - c LP_tau(V)``."""
    from selfsense.signals.iir import lfilter

    V = np.asarray(V, float)
    if len(V) == 0:
        return np.zeros(0)
    a = float(np.exp(-dt / tau))
    return lfilter([1.0 - a], [1.0, -a], V)


@dataclass
class AbsorptionFit:
    """The absorption member of the charge link identified on the free-tip calibration trials' laser."""

    c_f: float = 0.0
    tau_s: float = float("nan")
    cv_gain: float = 0.0
    cv_rms_m_without: float = float("nan")
    cv_rms_m_with: float = float("nan")
    #: the same rows with the leakage column int V dt instead (a slow charge path the absorption column can mimic)
    cv_rms_m_leak: float = float("nan")
    supported: bool = False
    trials: list = field(default_factory=list)
    grid: list = field(default_factory=list)
    note: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


def _blocked_cv_rms(X: np.ndarray, y: np.ndarray, held: list) -> float:
    """Held-out RMS of the least-squares rows ``X beta = y`` over the folds ``held`` (boolean row masks: fold i is
    fitted on the rows outside ``held[i]`` and scored on those inside). Columns are scaled to unit RMS for the
    conditioning only; each block's rows are reduced once to the triangular factor of ``[X | y]`` and fold i is
    solved on the stacked factors of the other blocks (the same minimiser as on their rows)."""
    s = np.maximum(np.sqrt(np.mean(X * X, axis=0)), 1e-300)
    Xs = X / s
    R = [np.linalg.qr(np.column_stack([Xs[h], y[h]]), mode="r") for h in held]
    p = X.shape[1]
    err = []
    for i, h in enumerate(held):
        T = np.vstack([r for j, r in enumerate(R) if j != i])
        beta = np.linalg.lstsq(T[:, :p], T[:, p], rcond=None)[0]
        err.append(Xs[h] @ beta - y[h])
    e = np.concatenate(err)
    return float(np.sqrt(np.mean(e * e)))


@_memo_by_content
def fit_absorption(free_trials: Mapping[str, pd.DataFrame], taus: tuple = ABSORPTION_TAUS_S,
                   min_gain: float = ABSORPTION_MIN_GAIN, n_blocks: int = ABSORPTION_BLOCKS) -> AbsorptionFit:
    """Dielectric absorption from the free-tip calibration trials (laser reference ``dx_ref``, V, Q; relay open).

    On a free tip the displacement follows the actuators' charge (thesis eqs. 24-27 and 52 with f = 0), so a charge
    parked in an absorption branch shows as a slow lag between the laser and the measured charge: after a step the
    charge keeps rising while the tip rests. Rows: ``dx = a Q + b Q^2 + s dQ/dt - a c LP_tau(V) + d_k`` (``s``: a
    sub-sample skew between the channels, ``d_k`` one constant per trial), for every ``tau`` of the grid; ``c`` is the
    branch capacitance [F]. The member is *supported* when, at the tau with the lowest blocked-CV RMS among those
    with ``c > 0`` (the branch only takes charge), the RMS is lower than without the column by at least
    ``min_gain``, that tau lies inside the grid (an edge optimum is a lag of another form: creep, a skew, a mode),
    and the RMS is at most :data:`ABSORPTION_OVER_LEAK` times that of the same rows with the leakage column
    ``int V dt`` instead (a slow charge path of another form is fitted almost as well by a long-tau column: on the 60
    devices of ``benchmarks/absorption_null.py`` the best interior gain reached 0.84 while the ratio stayed >= 0.997;
    with a branch it is 0.17-0.26).
    Blocked CV: fold i holds out the i-th of ``n_blocks`` contiguous blocks of every trial. Only calibration
    references are read."""
    rows = []
    for name, df in free_trials.items():
        if "dx_ref" not in df:
            continue
        m = (df["relay"].to_numpy() < 0.5) & np.isfinite(df["dx_ref"].to_numpy(dtype=float))
        if m.sum() < 10 * n_blocks:
            continue
        t = df["t"].to_numpy(dtype=float)
        dt = float(np.median(np.diff(t)))
        rows.append((name, m, dt, df["q"].to_numpy(dtype=float), df["V"].to_numpy(dtype=float),
                     df["dx_ref"].to_numpy(dtype=float)))
    out = AbsorptionFit(trials=[r[0] for r in rows])
    if not rows:
        out.note = "no free-tip calibration trial with a displacement reference: absorption not identified"
        return out

    # the rows without the column (Q, Q^2, dQ/dt, one constant per trial), built once; the column of each candidate
    # is inserted as the fourth
    Xs, ys, blocks = [], [], []
    for k, (_, m, dt, Q, V, dx) in enumerate(rows):
        one = np.zeros((len(Q), len(rows)))
        one[:, k] = 1.0
        Xs.append(np.column_stack([Q, Q * Q, np.gradient(Q, dt), one])[m])
        ys.append(dx[m])
        blocks.append(np.minimum((np.arange(int(m.sum())) * n_blocks) // max(int(m.sum()), 1), n_blocks - 1))
    X0, y, b = np.vstack(Xs), np.concatenate(ys), np.concatenate(blocks)

    def design(column):
        col = np.concatenate([column(V, dt)[m] for _, m, dt, _, V, _ in rows])
        return np.column_stack([X0[:, :3], col, X0[:, 3:]])

    held = [b == i for i in range(n_blocks)]

    def cv(X, y, b):
        return _blocked_cv_rms(X, y, held)

    base = cv(X0, y, b)
    out.cv_rms_m_without = base
    out.cv_rms_m_leak = cv(design(leak_column), y, b)
    best = None
    for tau in taus:
        X = design(lambda V, dt, tau=tau: absorption_column(V, dt, tau))
        e = cv(X, y, b)
        beta = np.linalg.lstsq(X, y, rcond=None)[0]
        c = float(-beta[3] / beta[0]) if beta[0] != 0 else 0.0
        out.grid.append({"tau_s": float(tau), "cv_gain": 1.0 - e / base, "c_f": c})
        if c > 0 and (best is None or e < best[0]):
            best = (e, float(tau), c)
    if best is None:
        out.note = "the absorption column fits with a negative capacitance at every time constant: not supported"
        return out
    e, tau, c = best
    out.c_f, out.tau_s, out.cv_rms_m_with, out.cv_gain = c, tau, e, 1.0 - e / base
    interior = taus[0] < tau < taus[-1]
    beats_leak = e <= ABSORPTION_OVER_LEAK * out.cv_rms_m_leak
    out.supported = bool(interior and out.cv_gain >= min_gain and beats_leak)
    out.note = (f"absorption branch {c:.3g} F, tau {tau:.3g} s: blocked-CV RMS of the free-tip laser rows "
                f"{e:.3g} m with, {base:.3g} m without (gain {out.cv_gain:.3f}, threshold {min_gain:g}), "
                f"{out.cv_rms_m_leak:.3g} m with a leakage column instead"
                + ("" if interior else f"; tau on the edge of the grid {taus[0]:g}-{taus[-1]:g} s")
                + ("" if beats_leak else f"; not {1 - ABSORPTION_OVER_LEAK:.0%} better than the leakage form"))
    return out


# --------------------------------------------------------------------------------------------------------------------
# Resolution of the charge measurement: an ADC step that the noise does not dither
# --------------------------------------------------------------------------------------------------------------------

#: noise of a quantised channel (SD in ADC steps) below which the mean of a constant input is biased by the
#: quantiser: the bias of the mean of ``round(x + n)`` for Gaussian n of SD sigma steps is at most
#: ``exp(-2 pi^2 sigma^2) / pi`` steps (first harmonic of the quantisation error), 0.2 % of a step at 0.5 but 14 %
#: at 0.2 and about a third at 0.1: below this SD the quantiser is taken as not dithered
DITHER_MIN_STEPS = 0.5


def quantisation_step(x: np.ndarray) -> float:
    """Step of the lattice that a quantised record sits on (its ADC step in the record's units), or 0 when the
    record is not quantised (the differences of its distinct values are not multiples of the smallest one:
    floating-point data, a resampled or filtered record)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size < 10:
        return 0.0
    u = np.unique(x)
    if u.size < 2:
        return 0.0
    d = np.diff(u)
    tol = 1e-9 * max(float(np.max(np.abs(u))), 1e-300)
    d = d[d > tol]
    if not d.size:
        return 0.0
    step = float(np.min(d))
    k = d / step
    if np.mean(np.abs(k - np.round(k)) < 1e-3) < 0.99:
        return 0.0
    return step


@dataclass
class ChargeResolution:
    """How well one trial's shunt channel resolves the actuator current (:func:`charge_resolution`)."""

    step_v: float = 0.0                 # ADC step of V_s [V] (0: the record is not quantised)
    current_step_a: float = 0.0         # the step as a current, step / R [A]
    relay_noise_steps: float = float("nan")   # SD of V_s over the shorted leads, in steps
    dithered: bool = True               # the noise dithers the quantiser where the current is constant
    n_holds: int = 0
    unresolved_hold_s: float = 0.0      # holds (and the relay short) whose current sits between two steps
    sigma_q_end_c: float = 0.0          # SD of the charge error at the end of the trial [C]
    sigma_q_rms_c: float = 0.0          # RMS over the trial of that SD [C]
    note: str = ""

    def to_dict(self) -> dict:
        d = asdict(self)
        d["relay_noise_steps"] = float(d["relay_noise_steps"]) if np.isfinite(d["relay_noise_steps"]) else None
        return d


def charge_resolution(df: pd.DataFrame, R: float) -> tuple[ChargeResolution, np.ndarray]:
    """The charge error that the shunt channel's offset estimate and quantisation leave in ``q`` (thesis eq. 57),
    and its SD over time [C].

    ``charge_from_shunt`` subtracts the mean of ``V_s`` over the relay short (the in-amp offset) from the whole
    record. Its error integrates over the trial:

    * with noise that dithers the ADC step (SD >= :data:`DITHER_MIN_STEPS` steps), the mean is unbiased and its
      error is statistical, ``SD / sqrt(N)`` over the short's N samples;
    * without dither the mean is off by up to half a step (uniform, SD ``step / sqrt(12)``): while the drive moves,
      the signal sweeps across the steps and reads true, so the subtracted offset error integrates; during a hold or
      a rest whose current sits within a step of the short's, the channel reads the short's code whatever the
      current: the hold's own error is again up to half a step, independent of the short's. Both integrate over
      their durations.

    Only ``V_s``, ``V``, ``t`` and the relay are read: no reference. Returns the summary and the SD of the charge
    error per sample (0 while the relay is closed)."""
    t = df["t"].to_numpy(dtype=float)
    Vs = df["V_s"].to_numpy(dtype=float) if "V_s" in df else None
    relay = df["relay"].to_numpy(dtype=float) >= 0.5
    zero = np.zeros(len(t))
    if Vs is None or len(t) < 10:
        return ChargeResolution(note="no shunt-voltage record"), zero
    step = quantisation_step(Vs)
    if not step > 0:
        return ChargeResolution(note="the shunt channel is not quantised (floating-point record)"), zero
    i_step = step / float(R)
    sd_bias = i_step / np.sqrt(12.0)
    open_ = ~relay
    if not open_.any():
        return ChargeResolution(step_v=step, current_step_a=i_step, note="no relay-open samples"), zero
    i_open = int(np.argmax(open_))
    dt = float(np.median(np.diff(t)))
    # the offset is read on the first shorted segment (signals.charge.relay_offset): its noise and length (none:
    # the offset was given, and only the holds are assessed)
    if relay.sum() >= 2:
        r0 = int(np.argmax(relay))
        r1 = r0 + (int(np.argmax(~relay[r0:])) if (~relay[r0:]).any() else len(t) - r0)
        first = Vs[r0:r1]
        relay_sd = float(np.std(first) / step)
    else:
        first, relay_sd = Vs[:0], float("nan")
    idx = np.flatnonzero(open_)
    holds = find_holds(t[idx], df["V"].to_numpy(dtype=float)[idx])
    in_hold = np.zeros(len(t), bool)
    sigma2 = np.zeros(len(t))
    unresolved = 0.0
    dithered = not relay_sd < DITHER_MIN_STEPS   # (no short: nan, the holds decide)
    for a, b in holds:
        seg = Vs[idx[a:b]]
        ts = t[idx[a:b]]
        # the slow relaxation current of the hold is not noise: SD about the segment's linear trend
        A = np.column_stack([np.ones_like(ts), ts - ts[0]])
        r = seg - A @ np.linalg.lstsq(A, seg, rcond=None)[0]
        if float(np.std(r)) / step >= DITHER_MIN_STEPS:
            continue
        dithered = False
        in_hold[idx[a:b]] = True
        ta, tb = float(ts[0]), float(ts[-1])
        unresolved += tb - ta
        sigma2 += (sd_bias * np.clip(t - ta, 0.0, tb - ta)) ** 2 * open_
    # the offset subtracted from every open sample: statistical (dithered short) or the short's bias, integrated over
    # the samples that read true (all of them when dithered; outside the unresolved holds when not)
    if not first.size:
        rate, reads = 0.0, open_
    elif relay_sd >= DITHER_MIN_STEPS:
        rate = relay_sd * i_step / np.sqrt(first.size)
        reads = open_
    else:
        rate = sd_bias
        unresolved += float(first.size) * dt
        reads = open_ & ~in_hold
    sigma2 += (rate * np.cumsum(reads) * dt) ** 2
    sig = np.sqrt(sigma2)
    sig[relay] = 0.0
    sig[:i_open] = 0.0
    res = ChargeResolution(step_v=step, current_step_a=i_step, relay_noise_steps=relay_sd, dithered=bool(dithered),
                           n_holds=len(holds), unresolved_hold_s=unresolved if not dithered else 0.0,
                           sigma_q_end_c=float(sig[-1]), sigma_q_rms_c=float(np.sqrt(np.mean(sig[open_] ** 2))))
    res.note = (f"the noise dithers the ADC step: the charge error is that of the offset's mean, "
                f"{res.sigma_q_end_c * 1e9:.3g} nC (1 SD) by the end of the trial" if dithered else
                f"one ADC step is {i_step * 1e9:.3g} nA and the noise is below half a step where the current is "
                f"constant ({unresolved:.3g} s of relay short and holds): the charge error reaches "
                f"{res.sigma_q_end_c * 1e6:.3g} uC (1 SD) by the end of the trial")
    return res, sig


# --------------------------------------------------------------------------------------------------------------------
# The quantiser member: the short's offset error of an undithered shunt channel
# --------------------------------------------------------------------------------------------------------------------

#: the quantiser member is adopted when the blocked-CV RMS of the free-tip laser rows with its column is at most this
#: fraction of the RMS without it (:func:`fit_quantiser`; docs/method.md 1b'). 1: not worse. The channel check has
#: already established that the error is there (an undithered channel, reference-free) and the current is bounded;
#: the CV only rules out a column that stands for something else. On the 72 undithered devices of whole-device seeds
#: 0-14 the identified current was nearer the true one than 0 on 70, while the RMS fell by 5 % or more on 39 of them
#: (a small current among the laser's other residuals)
QUANTISER_CV_RATIO = 1.0
#: ... and only when the identified current is inside the physical range: a current within 1 % of the bound (half an
#: ADC step over R) or beyond it is more than an offset rounding can give, i.e. the column is standing in for another
#: misfit (docs/method.md 1b')
QUANTISER_AT_BOUND = 0.99
#: ... and only when the drive separates the column from the other slow paths of the rows: the currents of the CV
#: folds (:attr:`QuantiserFit.i_q_folds_a`) spread over at most this share of the bound. On a sine of constant
#: amplitude ``int V dt``, the drift and the column are all ramps in time and the fold currents scatter over 1-4
#: bounds (synthetic trials, ``tests/chain/test_quantiser_link.py``); on the 72 undithered devices of whole-device
#: seeds 0-14 (calibration sines of several amplitudes) the spread was 0.01-0.67 of the bound, above 0.5 on two
QUANTISER_FOLD_SPREAD = 0.5


def quantiser_column(df: pd.DataFrame, half_step_v: float) -> np.ndarray:
    """``int m dt`` [s], restarted wherever the relay shorts the leads (like the charge, thesis eq. 57), with ``m`` = 1
    on the relay-open samples whose shunt voltage reads another ADC code than the short: ``|V_s - offset| >
    half_step_v``, ``offset`` the mean of ``V_s`` over the first shorted segment (what the charge integration
    subtracts, :func:`selfsense.signals.relay_offset`).

    Where the noise does not dither the quantiser (:func:`charge_resolution`), the short reads one code and the
    subtracted offset is off from the in-amp's true one by up to half a step, ``e``. A sample that reads the short's
    code carries no current whatever the actuator does (0 after the subtraction), so it also carries none of that
    error; a sample that reads another code (the drive moves the current across the steps) carries the true current
    plus ``e / R``. The charge error is then ``(e / R) * quantiser_column``, one current for the device (the in-amp's
    offset and the short's code are the same in every trial); measured on a 13-bit whole-device Preisach device, the
    measured-minus-true charge of every trial follows this column with R^2 0.98-1.00, where a ramp in time gives
    0.96 on the trials with long holds (docs/method.md 1b'). Returns zeros without a ``V_s`` column or a relay short."""
    from selfsense.signals import charge_from_shunt, relay_offset

    t = df["t"].to_numpy(dtype=float)
    relay = (df["relay"].to_numpy(dtype=float) >= 0.5).astype(float)
    if "V_s" not in df or not (relay > 0).any():
        return np.zeros(len(t))
    Vs = df["V_s"].to_numpy(dtype=float)
    off = relay_offset(Vs, relay)
    m = ((relay < 0.5) & (np.abs(Vs - off) > float(half_step_v))).astype(float)
    col, _ = charge_from_shunt(t, m, relay, 1.0, offset=None)
    return col


#: time constants [s] of the mechanical-creep lags of the quantiser member's laser rows (charge-free creep of the tip
#: follows the charge with a lag, docs/method.md 6h: the rows carry it so that the column does not take it up)
QUANTISER_LAGS_S = (1.0, 10.0)
#: contiguous blocks per trial of the quantiser member's blocked CV
QUANTISER_BLOCKS = 5


@dataclass
class QuantiserFit:
    """The quantiser member's offset current identified on the free-tip calibration trials' laser
    (:func:`fit_quantiser`)."""

    i_q_a: float = 0.0
    #: the current from the rows of each CV fold (all blocks but one)
    i_q_folds_a: list = field(default_factory=list)
    cv_rms_m_without: float = float("nan")
    cv_rms_m_with: float = float("nan")
    n_rows: int = 0
    trials: list = field(default_factory=list)
    note: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


def fit_quantiser(free_trials: Mapping[str, pd.DataFrame], half_step_v: float,
                  lags: tuple = QUANTISER_LAGS_S, n_blocks: int = QUANTISER_BLOCKS) -> QuantiserFit:
    """The offset current ``i_q`` [A] that an undithered shunt channel's relay short leaves
    (:func:`quantiser_column`), from the free-tip calibration trials (laser reference ``dx_ref``, V, Q; relay open).

    On a free tip the displacement follows the actuators' charge (thesis eqs. 24-27 and 52 with f = 0), so the
    measured charge's error shows against the laser with no H(q) involved. The rows hold every slow charge path of
    the charge link beside the member's column, so that none of them is taken for it:

        dx = a (Q - i_q m) + b Q^2 + s dQ/dt + a_L int V dt + sum_j c_j LP_j(Q) + d_k + e_k tau_k^2

    ``m`` the member's column, ``int V dt`` a leakage current (:func:`leak_column`), ``LP_j`` first-order lags of the
    charge with the time constants ``lags`` (the tip's charge-free creep, docs/method.md 6h), ``s`` a sub-sample skew
    of the channels, ``d_k`` and ``e_k tau_k^2`` a constant and an offset drift per trial (``tau_k`` the trial's time
    over its length; no linear term: on a drive that moves all the time ``m`` is a ramp in time too, and the drift's
    linear term would take it). ``i_q = -(coefficient of m) / a``. The blocked-CV RMS of the rows with and without
    ``m`` (fold i holds out the i-th of ``n_blocks`` contiguous blocks of every trial) say whether the column is
    supported. Only calibration references are read. Measured against the simulator's true current on the 72
    undithered devices of whole-device seeds 0-14, thesis protocol (``python benchmarks/quantiser_gate.py --seeds 0-14
    --link-only``): off by 2.8 % of the bound (median; 11 % at the 90th percentile) on the clean preset and 5.5 % (13 %)
    with leakage, offset drift and creep, nearer the truth than 0 on 70 of 72, where the reference-H search of the
    earlier member missed by up to the whole bound."""
    rows = []
    for name, df in free_trials.items():
        if "dx_ref" not in df or "V_s" not in df:
            continue
        m = (df["relay"].to_numpy() < 0.5) & np.isfinite(df["dx_ref"].to_numpy(dtype=float))
        if m.sum() < 10 * n_blocks:
            continue
        rows.append((name, df, m))
    out = QuantiserFit(trials=[r[0] for r in rows])
    if not rows:
        out.note = "no free-tip calibration trial with a displacement reference: the offset current is not identified"
        return out
    shared, own, cols, ys, blocks = [], [], [], [], []
    for k, (_, df, m) in enumerate(rows):
        t = df["t"].to_numpy(dtype=float)
        dt = float(np.median(np.diff(t)))
        Q = df["q"].to_numpy(dtype=float)
        V = df["V"].to_numpy(dtype=float)
        span = float(np.ptp(Q[m])) or 1.0
        shared.append(np.column_stack([Q, Q * Q / span, np.gradient(Q, dt), leak_column(V, dt)]
                                      + [_lowpass(Q, tau, dt) for tau in lags])[m])
        tk = t[m] - t[m][0]
        tau2 = (tk / max(float(tk[-1]), dt)) ** 2
        per = np.zeros((int(m.sum()), 2 * len(rows)))
        per[:, 2 * k], per[:, 2 * k + 1] = 1.0, tau2
        own.append(per)
        cols.append(quantiser_column(df, half_step_v)[m])
        ys.append(df["dx_ref"].to_numpy(dtype=float)[m])
        n = int(m.sum())
        blocks.append(np.minimum((np.arange(n) * n_blocks) // n, n_blocks - 1))
    S, P, c, y, b = np.vstack(shared), np.vstack(own), np.concatenate(cols), np.concatenate(ys), np.concatenate(blocks)
    held = [b == i for i in range(n_blocks)]
    X0 = np.column_stack([S, P])
    X1 = np.column_stack([S[:, :1], c, S[:, 1:], P])
    out.n_rows = len(y)
    out.cv_rms_m_without = _blocked_cv_rms(X0, y, held)
    out.cv_rms_m_with = _blocked_cv_rms(X1, y, held)
    s = np.maximum(np.sqrt(np.mean(X1 * X1, axis=0)), 1e-300)
    beta = np.linalg.lstsq(X1 / s, y, rcond=None)[0] / s
    if not np.isfinite(beta[0]) or beta[0] == 0.0:
        out.note = "the laser rows give no charge coefficient: the offset current is not identified"
        return out
    out.i_q_a = float(-beta[1] / beta[0])
    # the same current from each fold's rows (every block but one): their spread says whether the drive separates
    # the column from the other slow paths (on a sine of constant amplitude int V dt, the drift and the column are
    # all ramps in time, and the fold estimates scatter over more than the bound)
    folds = []
    for h in held:
        bf = np.linalg.lstsq(X1[~h] / s, y[~h], rcond=None)[0] / s
        folds.append(float(-bf[1] / bf[0]) if bf[0] != 0.0 else float("nan"))
    out.i_q_folds_a = folds
    out.note = (f"offset current {out.i_q_a * 1e9:.4g} nA from the free-tip laser rows ({out.n_rows} rows of "
                f"{len(rows)} trial{'s' if len(rows) > 1 else ''}): blocked-CV RMS {out.cv_rms_m_with:.3g} m with the "
                f"member's column, {out.cv_rms_m_without:.3g} m without")
    return out
