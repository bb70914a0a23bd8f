"""Modified Prandtl-Ishlinskii operator with log(t) creep and its exact inverse.

Seed: ``000_18d138f03f1777c3.txt`` eqs. (36), (41), (42); inverse superposition eqs. (79)-(80).

    Gamma[x] = w_S^T S_{r_S}[ w_H^T H_{r_H}[x, z_H0] + w_K^T K_{r_K a_K}[x, Z_K0] i + offset ]

x in its own unit (e.g. charge [C]); the intermediate u = H[x] + K[x] + offset is in x's unit when the
model comes from ``fit_modified_pi`` (gauge fixed by eqs. 76-78); y in the output unit (e.g. V_H [V]).
``offset`` is an optional additive constant inside the superposition (0 in the thesis).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _kernels
from .operators import log_creep_eigenvalues


def _arr(v, shape=None) -> np.ndarray:
    a = np.array(v, dtype=float)
    if shape is not None:
        a = np.array(np.broadcast_to(a, shape), dtype=float)
    return np.ascontiguousarray(a)


def superposition_slopes(r, w):
    """Slopes of y = sum_i w_i S_{r_i}[u] on its linear pieces.

    Returns (pos_r, pos_slopes, neg_r, neg_slopes, s0): s0 slope on the piece containing 0; pos_slopes[k] the
    slope for u > pos_r[k] (pos_r ascending); neg_slopes[k] the slope for u < neg_r[k] (neg_r descending).
    """
    r = np.asarray(r, float)
    w = np.asarray(w, float)
    s0 = float(w[r == 0].sum())
    ip = np.where(r > 0)[0]
    ip = ip[np.argsort(r[ip], kind="stable")]
    ineg = np.where(r < 0)[0]
    ineg = ineg[np.argsort(-r[ineg], kind="stable")]
    return r[ip], s0 + np.cumsum(w[ip]), r[ineg], s0 + np.cumsum(w[ineg]), s0


def invert_superposition(r, w):
    """Inverse of a strictly increasing superposition sum, eqs. (79)-(80) generalised to both sides of 0.

    S(u) = sum_i w_i S_{r_i}[u] with one r = 0 (identity) term. Returns (r_inv, w_inv) with S^{-1} in the same
    form: breakpoints r_inv_i = S(r_i) (eq. 80), w_inv_0 = 1/w_0 and w_inv_i = 1/s_i - 1/s_{i-1}
    = -w_i / (s_i s_{i-1}) (eq. 79), s_i the slope beyond the i-th breakpoint counted from 0 outwards.
    """
    r = np.asarray(r, float)
    w = np.asarray(w, float)
    if np.count_nonzero(r == 0) != 1:
        raise ValueError("superposition needs exactly one threshold r = 0 (the identity term)")
    pr, ps, nr, ns, s0 = superposition_slopes(r, w)
    if s0 <= 0 or np.any(ps <= 0) or np.any(ns <= 0):
        raise ValueError("superposition operator is not strictly increasing; it has no inverse")

    def S(u):
        out = s0 * u
        for ri, wi in zip(r, w):
            if ri > 0:
                out += wi * max(u - ri, 0.0)
            elif ri < 0:
                out += wi * min(u - ri, 0.0)
        return out

    r_inv = [0.0]
    w_inv = [1.0 / s0]
    for rr, ss in ((pr, ps), (nr, ns)):
        prev = s0
        for ri, si in zip(rr, ss):
            r_inv.append(S(ri))
            w_inv.append(1.0 / si - 1.0 / prev)
            prev = si
    return np.array(r_inv), np.array(w_inv)


@dataclass
class PIState:
    """Streaming state: play states p (n_H,), creep states c (n_K, m), last input x_last (NaN = none yet)."""

    p: np.ndarray
    c: np.ndarray
    x_last: float = float("nan")

    def copy(self) -> "PIState":
        return PIState(self.p.copy(), self.c.copy(), float(self.x_last))


@dataclass
class ModifiedPI:
    """Modified Prandtl-Ishlinskii operator with creep, ``000_18d138f03f1777c3.txt`` eq. (42).

    Parameters (x unit = [x], y unit = [y]): r_H, w_H, z_H0 play thresholds [x], weights [-] and initial states
    [x] (eqs. 29-32); r_K [x], w_K (n_K,), a_K [1/s] (m,), Z_K0 (n_K, m) creep operator (eqs. 39-41);
    r_S [u], w_S superposition thresholds and weights (eq. 35; exactly one r_S = 0); dt [s]; offset [u].
    """

    r_H: np.ndarray
    w_H: np.ndarray
    r_S: np.ndarray
    w_S: np.ndarray
    dt: float
    z_H0: np.ndarray | None = None
    r_K: np.ndarray = field(default_factory=lambda: np.zeros(0))
    w_K: np.ndarray = field(default_factory=lambda: np.zeros(0))
    a_K: np.ndarray = field(default_factory=lambda: np.zeros(0))
    Z_K0: np.ndarray | None = None
    offset: float = 0.0

    def __post_init__(self):
        self.r_H = _arr(self.r_H)
        self.w_H = _arr(self.w_H, self.r_H.shape)
        self.z_H0 = _arr(0.0 if self.z_H0 is None else self.z_H0, self.r_H.shape)
        self.r_K = _arr(self.r_K)
        self.w_K = _arr(self.w_K, self.r_K.shape)
        self.a_K = _arr(self.a_K)
        shape = (len(self.r_K), len(self.a_K))
        self.Z_K0 = _arr(0.0 if self.Z_K0 is None else self.Z_K0, shape)
        self.r_S = _arr(self.r_S)
        self.w_S = _arr(self.w_S, self.r_S.shape)
        self.dt = float(self.dt)
        self.offset = float(self.offset)
        if self.dt <= 0:
            raise ValueError("dt must be > 0")
        if np.any(self.r_H < 0) or np.any(self.r_K < 0) or np.any(self.a_K <= 0):
            raise ValueError("play/creep thresholds must be >= 0, creep eigenvalues > 0")
        if np.count_nonzero(self.r_S == 0) != 1:
            raise ValueError("r_S needs exactly one zero threshold (identity term, eq. 35)")
        self._prepare()

    @classmethod
    def with_log_creep(cls, r_H, w_H, r_S, w_S, dt, r_K, w_K, m, **kw) -> "ModifiedPI":
        """Build with the log(t) creep bank a_j = 1/(10^(j-1) dt), eq. (40)."""
        return cls(r_H=r_H, w_H=w_H, r_S=r_S, w_S=w_S, dt=dt, r_K=r_K, w_K=w_K, a_K=log_creep_eigenvalues(m, dt), **kw)

    # -- kernel parameter packing -------------------------------------------------------------------
    @staticmethod
    def _split_sup(r, w):
        s0 = float(w[r == 0].sum())
        pos, neg = r > 0, r < 0
        return s0, _arr(r[pos]), _arr(w[pos]), _arr(r[neg]), _arr(w[neg])

    def _prepare(self):
        n, m = len(self.r_K), len(self.a_K)
        self._rC = _arr(np.repeat(self.r_K, m))
        self._wC = _arr(np.repeat(self.w_K, m))
        self._gC = _arr(np.tile(-np.expm1(-self.a_K * self.dt), n))  # 1 - exp(-a T_s), precomputed
        self._sup = self._split_sup(self.r_S, self.w_S)
        self._inv_sup = None

    def _inverse_sup(self):
        if self._inv_sup is None:
            self._inv_sup = self._split_sup(*invert_superposition(self.r_S, self.w_S))
        return self._inv_sup

    def initial_state(self) -> PIState:
        return PIState(self.z_H0.copy(), self.Z_K0.copy(), float("nan"))

    # -- evaluation ---------------------------------------------------------------------------------
    def apply(self, x, state: PIState | None = None):
        """Streaming forward evaluation: returns (y, new_state); feeding blocks equals one batch call exactly."""
        x = np.ascontiguousarray(np.asarray(x, dtype=float).ravel())
        st = self.initial_state() if state is None else state.copy()
        c = np.ascontiguousarray(st.c.reshape(-1))
        xl = np.array([st.x_last])
        y = np.empty(len(x))
        s0, rSp, wSp, rSn, wSn = self._sup
        _kernels.gamma_kernel(x, self.r_H, self.w_H, st.p, self._rC, self._wC, self._gC, c, xl,
                              self.offset, s0, rSp, wSp, rSn, wSn, y)
        return y, PIState(st.p, c.reshape(st.c.shape), float(xl[0]))

    def __call__(self, x) -> np.ndarray:
        return self.apply(x)[0]

    def apply_inverse(self, y, state: PIState | None = None):
        """Streaming inverse: x with Gamma[x] = y exactly (per-sample piecewise-linear solve); returns (x, state)."""
        y = np.ascontiguousarray(np.asarray(y, dtype=float).ravel())
        st = self.initial_state() if state is None else state.copy()
        if not (self.w_H[self.r_H == 0].sum() > 0 and np.all(self.w_H >= 0)):
            raise ValueError("inverse needs w_H >= 0 with a positive weight on the r_H = 0 play operator")
        c = np.ascontiguousarray(st.c.reshape(-1))
        xl = np.array([st.x_last])
        x = np.empty(len(y))
        s0, rSp, wSp, rSn, wSn = self._inverse_sup()
        _kernels.gamma_inverse_kernel(y, self.r_H, self.w_H, st.p, self._rC, self._wC, self._gC, c, xl,
                                      self.offset, s0, rSp, wSp, rSn, wSn, x)
        return x, PIState(st.p, c.reshape(st.c.shape), float(xl[0]))

    def inverse(self, y) -> np.ndarray:
        """Gamma^{-1}[y] from the initial state."""
        return self.apply_inverse(y)[0]

    def intermediate(self, x) -> np.ndarray:
        """u = w_H^T H[x] + w_K^T K[x] i + offset (the superposition's argument), reference-speed helper."""
        from .operators import creep_operator, play_operator

        u = play_operator(x, self.r_H, self.z_H0) @ self.w_H + self.offset
        if len(self.r_K) and len(self.a_K):
            u = u + creep_operator(x, self.r_K, self.a_K, self.dt, self.Z_K0).sum(axis=2) @ self.w_K
        return u

    # -- serialisation ------------------------------------------------------------------------------
    def with_dt(self, dt: float) -> "ModifiedPI":
        """The same operator discretised at another sample time ``dt`` [s]: the creep eigenvalues ``a_K`` are in 1/s
        and stay; only their discrete-time factors 1 - exp(-a dt) change."""
        d = self.to_dict()
        d["dt"] = float(dt)
        return type(self).from_dict(d)

    def to_dict(self) -> dict:
        """Plain JSON-able dict (lists of floats); from_dict(to_dict()) reproduces the model bit-exactly."""
        L = lambda a: [float(v) for v in np.asarray(a).ravel()]  # noqa: E731
        return {
            "type": "ModifiedPI", "version": 1, "dt": float(self.dt), "offset": float(self.offset),
            "r_H": L(self.r_H), "w_H": L(self.w_H), "z_H0": L(self.z_H0),
            "r_K": L(self.r_K), "w_K": L(self.w_K), "a_K": L(self.a_K),
            "Z_K0": [L(row) for row in self.Z_K0],
            "r_S": L(self.r_S), "w_S": L(self.w_S),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "ModifiedPI":
        if d.get("type", "ModifiedPI") != "ModifiedPI":
            raise ValueError(f"not a ModifiedPI dict: type={d.get('type')!r}")
        nK, m = len(d.get("r_K", [])), len(d.get("a_K", []))
        Z = np.array(d.get("Z_K0", []), dtype=float).reshape(nK, m)
        return cls(r_H=d["r_H"], w_H=d["w_H"], z_H0=d.get("z_H0"), r_K=d.get("r_K", []), w_K=d.get("w_K", []),
                   a_K=d.get("a_K", []), Z_K0=Z, r_S=d["r_S"], w_S=d["w_S"], dt=d["dt"], offset=d.get("offset", 0.0))


def benchmark_throughput(n_samples: int = 10 ** 7, repeats: int = 3) -> dict:
    """Forward / inverse speed of the 15 play, 15 superposition, 15x4 creep model [M samples/s] (best of repeats).

    Run: ``python -c "from selfsense.hysteresis.pi import benchmark_throughput as b; print(b())"``. Deterministic model (seeded); measures wall time only.
    """
    import time

    rng = np.random.default_rng(0)
    r = np.linspace(0, 1, 15)
    rs = np.linspace(-1, 1, 15)
    rS = np.r_[0.0, rs[rs != 0]]
    m = ModifiedPI.with_log_creep(r, rng.uniform(0.1, 1, 15), rS, np.r_[1.0, rng.uniform(-0.03, 0.03, len(rS) - 1)],
                                  1e-4, r, rng.uniform(0, 0.1, 15), 4)
    x = np.sin(np.arange(n_samples) * 1e-3)
    m(x[:100])
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        y = m(x)
        best = min(best, time.perf_counter() - t)
    ni = min(n_samples, 10 ** 6)
    t = time.perf_counter()
    m.inverse(y[:ni])
    ti = time.perf_counter() - t
    return {"forward_Msps": n_samples / best / 1e6, "inverse_Msps": ni / ti / 1e6, "n_samples": n_samples,
            "operators": "15 play, 15 superposition, 15x4 creep"}

