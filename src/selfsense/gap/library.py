"""The library of candidate unmodelled effects (docs/gap.md).

Each :class:`Effect` has
* ``screen(df, est) -> (N, k)`` residual features used for screening (blocked CV on the held-out residual);
  ``df`` is a prepared trial (CONTRACTS.md: t, V, q, u_cmd, relay, dx_ref, f_ref, V_c, V_s), ``est`` the base
  estimate of that trial (t, dx_hat, f_hat, dx_raw, f_raw, V_p, V_H, q);
* ``augmentation(**kw)`` -> a fresh object implementing the CONTRACTS.md augmentation protocol
  (``name``, ``fit(trials, meta, estimator)`` on calibration trials only, ``transform(df)``, ``features(df)``,
  ``feature_names``), used for confirmation by refit.

Structural augmentations come in four kinds:
* charge-path corrections (``target="q"``): fitted jointly with a play-operator H by least squares over all
  free-tip calibration trials (thesis eq. 55 target ``V - Q/(n_A C_p)``); transform ``Q <- Q + n_A C_p sum c_j g_j``;
* voltage-side / hysteresis-shape corrections (``target="V"``): same joint fit, transform ``V <- V - sum_j c_j g_j``,
  i.e. extra terms of H(q) (thesis eq. 27: V_p = V - H(q));
* extra regressors of the sensing regression (thesis eq. 52 rows), ``features(df)``;
* physical reconstructions of a measured input (amplifier limits: :class:`CurrentLimitReconstruction`).
The forms are deliberately NOT the simulator's generator forms (see FORMS.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd

from selfsense.sensing.core import force_regressor, h_target, piezo_voltage

from .model import fit_fast_pi, pi_design, rig_params, solve_signed_nnls, _play
from .model import sup_thresholds as _sup_thresholds, thresholds as _thresholds
from .protocol import _runs
from selfsense.signals import SignalError, relay_offset

from .signals import active, branch, deriv, dt_of, first_loading, leaky_integral, lowpass, t_active

__all__ = ["Effect", "LIBRARY", "FAMILIES", "effect", "HCorrection", "RegressorAug", "Composite"]

# --------------------------------------------------------------------------- column generators (prepared df)


def _Q(df):
    return df["q"].to_numpy(float)


def _V(df):
    return df["V"].to_numpy(float)


def _scale(x):
    s = float(np.max(np.abs(x))) if len(x) else 1.0
    return s if s > 0 else 1.0


def g_leak(df):
    """Leaky integral of the actuator voltage, tau = 200 s, active part only [V s]."""
    dt = dt_of(df["t"].to_numpy())
    return leaky_integral(_V(df) * active(df), 200.0, dt)[:, None]


def g_offset(df):
    """Time since relay release and its square over a fixed 100 s [s, s^2 / 100 s] (the same meaning in trials of
    any length)."""
    ta = t_active(df)
    return np.column_stack([ta, ta**2 / 100.0])


def g_absorption(df):
    """Electrical soak: first-order lags of V minus V, tau = 0.3 s and 3 s [V]."""
    dt = dt_of(df["t"].to_numpy())
    V = _V(df) * active(df)
    return np.column_stack([lowpass(V, tau, dt) - V for tau in (0.3, 3.0)])


def g_temperature(df):
    """Gain drift: V t and Q t (time since relay release) [V s, C s]."""
    ta = t_active(df)
    return np.column_stack([_V(df) * ta, _Q(df) * ta])


def g_creep(df):
    """Mechanical creep lag bank on the charge: LP_tau(Q) - Q, tau = 0.05, 0.5, 5 s [C]."""
    dt = dt_of(df["t"].to_numpy())
    Q = _Q(df)
    return np.column_stack([lowpass(Q, tau, dt) - Q for tau in (0.05, 0.5, 5.0)])


def g_mode(df):
    """Mechanism dynamics: dQ/dt and d2Q/dt2 after a 2 ms low-pass [C/s, C/s^2]."""
    dt = dt_of(df["t"].to_numpy())
    Q = _Q(df)
    d1 = deriv(Q, dt, 0.002)
    d2 = deriv(d1, dt, 0.002)
    return np.column_stack([d1, d2])


def g_amplifier(df):
    """Amplifier bandwidth: V_c - LP_tau(V_c), tau = 0.5, 2, 8 ms [V]."""
    dt = dt_of(df["t"].to_numpy())
    Vc = df["V_c"].to_numpy(float) if "V_c" in df else _V(df)
    return np.column_stack([Vc - lowpass(Vc, tau, dt) for tau in (0.0005, 0.002, 0.008)])


def g_one_sided(df):
    """Branch-dependent and first-loading hysteresis terms of Q: b Q, b Q^2/Qm, 1_first Q, max(Q - r, 0)."""
    Q = _Q(df)
    Qm = _scale(Q)
    b = branch(Q, 0.02 * Qm)
    fl = first_loading(Q, 0.01 * Qm)
    d = np.maximum.accumulate(Q) - Q  # distance below the running maximum (first-loading memory)
    return np.column_stack([b * Q, b * Q**2 / Qm, fl * Q, d, d**2 / Qm])


def g_preload(df, ref_scale: float | None = None):
    """Wrong initial operator state: P_r[Q; z0 = r] - P_r[Q; z0 = 0] for r = 0.2, 0.45, 0.7 Qm (zero once wiped)."""
    Q = _Q(df)
    Qm = ref_scale or _scale(Q)
    r = np.array([0.2, 0.45, 0.7]) * Qm
    return _play(Q, r, r) - _play(Q, r, None)


def g_few_ops(df, ref_scale: float | None = None, n: int = 12):
    """Finer play operators (thresholds between the base ones) of Q [C]."""
    Q = _Q(df)
    Qm = ref_scale or _scale(Q)
    r = Qm * np.array([0.015, 0.03, 0.05, 0.08, 0.12, 0.18])
    return _play(Q, r)


# --------------------------------------------------------------------------- augmentations (CONTRACTS protocol)

_NOMINAL: dict = {}


def like(estimator, augmentations=()):
    """A fresh, unfitted estimator of the same kind and configuration as ``estimator``."""
    from .model import FastSensingEstimator

    if isinstance(estimator, FastSensingEstimator):
        return FastSensingEstimator(rig=estimator.rig, augmentations=tuple(augmentations), n_play=estimator.n_play,
                                    regression=estimator.regression)
    return type(estimator)(config=estimator.config, rig=estimator.rig, augmentations=tuple(augmentations))


def nominal_fit(trials, meta, estimator):
    """Nominal estimator (same kind as ``estimator``, no augmentation) on these calibration trials, cached on the
    identity of the trial frames so the augmentations of one diagnosis share one private nominal fit."""
    key = (tuple((k, id(v)) for k, v in trials.items()), tuple(meta.index), id(estimator.rig),
           type(estimator).__name__)
    if key not in _NOMINAL:
        if len(_NOMINAL) > 16:
            _NOMINAL.clear()
        _NOMINAL[key] = (like(estimator).fit(trials, meta), trials, meta)  # keep refs alive
    return _NOMINAL[key][0]



@dataclass
class HCorrection:
    """Structural correction fitted jointly with a play-operator H on the free-tip calibration trial.

    ``target="q"``: charge-path effect, ``Q <- Q + n_A C_p sum c_j g_j(df)``;
    ``target="V"``: hysteresis-shape / voltage effect, ``V <- V - sum c_j g_j(df)``.
    """

    name: str
    cols: Callable
    target: str = "q"
    scaled: bool = False  # cols take a reference charge scale (fixed at fit time)
    coef_: np.ndarray | None = None
    feature_names: tuple = ()

    def _g(self, df):
        return self.cols(df, self._qs) if self.scaled else self.cols(df)

    def fit(self, trials, meta, estimator) -> None:
        """Joint least squares over ALL free-tip calibration trials (stacked, each with its own play-operator
        history): y = V - Q/(n_A C_p) = H(Q) + sum_j c_j g_j (thesis eq. 55 target). Stacking trials with
        different histories (sine, mixed, protocol steps) is what separates a slow charge-path term from H."""
        free = list(meta[meta["tip"] == "free"].index)
        p = rig_params(estimator.rig)
        self._cpt = p["n_A"] * p["C_p"]
        Qs = [_Q(trials[t])[active(trials[t])] for t in free]
        self._qs = _scale(np.concatenate(Qs))
        n_play = min(int(getattr(estimator, "n_play", getattr(getattr(estimator, "config", None), "n_play", 8))), 10)
        r = _thresholds(self._qs, n_play)
        d = _sup_thresholds(self._qs, 4)
        X, Y = [], []
        step = max(1, sum(len(q) for q in Qs) // 6000)
        n0 = 2 + len(d)  # free-sign columns of pi_design: 1, Q and the superposition terms
        for t, Q in zip(free, Qs):
            df = trials[t]
            act = active(df)
            G = self._g(df)[act]
            y = _V(df)[act] - Q / self._cpt
            B = pi_design(Q, r, d)  # play histories over the active samples of the trial, then decimated
            X.append(np.column_stack([B[:, :n0], G, B[:, n0:]])[::step])
            Y.append(y[::step])
        X, Y = np.vstack(X), np.concatenate(Y)
        nf = X.shape[1] - n_play  # free-sign columns: pi_design's and the correction's
        c = solve_signed_nnls(X, Y, nf)
        self.coef_ = c[n0:nf]

    def transform(self, df: pd.DataFrame) -> pd.DataFrame:
        if self.coef_ is None:
            return df
        corr = self._g(df) @ self.coef_
        df = df.copy()
        if self.target == "q":
            df["q"] = _Q(df) + self._cpt * corr
        else:
            df["V"] = _V(df) - corr
        return df


@dataclass
class RegressorAug:
    """Extra regressors appended to both rows of the sensing regression (thesis eq. 52 / 46)."""

    name: str
    cols: Callable
    n_cols: int
    needs_force_proxy: bool = False

    @property
    def feature_names(self):
        return tuple(f"g{j}" for j in range(self.n_cols))

    def fit(self, trials, meta, estimator) -> None:
        p = rig_params(estimator.rig)
        self._nA, self._Cp = p["n_A"], p["C_p"]
        self._cpt = p["n_A"] * p["C_p"]
        if self.needs_force_proxy:  # private free-tip H to form the force proxy s = Q - n_A C_p V_p (eq. 52 row 2)
            free = meta[meta["tip"] == "free"].index[0]
            df = trials[free]
            act = active(df)
            Q = _Q(df)[act]
            self._h, _ = fit_fast_pi(Q[:: max(1, len(Q) // 3000)],
                                     h_target(_V(df)[act], Q, 1.0 / self._cpt)[:: max(1, len(Q) // 3000)], 8)
            s = self._proxy(df)[act]
            self._ss = _scale(s)
            self._vs = _scale(_V(df)[act])

    def _proxy(self, df):
        Q = _Q(df)
        return force_regressor(Q, piezo_voltage(_V(df), self._h(Q)), self._nA, self._Cp)   # eqs. (27), (52)

    def features(self, df: pd.DataFrame) -> pd.DataFrame:
        G = self.cols(self, df)
        return pd.DataFrame(G, columns=list(self.feature_names), index=df.index)


def _cross(aug, df):
    return _Q(df)[:, None]


def _stress(aug, df):
    s = aug._proxy(df) / aug._ss
    return np.column_stack([s * _V(df) / aug._vs, s * _Q(df) / _scale(_Q(df))])


def _contact(aug, df):
    s = aug._proxy(df) / aug._ss
    return np.column_stack([s * np.abs(s), np.maximum(s, 0) ** 1.5])


def _creep_feats(aug, df):
    return g_creep(df)


def _mode_feats(aug, df):
    return g_mode(df)


def _temp_feats(aug, df):
    return g_temperature(df)


@dataclass
class OutputAug:
    """Regressors built from the *nominal model's own output* (a private nominal fit on the same calibration
    trials): e.g. derivatives of the estimated tip signals for output dynamics, lags of them for creep, products
    with the estimated force for load effects. Zero wherever the nominal output is zero, so blocked-tip dx = 0 and
    free-tip f = 0 rows stay consistent."""

    name: str
    fn: Callable

    def fit(self, trials, meta, estimator) -> None:
        self._base = nominal_fit(trials, meta, estimator)
        any_df = next(iter(trials.values()))
        self.feature_names = tuple(f"g{j}" for j in range(self._cols(any_df).shape[1]))

    def _cols(self, df):
        return np.asarray(self.fn(df, self._base.estimate(df)), float)

    def features(self, df: pd.DataFrame) -> pd.DataFrame:
        return pd.DataFrame(self._cols(df), columns=list(self.feature_names), index=df.index)


@dataclass
class Composite:
    """Several augmentations applied as one (transforms in order, features concatenated)."""

    name: str
    parts: tuple

    @property
    def feature_names(self):
        out = []
        for p in self.parts:
            out += [f"{p.name}.{n}" for n in getattr(p, "feature_names", ())] if hasattr(p, "features") else []
        return tuple(out)

    def fit(self, trials, meta, estimator):
        for p in self.parts:
            p.fit(trials, meta, estimator)
            if hasattr(p, "transform"):
                trials = {k: p.transform(v) for k, v in trials.items()}

    def transform(self, df):
        for p in self.parts:
            if hasattr(p, "transform"):
                df = p.transform(df)
        return df

    def features(self, df):
        frames = [p.features(df) for p in self.parts if hasattr(p, "features")]
        if not frames:
            return pd.DataFrame(index=df.index)
        F = pd.concat(frames, axis=1)
        F.columns = list(self.feature_names)
        return F


@dataclass
class Smoothing:
    """Floor entry: a light low-pass of V and q (noise cannot be modelled away; this should not help)."""

    name: str = "noise"
    tau_samples: float = 3.0

    def fit(self, trials, meta, estimator):
        pass

    def transform(self, df):
        dt = dt_of(df["t"].to_numpy())
        df = df.copy()
        df["q"] = lowpass(_Q(df), self.tau_samples * dt, dt)
        df["V"] = lowpass(_V(df), self.tau_samples * dt, dt)
        return df


# --------------------------------------------------------------------------- screening features (df + base est)


def _xhat(est):
    return est["dx_raw"].to_numpy(float), est["f_raw"].to_numpy(float)


def s_creep(df, est):
    dt = dt_of(df["t"].to_numpy())
    out = []
    for x in _xhat(est):
        out += [lowpass(x, tau, dt) - x for tau in (0.05, 0.5, 5.0)]
    return np.column_stack(out)


def s_temperature(df, est):
    ta = t_active(df)
    dx, f = _xhat(est)
    return np.column_stack([dx * ta, f * ta, _V(df) * ta])


def s_mode(df, est):
    dt = dt_of(df["t"].to_numpy())
    out = []
    for x in _xhat(est):
        d1 = deriv(x, dt, 0.002)
        out += [d1, deriv(d1, dt, 0.002)]
    return np.column_stack(out)


def s_one_sided(df, est):
    V = _V(df)
    Vm = _scale(V)
    b = branch(V, 0.02 * Vm)
    fl = first_loading(V, 0.01 * Vm)
    return np.column_stack([b * V, b * V**2 / Vm, fl * V, g_one_sided(df)])


def s_cross(df, est):
    return np.column_stack([_Q(df), est["V_p"].to_numpy(float)])


def s_stress(df, est):
    dx, f = _xhat(est)
    fs, xs = _scale(f), _scale(dx)
    Vp = est["V_p"].to_numpy(float)
    return np.column_stack([f / fs * dx / xs, f / fs * Vp / _scale(Vp), f / fs * _V(df) / _scale(_V(df))])


def s_contact(df, est):
    dx, f = _xhat(est)
    fs = _scale(f)
    s = f / fs
    return np.column_stack([s * np.abs(s), np.maximum(s, 0) ** 1.5, (s > 0.05).astype(float)])


# --------------------------------------------------------------------------- the library


@dataclass(frozen=True)
class Effect:
    """One candidate effect: ``family.member``."""

    family: str
    member: str
    screen: Callable | None
    augmentation: Callable
    description: str = ""
    suggestion: str = ""
    experiment: str = ""

    @property
    def name(self) -> str:
        return f"{self.family}.{self.member}"


def _hc(name, cols, target, scaled=False):
    return lambda: HCorrection(name=name, cols=cols, target=target, scaled=scaled)


LIBRARY: tuple[Effect, ...] = (
    Effect("slow", "creep", s_creep,
           lambda: OutputAug("slow.creep", s_creep),
           "creep between charge and displacement (lag bank of Q in the sensing regression)",
           "add a creep operator bank to the charge-to-tip map", "up/down steps to the same level"),
    Effect("slow", "leakage", lambda df, est: g_leak(df),
           _hc("slow.leakage", g_leak, "q"),
           "charge leakage through a finite insulation resistance (leaky integral of V added to Q)",
           "model R_leak in the charge path", "long holds at high V and at 0 V"),
    Effect("slow", "offset_drift", lambda df, est: g_offset(df),
           _hc("slow.offset_drift", g_offset, "q"),
           "integrator / ADC offset drift (ramp in Q)", "estimate the shunt-amplifier offset on a 0 V hold",
           "a zero-input hold"),
    Effect("slow", "absorption", lambda df, est: g_absorption(df),
           _hc("slow.absorption", g_absorption, "q"),
           "dielectric absorption (electrical soak of the charge after steps)",
           "add a soak term to the charge path (C0G sense capacitor)", "step on a blocked tip / dummy capacitor"),
    Effect("slow", "temperature", s_temperature,
           lambda: OutputAug("slow.temperature", s_temperature),
           "temperature drift of C_p and alpha (gain drift over time)", "log temperature; T-dependent C_p and alpha",
           "identical cycles repeated after a rest"),
    Effect("rate", "mechanism_mode", s_mode,
           lambda: OutputAug("rate.mechanism_mode", s_mode),
           "mechanism dynamics (2nd-order mode): derivatives of Q in the sensing regression",
           "add the mechanism mode to the two-port", "sine sweeps"),
    Effect("rate", "amplifier", lambda df, est: g_amplifier(df),
           lambda: CurrentLimitReconstruction(),
           "amplifier bandwidth / slew (terminal voltage lags the command)", "measure V at the terminals",
           "fast steps, terminal voltage probe"),
    Effect("hysteresis", "one_sided", s_one_sided,
           _hc("hysteresis.one_sided", g_one_sided, "V"),
           "one-sided / asymmetric hysteresis and initial ascending curve (branch-dependent H terms)",
           "use the one-sided RI model (002_7d89b7147aad52e4.txt)", "nested minor loops, first loading"),
    Effect("hysteresis", "preload", lambda df, est: g_preload(df),
           _hc("hysteresis.preload", g_preload, "V", scaled=True),
           "wrong initial operator state (preload): terms that vanish once each operator is wiped",
           "fit the initial operator state z0 / precondition with a major loop", "conditioning major loop"),
    Effect("hysteresis", "few_operators", lambda df, est: g_few_ops(df),
           _hc("hysteresis.few_operators", g_few_ops, "V", scaled=True),
           "too few play operators (finer thresholds)", "more play operators", "nested minor loops"),
    Effect("load", "cross_terms", s_cross,
           lambda: OutputAug("load.cross_terms", lambda df, est: est["V_p"].to_numpy(float)[:, None]),
           "neglected two-port cross terms (thesis eq. 46 vs 52): free force-row charge coefficient",
           "regression='full' (eq. 46)", "several object stiffnesses"),
    Effect("load", "stress_hysteresis", s_stress,
           lambda: OutputAug("load.stress_hysteresis", s_stress),
           "stress-dependent hysteresis (free-tip H used under load): force-proxy x V, Q terms",
           "calibrate H under load too", "free vs blocked at equal V"),
    Effect("load", "contact", s_contact,
           lambda: OutputAug("load.contact", s_contact),
           "contact nonlinearity (Hertz-like force-proxy powers)", "contact law in the load model",
           "objects of different stiffness"),
    Effect("floor", "noise", None, lambda: Smoothing("floor.noise"),
           "sensor noise / quantisation (the floor: nothing should beat it)", "better ADC / averaging",
           "rest segment"),
)

FAMILIES = tuple(dict.fromkeys(e.family for e in LIBRARY))
_BY_NAME = {e.name: e for e in LIBRARY}


def effect(name: str) -> Effect:
    """Library entry by ``family.member`` name."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise KeyError(f"unknown effect {name!r}; expected one of {sorted(_BY_NAME)}") from None



# --------------------------------------------------------------------------- physical self-calibrations


def _relay_offset(df) -> float:
    """Shunt offset over the first shorted segment (``selfsense.signals.relay_offset``); 0 without one."""
    try:
        return relay_offset(df["V_s"].to_numpy(float), df["relay"].to_numpy(float))
    except SignalError:
        return 0.0


def _slew_limit(x: np.ndarray, t: np.ndarray, rate: float) -> np.ndarray:
    """Rate-limited copy of ``x``: |dy/dt| <= rate [units/s] (forward recursion)."""
    y = np.empty_like(x)
    y[0] = x[0]
    dtl = rate * np.diff(t)
    prev = x[0]
    for i in range(1, len(x)):  # a few thousand samples per trial: plain Python is fast enough here
        d = x[i] - prev
        lim = dtl[i - 1]
        prev = prev + (lim if d > lim else (-lim if d < -lim else d))
        y[i] = prev
    return y


@dataclass
class CurrentLimitReconstruction:
    """Structural augmentation for amplifier limits (rate family). The actuator voltage is reconstructed from the
    command, ``V_c = gain u_cmd`` (thesis eq. 56); a current-limited amplifier cannot charge the capacitive load
    faster than ``i_max / C`` and its true output lags the command.

    Fit (calibration trials only): the shunt current must show a *plateau* at its largest value (>= ``plateau_s``
    of consecutive samples within 2 % of the maximum; a smooth current peak does not give one, a linear voltage
    ramp does); otherwise the augmentation is the identity. ``i_max`` is that maximum plus a 2 % margin, so on
    data without a limit the rate limit does not engage (measured on an effect-free case: actuator-voltage
    change 0.00 V RMS). Transform, per trial with C the
    secant capacitance ptp(q)/ptp(V): ``V_c' = rate_limit(V_c, i_max / C)`` and ``V <- V - (V_c - V_c')`` (a
    correction of V, so transforms of other augmentations applied before it are kept)."""

    name: str = "rate.amplifier"
    plateau_s: float = 0.03
    i_max_: float = float("inf")

    def fit(self, trials, meta, estimator) -> None:
        R = rig_params(estimator.rig)["R"]
        cur = {}
        for t, df in trials.items():
            act = active(df)
            if act.any():
                cur[t] = np.abs(df["V_s"].to_numpy(float) - _relay_offset(df)) / R * act
        imax = max((float(np.max(c)) for c in cur.values()), default=0.0)
        longest = 0.0
        for t, c in cur.items():
            dt = dt_of(trials[t]["t"].to_numpy())
            runs = _runs(c >= 0.98 * imax)
            longest = max(longest, max(((b - a) * dt for a, b in runs), default=0.0))
        self.i_max_ = 1.02 * imax if imax > 0 and longest >= self.plateau_s else float("inf")

    def transform(self, df: pd.DataFrame) -> pd.DataFrame:
        act = active(df)
        if not np.isfinite(self.i_max_) or not act.any():
            return df
        V, Q = _V(df)[act], _Q(df)[act]
        C = float(np.ptp(Q) / np.ptp(V)) if np.ptp(V) > 0 else 0.0
        if not C > 0:
            return df
        df = df.copy()
        vc0 = df["V_c"].to_numpy(float)
        vc = _slew_limit(vc0, df["t"].to_numpy(float), self.i_max_ / C)
        df["V_c"] = vc
        df["V"] = _V(df) - (vc0 - vc)
        return df
