"""The load stage's stand-in force estimate: a fast, fixed-form self-sensing estimator (:class:`FastSensingEstimator`).

The stage-wise diagnostic's load stage compares the load cell with a *nominal* force estimate on every trial. That
estimate must not depend on the configured estimator's model selection (the stage's null thresholds were
calibrated with this fixed form on effect-free cases of four device families), and it is refitted for every
blind case, so it is one least-squares fit of a fixed form:

* H(q) on the free-tip calibration trial, thesis ``000_18d138f03f1777c3.txt`` eq. (55): target
  ``V_H = V - Q / (n_A C_p)``, model the registry's Preisach operator with electrical creep
  (:func:`fit_standin_h`: a density on the cells of a 16 x 16 grid of the (alpha, beta) plane, 10 plays, a relaxation
  bank; ridge least squares). It is also the blocked stage's H^(Q) (:mod:`selfsense.gap.stages`): at equal Q the
  blocked tip differs from the free one only in stress, so what H^ cannot carry from the free tip to the blocked one
  is model error that hides the stress. Measured on 24 effect-free devices of the four truth families (seed 8080, not
  a campaign seed): the blocked stage's held-out RMS was 2.9 % of V's RMS (median; 8.5 % largest) with the earlier
  play-and-superposition PI of 8 plays (thesis eqs. 29-35), 0.34 % (1.3 %) with this form;
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

from selfsense.io.rig import rig_value
from selfsense.sensing.core import (force_coefficients, force_regressor, h_target, piezo_voltage, tip_displacement,
                                    tip_force)
from selfsense.sensing.estimator import scaled_lstsq

__all__ = ["H_PARAMS", "fit_standin_h", "FastSensingEstimator", "rig_params"]


def rig_params(rig: Any) -> dict[str, float]:
    """n_A, C_p (one actuator), amplifier gain and shunt resistance from a ``selfsense.io.Rig`` or a rig.yaml
    mapping (read as the estimator reads the rig)."""
    return {"n_A": rig_value(rig, "n_actuators"), "C_p": rig_value(rig, "actuator_catalog", "capacitance_f"),
            "gain": rig_value(rig, "amplifier_gain"), "R": rig_value(rig, "shunt_resistance_ohm")}


#: the stand-in's H(q): the registry's Preisach form at the settings the pipeline selects on the bundled dataset
#: (cells of a 16 x 16 grid, 10 plays, ridge 1e-3, the relaxation bank of electrical creep)
H_PARAMS = {"n_grid": 16, "n_play": 10, "ridge": 1e-3, "creep": True}


def fit_standin_h(Q: np.ndarray, y: np.ndarray, dt: float):
    """The stand-in's H(Q) [V] fitted to ``y`` [V] over the charge ``Q`` [C] sampled every ``dt`` [s]:
    :class:`selfsense.hysteresis.models.PreisachH` with :data:`H_PARAMS` (Preisach density on the cells of a
    triangular grid over the calibration charge range, plays for the slope jump at a reversal, electrical creep),
    evaluated from the relaxed state on every trial."""
    from selfsense.hysteresis.models import PreisachH

    return PreisachH(**H_PARAMS).fit(np.asarray(Q, float), np.asarray(y, float), float(dt))


def _lstsq(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The estimator's column-scaled least squares, singular values below 1e-10 of the largest cut."""
    return scaled_lstsq(X, y, rcond=1e-10)


@dataclass
class FastSensingEstimator:
    """The stand-in estimator: ``fit(trials, meta)`` on the calibration trials, ``estimate(df)`` on any trial."""

    rig: Any
    regression: str = "approx"

    hysteresis_: Any = field(default=None, init=False, repr=False)
    coef_: dict = field(default_factory=dict, init=False)

    def _regressors(self, df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
        """``[Q, V_p]`` (thesis eq. 27) and ``H(Q)``: the Preisach grid evaluated once per trial."""
        Q = df["q"].to_numpy(float)
        H = self.hysteresis_(Q)
        return np.column_stack([Q, piezo_voltage(df["V"].to_numpy(float), H)]), H

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
        Q = d["q"].to_numpy(float)[act]
        y = h_target(d["V"].to_numpy(float)[act], Q, 1.0 / (self.n_A_ * self.C_p_))   # thesis eq. (55)
        self.hysteresis_ = fit_standin_h(Q, y, float(np.median(np.diff(d["t"].to_numpy(float)))))
        Xd, yd, Xf, yf = [], [], [], []
        for tid, row in cal.to_dict("index").items():
            df = trials[tid]
            m = df["relay"].to_numpy() < 0.5
            F = self._regressors(df)[0][m]
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
        X, H = self._regressors(df)
        dx = tip_displacement(X[:, 0], X[:, 1], self.cd_[0], self.cd_[1])   # thesis eq. (52)
        f = tip_force(X[:, 0], X[:, 1], self.cf_[0], self.cf_[1])           # thesis eq. (46) / (52)
        relay = df["relay"].to_numpy() >= 0.5
        dx, f = np.where(relay, 0.0, dx), np.where(relay, 0.0, f)
        return pd.DataFrame({"t": df["t"].to_numpy(float), "dx_hat": dx, "f_hat": f, "dx_raw": dx, "f_raw": f,
                             "V_p": X[:, 1], "V_H": H, "q": X[:, 0]})
