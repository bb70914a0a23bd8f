"""H(q) models that are linear in their parameters and can be fitted jointly on several calibration trials.

``RICreepH``: the one-sided rate-independent hysteresis model of ``002_7d89b7147aad52e4.txt`` (eqs. 8-11 with the
F polynomial (15) and the G trend surface (16)) plus Kuhnen's log(t)-type creep bank of
``000_18d138f03f1777c3.txt`` eqs. (38)-(41) (thresholds of eq. 61, eigenvalues of eq. 40) and a linear term::

    H(q) = RI[q] + w_K^T K_{r_K a_K}[q] i + c q

Every term is linear in its coefficients (the RI output is ``Phi(q) @ [b; p]``, see ``RIModel.regressor``), so the
whole model is identified by one linear least-squares problem over the stacked samples of *all* free-tip
calibration trials, each trial starting from the relaxed state that the relay establishes (thesis sec. 5.1.1).
The G surface is constrained to G(M, M) = 0 (continuous output at reversals). A relative ridge of 1e-8 on the
column-normalised design keeps the solve well posed when creep columns are nearly collinear.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from selfsense.hysteresis.operators import creep_operator, log_creep_eigenvalues
from selfsense.hysteresis.ri import RIModel, diagonal_constraint_basis

__all__ = ["RICreepH", "fit_ri_creep"]


class RICreepH:
    """H(q) = RI[q] + creep bank[q] + c q, evaluated from the relaxed state (q >= 0 required by the RI part)."""

    def __init__(self, ri: RIModel, r_K: Sequence[float], a_K: Sequence[float], w_K: Sequence[float], c: float,
                 dt: float):
        self.ri = ri
        self.r_K = np.asarray(r_K, dtype=float)
        self.a_K = np.asarray(a_K, dtype=float)
        self.w_K = np.asarray(w_K, dtype=float).reshape(len(self.r_K), len(self.a_K)) if len(self.r_K) else np.zeros((0, 0))
        self.c = float(c)
        self.dt = float(dt)

    def _creep(self, Q: np.ndarray) -> np.ndarray:
        if self.w_K.size == 0:
            return np.zeros_like(Q)
        K = creep_operator(Q, self.r_K, self.a_K, self.dt)  # (N, n, m), thesis eq. (39)
        return np.einsum("knm,nm->k", K, self.w_K)

    def __call__(self, Q) -> np.ndarray:
        Q = np.asarray(Q, dtype=float)
        return self.ri(np.maximum(Q, 0.0)) + self._creep(Q) + self.c * Q

    def to_dict(self) -> dict:
        return {"ri": self.ri.to_dict(), "r_K": self.r_K.tolist(), "a_K": self.a_K.tolist(),
                "w_K": self.w_K.ravel().tolist(), "c": self.c, "dt": self.dt}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "RICreepH":
        return cls(RIModel.from_dict(d["ri"]), d["r_K"], d["a_K"], d["w_K"], d["c"], d["dt"])


def _design(ri: RIModel, T: np.ndarray, Q: np.ndarray, r_K: np.ndarray, a_K: np.ndarray, dt: float) -> np.ndarray:
    Phi = ri.regressor(np.maximum(Q, 0.0))  # (N, 20): [b (5) | p (15)]
    cols = [Phi[:, :5], Phi[:, 5:] @ T]
    if len(r_K) and len(a_K):
        cols.append(creep_operator(Q, r_K, a_K, dt).reshape(len(Q), -1))
    cols.append(Q[:, None])
    return np.column_stack(cols)


def fit_ri_creep(segments: Sequence[tuple[np.ndarray, np.ndarray]], dt: float, n_thresholds: int = 8,
                 n_creep: int = 6, creep: bool = True, ridge: float = 1e-8) -> tuple[RICreepH, dict]:
    """Least-squares identification of :class:`RICreepH` on ``segments = [(Q, y), ...]`` (one per trial).

    Creep thresholds r_Ki = i / (n + 1) ||Q||_inf, i = 0..n-1 (thesis eq. 61) and eigenvalues
    a_j = 1 / (10^(j-1) T_s) (eq. 40). Returns the model and a report (RMS of the stacked residual [V]).
    """
    qmax = max(float(np.max(Q)) for Q, _ in segments)
    if not qmax > 0:
        raise ValueError("fit_ri_creep: the calibration charge never rises above 0")
    ri = RIModel(input_scale=qmax * 1.05)
    T = diagonal_constraint_basis()
    r_K = np.arange(n_thresholds) / (n_thresholds + 1) * qmax if creep and n_creep > 0 else np.zeros(0)
    a_K = log_creep_eigenvalues(n_creep, dt) if creep and n_creep > 0 else np.zeros(0)
    X = np.vstack([_design(ri, T, np.asarray(Q, float), r_K, a_K, dt) for Q, _ in segments])
    Y = np.concatenate([np.asarray(y, float) for _, y in segments])
    s = np.sqrt(np.mean(X**2, axis=0))
    s[s == 0] = 1.0
    A = X / s
    coef = np.linalg.solve(A.T @ A + ridge * len(Y) * np.eye(A.shape[1]), A.T @ Y) / s
    nb, nc = 5, T.shape[1]
    ri.b = coef[:nb].copy()
    ri.p = T @ coef[nb:nb + nc]
    nK = len(r_K) * len(a_K)
    w_K = coef[nb + nc:nb + nc + nK]
    model = RICreepH(ri, r_K, a_K, w_K, coef[-1], dt)
    resid = X @ coef - Y
    return model, {"rms_v_stacked": float(np.sqrt(np.mean(resid**2))), "n_segments": len(segments),
                   "n_parameters": int(X.shape[1]), "solver": "lstsq (ridge 1e-8)", "status": "optimal"}
