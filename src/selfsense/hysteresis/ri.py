"""One-sided rate-independent (RI) hysteresis model.

Seed: ``002_7d89b7147aad52e4.txt`` (RI paper), Sect. 2 eqs. (1)-(11) and Sect. 4.3 eqs. (15)-(16).

The output for a non-negative input u(t) is, with the historical extrema that are not wiped out
``0 = m0 < m1 < ... < m_n < M_n < ... < M1 = M_max``,

* rising input (eq. 10):  f = F(M_max) - sum_{k=1}^{n-1}[G(M_k, m_k) - G(M_{k+1}, m_k)] - [G(M_n, m_n) - G(u, m_n)]
* falling input (eq. 11): f = F(M_max) - sum_{k=1}^{n-1}[G(M_k, m_k) - G(M_{k+1}, m_k)] - G(M_n, u)
* no reversal yet: f = F(u), the initial ascending curve (eq. 8).

F(M) is the quartic (15), G(M, m) the quartic trend surface (16). Modified wiping-out rule (Sect. 2): a rising
input that passes M_n wipes (M_n, m_n); a falling input that passes m_{n-1} wipes (M_n, m_{n-1}); m0 = 0 is never
wiped (u >= 0) and M_max is only ever replaced by a larger maximum, after which the output continues on F(u).
The initial ascending curve is therefore not part of any later loop, and minor loops between the same extrema are
congruent (their shape depends only on G).

Units: the model works on the scaled input ``u = (x - input_offset) / input_scale`` (dimensionless, must be >= 0);
``b`` and ``p`` are coefficients in u and carry the unit of the output y (e.g. m, T or V). With
``input_scale=1, input_offset=0`` the coefficients are those of the paper (u in V).

Defaults that differ from the paper (documented in docs/ri_model.md): the G surface is by default fitted with the
constraint G(M, M) = 0 (``constrain_diagonal=True``), which makes the output continuous at every reversal; the
paper's unconstrained 15-term surface is available with ``constrain_diagonal=False``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from . import _ri_kernels as K

__all__ = ["RIModel", "RIState", "ri_reference", "F_reference", "G_reference", "G_MONOMIALS",
           "diagonal_constraint_basis"]

#: exponents (M, m) of the 15 monomials of eq. (16), order p1..p15
G_MONOMIALS: tuple[tuple[int, int], ...] = (
    (0, 0), (0, 1), (1, 0), (0, 2), (1, 1), (2, 0), (0, 3), (1, 2), (2, 1), (3, 0),
    (0, 4), (1, 3), (2, 2), (3, 1), (4, 0),
)


def F_reference(b, M: float) -> float:
    """Eq. (15), plain Python."""
    return sum(float(b[i]) * M ** i for i in range(5))


def G_reference(p, M: float, m: float) -> float:
    """Eq. (16), plain Python, monomials in the order of ``G_MONOMIALS``."""
    return sum(float(p[i]) * M ** a * m ** c for i, (a, c) in enumerate(G_MONOMIALS))


def diagonal_constraint_basis() -> np.ndarray:
    """T (15 x 10) with p = T @ c spanning exactly the quartic surfaces with G(M, M) = 0.

    Such a surface is (M - m) * C(M, m) with C a full cubic (10 terms); column j of T is the expansion of
    (M - m) * M^a m^c for the j-th cubic monomial (a + c <= 3).
    """
    index = {e: i for i, e in enumerate(G_MONOMIALS)}
    cubic = [(a, d - a) for d in range(4) for a in range(d, -1, -1)]
    T = np.zeros((15, len(cubic)))
    for j, (a, c) in enumerate(cubic):
        T[index[(a + 1, c)], j] += 1.0
        T[index[(a, c + 1)], j] -= 1.0
    return T


def ri_reference(u, b, p, extrema=None, u_prev: float = 0.0):
    """Readable pure-Python RI model (eqs. 8, 10, 11 and the modified wiping-out rule).

    ``extrema`` is the alternating list [m0=0, M1, m1, M2, ...] (default: virgin, [0.0]).
    Returns (y, extrema, u_prev). Used by the tests to check the numba kernel.
    """
    E = [0.0] if extrema is None else [float(v) for v in extrema]
    y = []
    for ut in (float(v) for v in u):
        if ut < 0:
            raise ValueError("ri_reference: negative input")
        rising = len(E) % 2 == 1
        if rising and ut < u_prev:
            E.append(u_prev)  # a new local maximum
        elif not rising and ut > u_prev:
            E.append(u_prev)  # a new local minimum
        if len(E) % 2 == 1:
            while len(E) >= 3 and ut >= E[-2]:
                del E[-2:]
        else:
            while len(E) >= 4 and ut <= E[-2]:
                del E[-2:]
        u_prev = ut
        if len(E) == 1:
            y.append(F_reference(b, ut))
            continue
        Ms = E[1::2]  # M1, M2, ...
        ms = E[2::2]  # m1, m2, ...
        out = F_reference(b, Ms[0])
        if len(E) % 2 == 1:  # rising, eq. (10): n = len(Ms) = len(ms)
            n = len(Ms)
            for k in range(1, n):
                out -= G_reference(p, Ms[k - 1], ms[k - 1]) - G_reference(p, Ms[k], ms[k - 1])
            out -= G_reference(p, Ms[n - 1], ms[n - 1]) - G_reference(p, ut, ms[n - 1])
        else:  # falling, eq. (11): n = len(Ms), len(ms) = n - 1
            n = len(Ms)
            for k in range(1, n):
                out -= G_reference(p, Ms[k - 1], ms[k - 1]) - G_reference(p, Ms[k], ms[k - 1])
            out -= G_reference(p, Ms[n - 1], ut)
        y.append(out)
    return np.asarray(y, dtype=float), E, u_prev


@dataclass
class RIState:
    """Memory of the RI model between calls of ``RIModel.apply`` (streaming).

    ``extrema``: alternating extrema [m0=0, M1, m1, ...] in scaled input units; ``prefix``: the stored prefix sums
    of eqs. (10)/(11) at the same indices (output units); ``u_prev``: last scaled input.
    """

    extrema: np.ndarray = field(default_factory=lambda: np.zeros(1))
    prefix: np.ndarray = field(default_factory=lambda: np.zeros(1))
    u_prev: float = 0.0

    @property
    def virgin(self) -> bool:
        """True while the input has only moved along the initial ascending curve."""
        return self.extrema.shape[0] == 1

    @property
    def M_max(self) -> float:
        """Largest historical maximum (scaled input units)."""
        return float(self.extrema[1]) if self.extrema.shape[0] > 1 else float(self.u_prev)


class RIModel:
    """One-sided RI hysteresis model, ``002_7d89b7147aad52e4.txt`` eqs. (8)-(11), (15), (16).

    Parameters
    ----------
    b : 5 coefficients of F (eq. 15), output units, in the scaled input u.
    p : 15 coefficients of G (eq. 16, order p1..p15), output units.
    input_scale, input_offset : affine input map u = (x - input_offset) / input_scale. ``input_scale=None``
        means "set by ``fit`` to max(x - input_offset) of the training data" (u in [0, 1]); e.g. with x = charge q
        [C] (1e-5 C scale) this keeps the polynomials well conditioned.
    negative_tol : inputs with -negative_tol <= u < 0 are clipped to 0 (noise around zero); anything lower raises
        ``ValueError``. Default 0 (strict).
    max_depth : capacity of the fixed-size extrema stack of the numba kernel.

    Typical use as the H(q) of a self-sensing pipeline: ``H = RIModel().fit(q, V_H); V_H_hat = H(q)``.
    """

    def __init__(self, b=None, p=None, input_scale: float | None = None, input_offset: float = 0.0,
                 negative_tol: float = 0.0, max_depth: int = 1024):
        self.b = np.zeros(5) if b is None else np.asarray(b, dtype=float).copy()
        self.p = np.zeros(15) if p is None else np.asarray(p, dtype=float).copy()
        if self.b.shape != (5,) or self.p.shape != (15,):
            raise ValueError(f"RIModel: b must have 5 and p 15 coefficients, got {self.b.shape}, {self.p.shape}")
        if input_scale is not None and not (np.isfinite(input_scale) and input_scale > 0):
            raise ValueError(f"RIModel: input_scale must be a positive finite number, got {input_scale!r}")
        self.input_scale = None if input_scale is None else float(input_scale)
        self.input_offset = float(input_offset)
        self.negative_tol = float(negative_tol)
        self.max_depth = int(max_depth)
        self.fit_info: dict = {}

    # ------------------------------------------------------------------ input handling
    def scale_input(self, x) -> np.ndarray:
        """u = (x - input_offset) / input_scale, checked non-negative (one-sided model)."""
        x = np.asarray(x, dtype=float)
        if x.ndim != 1:
            raise ValueError(f"RIModel: input must be a 1-D array, got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("RIModel: input contains NaN or inf")
        scale = 1.0 if self.input_scale is None else self.input_scale
        u = (x - self.input_offset) / scale
        if u.size and u.min() < 0.0:
            i = int(np.argmin(u))
            if u[i] < -self.negative_tol:
                raise ValueError(
                    "RIModel: input must be non-negative (one-sided hysteresis, 002_7d89b7147aad52e4.txt Sect. 2: "
                    f"u = (x - {self.input_offset:g}) / {scale:g} >= 0); got x[{i}] = {x[i]:.6g} -> u = {u[i]:.6g}. "
                    "Shift the input with input_offset or allow small noise with negative_tol.")
            u = np.maximum(u, 0.0)
        return np.ascontiguousarray(u)

    # ------------------------------------------------------------------ evaluation
    def new_state(self) -> RIState:
        """Virgin state: no reversal yet, the next rise follows the initial ascending curve F."""
        return RIState()

    def _buffers(self, state: RIState):
        cap = max(self.max_depth, state.extrema.shape[0] + 2)
        E = np.zeros(cap)
        P = np.zeros(cap)
        L = state.extrema.shape[0]
        E[:L] = state.extrema
        P[:L] = state.prefix[:L]
        return E, P, L

    def apply(self, x, state: RIState | None = None) -> tuple[np.ndarray, RIState]:
        """Streaming evaluation: returns (y, state_after). ``apply(x1)`` then ``apply(x2, state)`` equals ``self(x1 ++ x2)``."""
        u = self.scale_input(x)
        state = self.new_state() if state is None else state
        E, P, L = self._buffers(state)
        y, L, u_prev, err = K.ri_eval_kernel(u, self.b, self.p, E, P, L, float(state.u_prev))
        if err:
            raise ValueError(f"RIModel: extrema stack overflow (max_depth={self.max_depth}); "
                             "increase max_depth or low-pass the input to remove nested micro-reversals")
        return y, RIState(E[:L].copy(), P[:L].copy(), float(u_prev))

    def __call__(self, x, state: RIState | None = None) -> np.ndarray:
        return self.apply(x, state)[0]

    def state_after(self, x_history, state: RIState | None = None) -> RIState:
        """Memory after the input history ``x_history`` (e.g. a preconditioning cycle 0 -> x_max -> 0)."""
        return self.apply(x_history, state)[1]

    def F(self, M) -> np.ndarray:
        """Eq. (15) at scaled maxima M."""
        M = np.asarray(M, dtype=float)
        return np.polynomial.polynomial.polyval(M, self.b)

    def G(self, M, m) -> np.ndarray:
        """Eq. (16) at scaled (M, m)."""
        M, m = np.broadcast_arrays(np.asarray(M, float), np.asarray(m, float))
        return sum(self.p[i] * M ** a * m ** c for i, (a, c) in enumerate(G_MONOMIALS))

    # ------------------------------------------------------------------ identification
    def regressor(self, x, state: RIState | None = None) -> np.ndarray:
        """Phi (N x 20) with self(x) == Phi @ concat(b, p) (the model is linear in its coefficients)."""
        u = self.scale_input(x)
        state = self.new_state() if state is None else state
        cap = max(self.max_depth, state.extrema.shape[0] + 2)
        E = np.zeros(cap)
        P = np.zeros(cap)
        PV = np.zeros((cap, K.N_G))
        L = state.extrema.shape[0]
        E[:L] = state.extrema
        if L > 1:  # rebuild the vector prefix sums of the given history
            Ms, ms = state.extrema[1::2], state.extrema[2::2]
            acc = np.zeros(K.N_G)
            for k in range(1, len(Ms)):
                acc = acc + (_gvec(Ms[k - 1], ms[k - 1]) - _gvec(Ms[k], ms[k - 1]))
                PV[2 * k + 1] = acc
        Phi, L, _, err = K.ri_regressor_kernel(u, E, P, PV, L, float(state.u_prev))
        if err:
            raise ValueError(f"RIModel: extrema stack overflow (max_depth={self.max_depth})")
        return Phi

    def fit(self, x, y, state: RIState | None = None, constrain_diagonal: bool = True,
            ridge: float = 0.0, smooth: float = 0.0, x_history=None) -> "RIModel":
        """Identify F (eq. 15) and G (eq. 16) by linear least squares from arbitrary one-sided data.

        Every sample lies on a branch fixed by its reversal history (M, m); eqs. (10)/(11) are linear in
        (b, p), so all branches are fitted at once: y ~= Phi(x) @ [b; p] (see ``regressor``). With
        ``constrain_diagonal`` p = T c with G(M, M) = 0 (continuous output at reversals).
        ``x_history`` (optional) is an input history applied before x (e.g. the preconditioning cycle of a
        magnet); it sets the memory but its outputs are not fitted. ``smooth`` weights the regularisation of
        ``smoothness_rows`` (Masing-like G plus a little bending energy; relative to the mean squared residual,
        with u in [0, 1]); ``ridge`` adds Tikhonov regularisation on the column-normalised coefficients.
        ``smooth = ridge = 0`` (default) is plain least squares as in the paper (minimum-norm if rank deficient).
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if x.shape != y.shape or x.ndim != 1:
            raise ValueError(f"RIModel.fit: x and y must be 1-D of equal length, got {x.shape} and {y.shape}")
        if self.input_scale is None:
            span = float(np.max(x) - self.input_offset)
            if x_history is not None:
                span = max(span, float(np.max(np.asarray(x_history, float)) - self.input_offset))
            self.input_scale = span if span > 0 else 1.0
        if x_history is not None:
            state = self.state_after(x_history, state)
        Phi = self.regressor(x, state)
        u_max = float(max(np.max(self.scale_input(x)), state.M_max if state is not None else 0.0, 1e-12))
        coef = solve_ls(Phi, y, constrain_diagonal=constrain_diagonal, ridge=ridge, smooth=smooth, u_max=u_max)
        self.b, self.p = coef[:5].copy(), coef[5:].copy()
        resid = y - Phi @ coef
        rng = float(np.ptp(y)) if y.size else 1.0
        self.fit_info = {"method": "regression over all reversal branches (eqs. 10-11 linear in b, p)",
                         "n_samples": int(y.size), "constrain_diagonal": bool(constrain_diagonal),
                         "smooth": float(smooth), "ridge": float(ridge),
                         "rms_pct": float(100 * np.sqrt(np.mean(resid ** 2)) / rng) if rng > 0 else 0.0,
                         "max_pct": float(100 * np.max(np.abs(resid)) / rng) if rng > 0 else 0.0}
        return self

    def fit_protocol(self, records, m_step: float | None = None, constrain_diagonal: bool = True) -> "RIModel":
        """Identify F and G with the paper's protocol (Sect. 4.3); see ``ri_identify.fit_protocol``."""
        from .ri_identify import fit_protocol
        fitted = fit_protocol(records, m_step=m_step, constrain_diagonal=constrain_diagonal,
                              input_scale=self.input_scale, input_offset=self.input_offset)
        self.b, self.p, self.input_scale = fitted.b, fitted.p, fitted.input_scale
        self.fit_info = fitted.fit_info
        return self

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        return {"model": "RIModel", "version": 1, "seed": "002_7d89b7147aad52e4.txt eqs. (10),(11),(15),(16)",
                "b": [float(v) for v in self.b], "p": [float(v) for v in self.p],
                "input_scale": self.input_scale, "input_offset": self.input_offset,
                "negative_tol": self.negative_tol, "max_depth": self.max_depth}

    @classmethod
    def from_dict(cls, d: dict) -> "RIModel":
        if d.get("model") != "RIModel":
            raise ValueError(f"RIModel.from_dict: not an RIModel dict (model={d.get('model')!r})")
        return cls(b=d["b"], p=d["p"], input_scale=d.get("input_scale"), input_offset=d.get("input_offset", 0.0),
                   negative_tol=d.get("negative_tol", 0.0), max_depth=d.get("max_depth", 1024))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_json(cls, s: str) -> "RIModel":
        return cls.from_dict(json.loads(s))

    def __repr__(self) -> str:
        return f"RIModel(b={self.b.tolist()}, p=<15>, input_scale={self.input_scale}, input_offset={self.input_offset})"


def _gvec(M: float, m: float) -> np.ndarray:
    out = np.empty(K.N_G)
    K.G_basis(float(M), float(m), out)
    return out


def smoothness_rows(u_max: float = 1.0, n_grid: int = 21, thin_plate: float = 1e-3) -> np.ndarray:
    """Rows R (n x 20) of the regularisation used by ``fit(..., smooth=...)``; |R c|^2 is the mean over the triangle
    0 <= m <= M <= u_max of

    * (G_M + G_m)^2 - zero for a Masing / Prandtl-Ishlinskii-like surface G = g(M - m): the loop between two extrema
      is shaped by their distance only;
    * ``thin_plate`` * (G_MM^2 + 2 G_Mm^2 + G_mm^2) - thin-plate bending energy of G;
    * the mean of F''^2 over [0, u_max] (F only seen at a single M_max is then extrapolated as a straight line).

    It fixes the parts of F and G that the data do not determine (e.g. the interior of the (M, m) triangle when only a
    major loop was measured). It is not in the RI paper, which identifies F and G from a full grid of reversal data.
    """
    g = np.linspace(0.0, u_max, n_grid)
    MM, mm = np.meshgrid(g, g, indexing="ij")
    sel = mm <= MM
    M, m = MM[sel], mm[sel]
    w = 1.0 / np.sqrt(M.size)

    def d(a, c, da, dc):  # derivative d^(da+dc) / dM^da dm^dc of M^a m^c
        if a < da or c < dc:
            return np.zeros_like(M)
        ka = float(np.prod(np.arange(a, a - da, -1))) if da else 1.0
        kc = float(np.prod(np.arange(c, c - dc, -1))) if dc else 1.0
        return ka * kc * M ** (a - da) * m ** (c - dc)

    rows = []
    R = np.zeros((M.size, 20))
    for i, (a, c) in enumerate(G_MONOMIALS):
        R[:, 5 + i] = w * (d(a, c, 1, 0) + d(a, c, 0, 1))
    rows.append(R)
    for da, dc, f in ((2, 0, 1.0), (1, 1, 2.0), (0, 2, 1.0)):
        R = np.zeros((M.size, 20))
        for i, (a, c) in enumerate(G_MONOMIALS):
            R[:, 5 + i] = np.sqrt(thin_plate * f) * w * d(a, c, da, dc)
        rows.append(R)
    RF = np.zeros((n_grid, 20))
    for i in range(2, 5):
        RF[:, i] = i * (i - 1) * g ** (i - 2) / np.sqrt(n_grid)
    rows.append(RF)
    return np.vstack(rows)


def solve_ls(Phi: np.ndarray, y: np.ndarray, constrain_diagonal: bool = True, ridge: float = 0.0,
             smooth: float = 0.0, u_max: float = 1.0) -> np.ndarray:
    """Least squares for [b; p] (20) with column normalisation.

    Minimises  mean((Phi c - y)^2) + smooth * (bending energy of G and F, ``smoothness_rows``) + ridge * |c_n|^2
    (c_n: column-normalised coefficients), optionally with p restricted to G(M, M) = 0.
    """
    if constrain_diagonal:
        T = np.zeros((20, 15))
        T[:5, :5] = np.eye(5)
        T[5:, 5:] = diagonal_constraint_basis()
    else:
        T = np.eye(20)
    N = max(Phi.shape[0], 1)
    A = Phi @ T / np.sqrt(N)
    yy = np.asarray(y, float) / np.sqrt(N)
    if smooth > 0:
        A = np.vstack([A, np.sqrt(smooth) * (smoothness_rows(u_max) @ T)])
        yy = np.concatenate([yy, np.zeros(A.shape[0] - yy.size)])
    norms = np.sqrt(np.sum(A ** 2, axis=0))
    keep = norms > 0
    As = A[:, keep] / norms[keep]
    if ridge > 0:
        As = np.vstack([As, np.sqrt(ridge) * np.eye(As.shape[1])])
        yy = np.concatenate([yy, np.zeros(As.shape[1])])
    sol, *_ = np.linalg.lstsq(As, yy, rcond=1e-13)
    c = np.zeros(A.shape[1])
    c[keep] = sol / norms[keep]
    return T @ c
