"""The load stage's stand-in force estimate: a fast, fixed-form self-sensing estimator (:class:`FastSensingEstimator`).

The stage-wise diagnostic's load stage compares the load cell with a *nominal* force estimate on every trial. That
estimate must not depend on the configured estimator's model selection (the stage's null thresholds were
calibrated with this fixed form on effect-free cases of four device families), and it is refitted for every
blind case, so it takes milliseconds:

* H(q) on the free-tip calibration trial, thesis ``000_18d138f03f1777c3.txt`` eq. (55): target
  ``V_H = V - Q / (n_A C_p)``, model ``H(Q) = c0 + w_0 Q + sum_j s_j max(Q - d_j, 0) + sum_i w_i P_{r_i}[Q]`` with
  play operators P (thesis eqs. 29-32, w_i >= 0) and one-sided superposition terms (eqs. 33-35, signed),
  identified by non-negative least squares instead of the QP of thesis App. A (eqs. 60-80);
* ``V_p = V - H(Q)`` (thesis eq. 27);
* sensing coefficients by joint least squares over the calibration trials, thesis eq. (52):
  ``dx = A1 Q + A2 V_p``, ``f = (A3/n_A)(Q - n_A C_p V_p)``; ``regression="full"`` frees the force row (eq. 46).

Equations (27), (52) and (55) are evaluated by :mod:`selfsense.sensing.core` (the definitions the batch and
streaming estimators use); only the H model and its fit are this module's own. Units: SI (C, V, m, N, s). No
limiting / DC offset post-processing: the diagnostic studies the raw estimate.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
import pandas as pd
from scipy.optimize import nnls

from selfsense.sensing.core import (force_coefficients, force_regressor, h_target, piezo_voltage, tip_displacement,
                                    tip_force)

__all__ = ["FastPI", "fit_fast_pi", "FastSensingEstimator", "rig_params"]


def _play(x: np.ndarray, r: np.ndarray, z0: np.ndarray | None = None) -> np.ndarray:
    from selfsense.hysteresis.operators import play_operator

    return play_operator(x, r, z0)


def rig_params(rig: Any) -> dict[str, float]:
    """n_A, C_p (one actuator), amplifier gain and shunt resistance from a ``selfsense.io.Rig`` or a rig.yaml
    mapping."""
    def get(*path):
        o = rig
        for p in path:
            o = o[p] if isinstance(o, Mapping) else getattr(o, p)
        return float(o)

    return {"n_A": get("n_actuators"), "C_p": get("actuator_catalog", "capacitance_f"),
            "gain": get("amplifier_gain"), "R": get("shunt_resistance_ohm")}


@dataclass
class FastPI:
    """H(Q) = c0 + w0 Q + sum_j s_j S_{d_j}[Q] + sum_i w_i P_{r_i}[Q]  (Q [C] -> V).

    P: play operators (thesis eqs. 29-32, z0 = 0, w_i >= 0); S: one-sided dead-zone superposition operators
    max(Q - d_j, 0) (thesis eqs. 33-35, free-sign weights) for the saturation a play sum cannot make."""

    r: np.ndarray
    w: np.ndarray
    w0: float
    c0: float
    d: np.ndarray = field(default_factory=lambda: np.zeros(0))
    s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __call__(self, Q: np.ndarray) -> np.ndarray:
        Q = np.asarray(Q, float)
        out = self.c0 + self.w0 * Q + _play(Q, self.r) @ self.w
        if len(self.d):
            out = out + np.maximum(Q[:, None] - self.d[None, :], 0.0) @ self.s
        return out


def _levels(Q: np.ndarray, n: int) -> np.ndarray:
    """n equally spaced levels i/(n+1) * max|Q|, i = 1..n (thesis App. A: equally spaced thresholds)."""
    qmax = float(np.max(np.abs(Q))) or 1.0
    return qmax * np.arange(1, n + 1) / (n + 1)


def _signed_nnls(X: np.ndarray, y: np.ndarray, n_free: int) -> np.ndarray:
    """Least squares with the first ``n_free`` coefficients free in sign and the rest >= 0 (column-scaled NNLS)."""
    s = np.sqrt(np.mean(X**2, axis=0))
    s[s == 0] = 1.0
    Z = X / s
    Zs = np.column_stack([Z[:, :n_free], -Z[:, :n_free], Z[:, n_free:]])
    b, _ = nnls(Zs, y, maxiter=50 * Zs.shape[1])
    coef = np.concatenate([b[:n_free] - b[n_free:2 * n_free], b[2 * n_free:]])
    return coef / s


def fit_fast_pi(Q: np.ndarray, y: np.ndarray, n_play: int = 8, n_sup: int = 4) -> FastPI:
    """Fit :class:`FastPI` to ``y`` [V] over the charge ``Q`` [C]."""
    Q = np.asarray(Q, float)
    r, d = _levels(Q, n_play), _levels(Q, n_sup)
    X = np.column_stack([np.ones_like(Q), Q, np.maximum(Q[:, None] - d[None, :], 0.0), _play(Q, r)])
    nf = 2 + n_sup
    c = _signed_nnls(X, np.asarray(y, float), nf)
    return FastPI(r=r, w=c[nf:], w0=float(c[1]), c0=float(c[0]), d=d, s=c[2:nf])


def _lstsq(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Column-scaled least squares."""
    s = np.sqrt(np.mean(X**2, axis=0))
    s[s == 0] = 1.0
    c, *_ = np.linalg.lstsq(X / s, y, rcond=1e-10)
    return c / s


def _decimate(n: int, max_samples: int) -> slice:
    return slice(None, None, max(1, int(np.ceil(n / max_samples))))


@dataclass
class FastSensingEstimator:
    """The stand-in estimator: ``fit(trials, meta)`` on the calibration trials, ``estimate(df)`` on any trial."""

    rig: Any
    n_play: int = 8
    regression: str = "approx"
    max_fit_samples: int = 4000

    hysteresis_: Any = field(default=None, init=False, repr=False)
    coef_: dict = field(default_factory=dict, init=False)

    def _regressors(self, df: pd.DataFrame) -> np.ndarray:
        Q = df["q"].to_numpy(float)
        return np.column_stack([Q, piezo_voltage(df["V"].to_numpy(float), self.hysteresis_(Q))])  # thesis eq. (27)

    def fit(self, trials: Mapping[str, pd.DataFrame], meta: pd.DataFrame) -> "FastSensingEstimator":
        meta = meta.set_index("trial") if "trial" in meta.columns else meta
        cal = meta[meta["role"] == "calibration"]
        free = cal[cal["tip"] == "free"]
        if cal.empty or free.empty:
            raise ValueError("trials.csv: need a calibration trial with tip 'free' (it calibrates H(q))")
        p = rig_params(self.rig)
        self.n_A_, self.C_p_ = p["n_A"], p["C_p"]
        d = trials[free.index[0]]
        act = d["relay"].to_numpy() < 0.5
        sl = _decimate(int(act.sum()), self.max_fit_samples)
        Q = d["q"].to_numpy(float)[act][sl]
        y = h_target(d["V"].to_numpy(float)[act][sl], Q, 1.0 / (self.n_A_ * self.C_p_))   # thesis eq. (55)
        self.hysteresis_ = fit_fast_pi(Q, y, self.n_play)
        Xd, yd, Xf, yf = [], [], [], []
        for tid, row in cal.to_dict("index").items():
            df = trials[tid]
            m = df["relay"].to_numpy() < 0.5
            F = self._regressors(df)[m]
            if row["reference"] == "displacement":
                ref = df["dx_ref"].to_numpy(float)[m]
                ok = np.isfinite(ref)
                Xd.append(F[ok]); yd.append(ref[ok])
            if row["tip"] == "blocked":
                Xd.append(F); yd.append(np.zeros(len(F)))
            if row["reference"] == "force":
                ref = df["f_ref"].to_numpy(float)[m]
                ok = np.isfinite(ref)
                Xf.append(F[ok]); yf.append(ref[ok])
            if row["tip"] == "free":
                Xf.append(F); yf.append(np.zeros(len(F)))
        Xd, yd, Xf, yf = np.vstack(Xd), np.concatenate(yd), np.vstack(Xf), np.concatenate(yf)
        cd = _lstsq(Xd, yd)
        if self.regression == "approx":
            z = force_regressor(Xf[:, 0], Xf[:, 1], self.n_A_, self.C_p_)   # thesis eq. (52), second row
            cf = _lstsq(z[:, None], yf)
            cf = np.array(force_coefficients(float(cf[0] * self.n_A_), self.n_A_, self.C_p_))
        else:
            cf = _lstsq(Xf, yf)
        self.cd_, self.cf_ = cd, cf
        self.coef_ = {"A1": float(cd[0]), "A2": float(cd[1]), "B21": float(cf[0]), "B22": float(cf[1]),
                      "A3": float(cf[0] * self.n_A_)}
        return self

    def estimate(self, df: pd.DataFrame) -> pd.DataFrame:
        X = self._regressors(df)
        dx = tip_displacement(X[:, 0], X[:, 1], self.cd_[0], self.cd_[1])   # thesis eq. (52)
        f = tip_force(X[:, 0], X[:, 1], self.cf_[0], self.cf_[1])           # thesis eq. (46) / (52)
        relay = df["relay"].to_numpy() >= 0.5
        dx = np.where(relay, 0.0, dx)
        f = np.where(relay, 0.0, f)
        Q = df["q"].to_numpy(float)
        return pd.DataFrame({"t": df["t"].to_numpy(float), "dx_hat": dx, "f_hat": f, "dx_raw": dx, "f_raw": f,
                             "V_p": X[:, 1], "V_H": self.hysteresis_(Q), "q": Q})
