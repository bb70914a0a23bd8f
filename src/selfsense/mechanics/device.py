"""Whole-tweezer static mechanics: n_A Goldfarb-Celanovic actuators + mechanism (S1, S2, S3).

Seeds: thesis ``000_18d138f03f1777c3.txt`` sec. 3.1 (0.1 N blocked / 7 mm free at 150 V),
Table 1 (Cedrat MLA 2510 catalog, per actuator), eqs. (21), (24)-(27), (44)-(46);
paper ``001_972cacfaa08ad91a.txt`` Table I (alpha = 2.35 N/V, C_p = 0.3 uF,
dx_pzt_free = 10 um, dx_tip_free = 6.3 mm, B = 1.59e-3).

Sign conventions: docs/dev/CONTRACTS.md (dx_tip closing of both arms, positive when actuators
expand; f_tip pinch-positive; q TOTAL charge of the n_A actuators). Mechanism stiffness
``K = [[S1, S3], [S3, S2]]`` (PSD) relates the forces applied ON the mechanism to
``[x_pzt, dx_tip]``; S3 < 0. See :mod:`selfsense.mechanics.piezo`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from . import piezo

__all__ = ["TweezerMechanics", "default_tweezer_mechanics", "mechanism_from_targets"]


def mechanism_from_targets(dx_tip_free: float, f_tip_block: float, dx_pzt_free: float, Vp: float,
                           alpha: float, k: float, n_A: int) -> tuple[float, float, float]:
    """Unique (S1, S2, S3) [N/m] giving the requested free stroke, blocked force and free
    PZT displacement at ``V_p = Vp`` (closed-form inversion of :func:`piezo.static_response`).

    With ``G = n_A alpha Vp``, ``B = dx_pzt_free/dx_tip_free``:
    ``-S3 = f_b G / (G dx_pzt_free - f_b dx_tip_free)``, ``S2 = -B S3`` (paper eq. 18),
    ``S1 = (G - S3 dx_tip_free)/dx_pzt_free - n_A k``. Raises ``ValueError`` if the result
    is not a passive (PSD, S3 < 0) mechanism.
    """
    G = n_A * alpha * Vp
    den = G * dx_pzt_free - f_tip_block * dx_tip_free
    if den <= 0:
        raise ValueError("targets infeasible: f_tip_block * dx_tip_free >= n_A alpha Vp dx_pzt_free "
                         "(the mechanism would have to deliver more work than the actuators)")
    S3 = -f_tip_block * G / den
    S2 = -S3 * dx_pzt_free / dx_tip_free
    S1 = (G - S3 * dx_tip_free) / dx_pzt_free - n_A * k
    if not (S1 > 0 and S2 > 0 and S1 * S2 - S3 * S3 >= 0):
        raise ValueError(f"targets give a non-passive mechanism S=({S1:.4g}, {S2:.4g}, {S3:.4g}); "
                         "dx_pzt_free too large for these alpha, k")
    return float(S1), float(S2), float(S3)


@dataclass(frozen=True)
class TweezerMechanics:
    """Static model of the tweezer: per-actuator piezo constants + mechanism stiffness.

    Fields (SI): ``n_A`` actuators; ``alpha`` [N/V], ``Cp`` [F], ``k`` [N/m] per actuator;
    ``S1, S2, S3`` [N/m] mechanism stiffness (PSD convention, S3 < 0); ``V_max`` [V];
    catalog values for reference (thesis Table 1): ``catalog_free_disp`` [m],
    ``catalog_blocked_force`` [N], ``catalog_capacitance`` [F].
    """

    S1: float
    S2: float
    S3: float
    n_A: int = 5
    alpha: float = 2.35
    Cp: float = 0.3e-6
    k: float = 24e6
    V_max: float = 150.0
    catalog_free_disp: float = 10e-6
    catalog_blocked_force: float = 240.0
    catalog_capacitance: float = 0.25e-6

    def __post_init__(self):
        K = self.stiffness_matrix()
        ev = np.linalg.eigvalsh(K)
        if ev.min() < -1e-12 * abs(ev).max():
            raise ValueError(f"mechanism stiffness not PSD: eigenvalues {ev}")
        if self.S3 >= 0:
            raise ValueError("S3 must be < 0 (tip closes when actuators expand)")

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_targets(cls, dx_tip_free=6.3e-3, f_tip_block=0.1, dx_pzt_free=10e-6, Vp=150.0,
                     n_A=5, alpha=2.35, Cp=0.3e-6, k=24e6, **kw) -> "TweezerMechanics":
        S = mechanism_from_targets(dx_tip_free, f_tip_block, dx_pzt_free, Vp, alpha, k, n_A)
        return cls(*S, n_A=n_A, alpha=alpha, Cp=Cp, k=k, V_max=Vp, **kw)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TweezerMechanics":
        return cls(**d)

    # ---------------------------------------------------------------- matrices
    @property
    def _p(self):
        return (self.S1, self.S2, self.S3, self.alpha, self.Cp, self.k, self.n_A)

    def stiffness_matrix(self) -> np.ndarray:
        return np.array([[self.S1, self.S3], [self.S3, self.S2]], dtype=float)

    @property
    def Cp_total(self) -> float:
        """n_A C_p [F] (docs/dev/CONTRACTS.md H(q) convention)."""
        return self.n_A * self.Cp

    def tip_matrix(self, convention: str = "contract") -> np.ndarray:
        """Exact eq. (45) ``[dx_tip, f_tip] = M [q_total, V_p]`` (contract signs by default)."""
        return piezo.tip_matrix(*self._p, convention=convention)

    def a_coefficients(self) -> dict:
        return piezo.a_coefficients(*self._p)

    # ---------------------------------------------------------------- solves
    def solve(self, Vp, *, k_env: float = 0.0, gap: float = 0.0, blocked: bool = False) -> dict:
        """Equilibrium for ``V_p`` [V] (array) and tip environment.

        ``k_env=0``: free tip; ``blocked=True``: dx_tip = 0; otherwise a linear spring of
        stiffness ``k_env`` [N/m] (``np.inf`` = rigid) engaged after a closing ``gap`` [m]:
        ``f_tip = k_env * max(dx_tip - gap, 0)`` (k_env, gap may be arrays). Returns arrays ``x_pzt`` [m per actuator],
        ``dx_tip`` [m], ``f_tip`` [N], ``q`` [C total], ``F_in`` [N total PZT force].
        """
        return piezo.static_response(*self._p, Vp, k_env=k_env, gap=gap, blocked=blocked)

    def free(self, Vp) -> dict:
        return self.solve(Vp)

    def blocked(self, Vp) -> dict:
        return self.solve(Vp, blocked=True)

    def sense(self, q, Vp) -> tuple[np.ndarray, np.ndarray]:
        """Exact self-sensing map (eq. 45): total charge q [C], V_p [V] -> (dx_tip, f_tip)."""
        M = self.tip_matrix("contract")
        q = np.asarray(q, dtype=float)
        Vp = np.asarray(Vp, dtype=float)
        return M[0, 0] * q + M[0, 1] * Vp, M[1, 0] * q + M[1, 1] * Vp

    def free_blocked(self, Vp=None) -> dict:
        return piezo.free_blocked_response(*self._p, self.V_max if Vp is None else Vp)

    def onsite_parameters(self, Vp=None) -> dict:
        """Paper eq. (20)-(23) quantities of this device at V_p (default V_max):
        ``B``, per-actuator ``A_q`` [m/C], ``h_slope`` [V/C, per-actuator charge]."""
        fr = self.free(self.V_max if Vp is None else Vp)
        B = float(piezo.onsite_B(fr["x_pzt"], fr["dx_tip"]))
        A_q = float(piezo.onsite_A_q(fr["dx_tip"], fr["q"] / self.n_A))
        return dict(B=B, A_q=A_q, alpha_B_A_q=self.alpha * B * A_q,
                    h_slope=float(piezo.onsite_h_slope(self.alpha, B, A_q, self.Cp)))


def default_tweezer_mechanics() -> TweezerMechanics:
    """Default device: paper Table I (alpha 2.35 N/V, C_p 0.3 uF, dx_pzt_free 10 um,
    dx_tip_free 6.3 mm), thesis 0.1 N blocked tip force, catalog k = 24 N/um, n_A = 5,
    all at V_p = 150 V."""
    return TweezerMechanics.from_targets()
