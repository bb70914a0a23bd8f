"""Statistics for the gap diagnostic: blocked cross-validation, block bootstrap, exact Shapley values,
residual whiteness tests.

Everything here is time-series aware: folds and bootstrap resamples are *contiguous blocks* of samples, never
random samples (docs/gap.md: "Screen with blocked cross-validation (contiguous segments, never random
samples)": iid tests are anti-conservative on autocorrelated residuals).
"""
from __future__ import annotations

import itertools
from math import factorial
from typing import Callable, Hashable, Sequence

import numpy as np

__all__ = [
    "contiguous_blocks",
    "block_bootstrap_indices",
    "blocked_cv_sse",
    "blocked_cv_gain",
    "shapley_exact",
    "shapley_interactions",
    "ljung_box",
    "bootstrap_ci",
]


def contiguous_blocks(groups: np.ndarray, n_blocks_per_group: int) -> np.ndarray:
    """Block label per sample: each group (trial) is cut into ``n_blocks_per_group`` contiguous segments.

    ``groups`` is one label per sample (samples of one group must be contiguous and in time order).
    Returns int labels 0..B-1, constant on contiguous runs.
    """
    groups = np.asarray(groups)
    out = np.empty(len(groups), dtype=np.int64)
    nxt = 0
    # preserve order of first appearance
    _, first = np.unique(groups, return_index=True)
    for g in groups[np.sort(first)]:
        idx = np.flatnonzero(groups == g)
        k = max(1, min(n_blocks_per_group, len(idx)))
        lab = (np.arange(len(idx)) * k) // len(idx)
        out[idx] = nxt + lab
        nxt += k
    return out


def block_bootstrap_indices(blocks: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One block-bootstrap resample: draw whole blocks with replacement, return the concatenated sample indices.

    Every block is a contiguous run of samples, so autocorrelation inside a block is kept.
    """
    blocks = np.asarray(blocks)
    labels = np.unique(blocks)
    members = [np.flatnonzero(blocks == b) for b in labels]
    pick = rng.integers(0, len(labels), size=len(labels))
    return np.concatenate([members[i] for i in pick])


def _ridge(X: np.ndarray, y: np.ndarray, lam: float) -> np.ndarray:
    p = X.shape[1]
    A = X.T @ X + lam * np.eye(p)
    A[0, 0] -= lam  # do not penalise the intercept (first column)
    return np.linalg.solve(A, X.T @ y)


def _design(F: np.ndarray | None, n: int) -> np.ndarray:
    one = np.ones((n, 1))
    if F is None or F.size == 0:
        return one
    return np.column_stack([one, F])


def blocked_cv_sse(F: np.ndarray | None, y: np.ndarray, folds: np.ndarray, lam: float = 1e-3,
                   weights: np.ndarray | None = None) -> float:
    """Sum of squared held-out errors of ridge(intercept + F) with leave-fold-out over contiguous folds.

    ``F`` columns are standardised on the training part of each split; ``lam`` is relative to n.
    """
    y = np.asarray(y, float)
    w = np.ones_like(y) if weights is None else np.asarray(weights, float)
    sse = 0.0
    for k in np.unique(folds):
        te = folds == k
        tr = ~te
        if tr.sum() < 3:
            continue
        if F is None or F.size == 0:
            pred = np.full(te.sum(), np.average(y[tr], weights=w[tr]))
        else:
            mu = F[tr].mean(axis=0)
            sd = F[tr].std(axis=0)
            sd[sd == 0] = 1.0
            Z = (F - mu) / sd
            Xtr = _design(Z[tr], tr.sum())
            sw = np.sqrt(w[tr])[:, None]
            beta = _ridge(Xtr * sw, y[tr] * sw[:, 0], lam * tr.sum())
            pred = _design(Z[te], te.sum()) @ beta
        sse += float(np.sum(w[te] * (y[te] - pred) ** 2))
    return sse


def blocked_cv_gain(F: np.ndarray | None, y: np.ndarray, folds: np.ndarray, F_base: np.ndarray | None = None,
                    lam: float = 1e-3) -> float:
    """Relative held-out SSE reduction of adding ``F`` to ``F_base``: 1 - SSE(base + F) / SSE(base).

    Folds are contiguous blocks (see :func:`contiguous_blocks`); 0 = no gain, negative = overfitting.
    """
    base = blocked_cv_sse(F_base, y, folds, lam)
    full_F = F if F_base is None else (F_base if F is None else np.column_stack([F_base, F]))
    full = blocked_cv_sse(full_F, y, folds, lam)
    return 1.0 - full / base if base > 0 else 0.0


def shapley_exact(players: Sequence[Hashable], value: Callable[[frozenset], float]) -> dict:
    """Exact Shapley values of a set function ``value`` (evaluated on all 2^k coalitions, cached).

    phi_i = sum_{S subset N\\{i}} |S|! (k-|S|-1)! / k! [v(S u {i}) - v(S)].  Efficiency: sum phi = v(N) - v({}).
    """
    players = list(players)
    k = len(players)
    cache: dict[frozenset, float] = {}

    def v(S: frozenset) -> float:
        if S not in cache:
            cache[S] = float(value(S))
        return cache[S]

    phi = {}
    for p in players:
        others = [q for q in players if q != p]
        tot = 0.0
        for r in range(len(others) + 1):
            wgt = factorial(r) * factorial(k - r - 1) / factorial(k)
            for S in itertools.combinations(others, r):
                S = frozenset(S)
                tot += wgt * (v(S | {p}) - v(S))
        phi[p] = tot
    return phi


def shapley_interactions(players: Sequence[Hashable], value: Callable[[frozenset], float]) -> dict:
    """Shapley interaction index for every pair (Grabisch 1997):
    I_ij = sum_{S subset N\\{i,j}} |S|! (k-|S|-2)! / (k-1)! [v(S+ij) - v(S+i) - v(S+j) + v(S)].

    Negative = the two effects compete for the same residual (substitutes), positive = complements.
    """
    players = list(players)
    k = len(players)
    cache: dict[frozenset, float] = {}

    def v(S: frozenset) -> float:
        if S not in cache:
            cache[S] = float(value(S))
        return cache[S]

    out = {}
    for i, j in itertools.combinations(players, 2):
        others = [q for q in players if q not in (i, j)]
        tot = 0.0
        for r in range(len(others) + 1):
            wgt = factorial(r) * factorial(k - r - 2) / factorial(k - 1)
            for S in itertools.combinations(others, r):
                S = frozenset(S)
                tot += wgt * (v(S | {i, j}) - v(S | {i}) - v(S | {j}) + v(S))
        out[(i, j)] = tot
    return out


def ljung_box(x: np.ndarray, lags: int = 20) -> tuple[float, float]:
    """Ljung-Box portmanteau statistic Q = n(n+2) sum_k rho_k^2/(n-k) and its chi^2(lags) p-value."""
    from scipy.special import chdtrc   # the chi^2 survival function (scipy.stats.chi2.sf's own, without its import)

    x = np.asarray(x, float)
    x = x - x.mean()
    n = len(x)
    den = float(np.dot(x, x))
    if n <= lags + 1 or den == 0:
        return 0.0, 1.0
    rho = np.array([np.dot(x[:-k], x[k:]) / den for k in range(1, lags + 1)])
    Q = float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, lags + 1))))
    return Q, float(chdtrc(lags, Q))


def bootstrap_ci(stat: Callable[[np.ndarray], float], blocks: np.ndarray, n_boot: int, seed: int,
                 level: float = 0.9) -> tuple[float, float]:
    """Percentile interval of ``stat(indices)`` over block-bootstrap resamples (contiguous blocks)."""
    rng = np.random.default_rng(seed)
    vals = np.array([stat(block_bootstrap_indices(blocks, rng)) for _ in range(n_boot)])
    a = (1 - level) / 2
    return float(np.quantile(vals, a)), float(np.quantile(vals, 1 - a))


class GramCV:
    """Fast leave-one-block-out ridge CV from per-block Gram matrices.

    ``F`` (n, p) standardised features, ``y`` (n,), ``blocks`` (n,) contiguous block labels. For any column subset
    and any block weights (block-bootstrap counts), the held-out SSE is computed from the (p+2)^2 block Grams of
    ``[1, F, y]`` without touching the samples again. Same estimator as :func:`blocked_cv_sse` with each block a fold.
    """

    def __init__(self, F: np.ndarray, y: np.ndarray, blocks: np.ndarray, lam: float = 1e-3):
        Z = np.column_stack([np.ones(len(y)), F, y])
        order = np.argsort(blocks, kind="stable")
        Z, bl = Z[order], np.asarray(blocks)[order]
        self.labels, starts = np.unique(bl, return_index=True)
        ends = np.append(starts[1:], len(bl))
        self.G = np.stack([Z[a:e].T @ Z[a:e] for a, e in zip(starts, ends)])  # (B, p+2, p+2)
        self.n = (ends - starts).astype(float)
        self.p = F.shape[1]
        self.lam = lam

    def sse(self, cols: np.ndarray | None, counts: np.ndarray | None = None) -> float:
        """Held-out SSE of ridge(intercept + F[:, cols]); ``counts`` = per-block multiplicity (bootstrap)."""
        c = np.ones(len(self.labels)) if counts is None else np.asarray(counts, float)
        idx = np.concatenate([[0], 1 + np.asarray(cols, int)]) if cols is not None and len(cols) else np.array([0])
        yi = self.p + 1
        full = np.append(idx, yi)
        Gs = self.G[:, full[:, None], full[None, :]]          # (B, q+1, q+1)
        Gt = np.tensordot(c, Gs, axes=1)
        keep = np.flatnonzero(c > 0)
        Gk = Gs[keep]
        ck = c[keep][:, None, None]
        Tr = Gt[None] - ck * Gk                                 # training Grams per left-out block
        q = len(idx)
        ntr = float(c @ self.n) - c[keep] * self.n[keep]
        pen = np.ones(q)
        pen[0] = 0.0
        A = Tr[:, :q, :q] + (self.lam * ntr)[:, None, None] * np.diag(pen)[None]
        b = Tr[:, :q, q]
        A = A + 1e-12 * np.trace(A, axis1=1, axis2=2)[:, None, None] * np.eye(q)[None]
        beta = np.linalg.solve(A, b[..., None])[..., 0]
        Ak = Gk[:, :q, :q]
        sse_k = Gk[:, q, q] - 2 * np.einsum("ki,ki->k", beta, Gk[:, :q, q]) + np.einsum("ki,kij,kj->k", beta, Ak, beta)
        ok = ntr >= 3
        return float(np.sum(c[keep][ok] * sse_k[ok]))
