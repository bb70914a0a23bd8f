"""Statistics of the gap diagnostic: exact Shapley axioms, blocked resampling, blocked CV."""

import numpy as np
import pytest

from selfsense.gap import stats


def _game(S):
    # additive part + a pairwise substitute term (a and b explain the same residual) + null player d
    base = {"a": 3.0, "b": 2.0, "c": 1.0, "d": 0.0}
    v = sum(base[p] for p in S)
    if {"a", "b"} <= S:
        v -= 1.5
    return v


def test_shapley_efficiency_symmetry_null_player():
    players = ["a", "b", "c", "d"]
    phi = stats.shapley_exact(players, _game)
    assert sum(phi.values()) == pytest.approx(_game(frozenset(players)) - _game(frozenset()))
    assert phi["d"] == pytest.approx(0.0)                      # null player
    assert phi["a"] == pytest.approx(3.0 - 0.75)               # the shared loss splits evenly
    assert phi["b"] == pytest.approx(2.0 - 0.75)
    sym = stats.shapley_exact(["x", "y"], lambda S: 5.0 * len(S) ** 2)   # symmetric players get equal shares
    assert sym["x"] == pytest.approx(sym["y"])


def test_shapley_interaction_sign_marks_substitutes():
    inter = stats.shapley_interactions(["a", "b", "c"], lambda S: _game(S))
    assert inter[("a", "b")] == pytest.approx(-1.5)
    assert inter[("a", "c")] == pytest.approx(0.0)


def test_block_bootstrap_draws_whole_contiguous_blocks():
    groups = np.repeat([0, 1, 2], [100, 50, 70])
    blocks = stats.contiguous_blocks(groups, 5)
    # each block label occupies one contiguous run inside one group
    for b in np.unique(blocks):
        idx = np.flatnonzero(blocks == b)
        assert np.all(np.diff(idx) == 1)
        assert len(np.unique(groups[idx])) == 1
    rng = np.random.default_rng(0)
    idx = stats.block_bootstrap_indices(blocks, rng)
    assert len(np.unique(blocks)) == 15
    # the resample is a concatenation of complete blocks: split at label changes, each run is a full block
    runs = np.split(idx, np.flatnonzero(np.diff(blocks[idx]) != 0) + 1)
    for r in runs:
        full = np.flatnonzero(blocks == blocks[r[0]])
        assert len(r) % len(full) == 0 and np.all(np.diff(r[: len(full)]) == 1)


def test_gram_cv_equals_direct_blocked_cv_and_detects_signal():
    rng = np.random.default_rng(1)
    n = 1200
    F = rng.normal(size=(n, 3))
    y = 0.8 * F[:, 0] + rng.normal(size=n)
    blocks = stats.contiguous_blocks(np.zeros(n), 10)
    g = stats.GramCV(F, y, blocks)
    direct = stats.blocked_cv_sse(F[:, [0, 2]], y, blocks)
    # same ridge estimator on pre-standardised columns: agree to within the standardisation difference
    assert g.sse(np.array([0, 2])) == pytest.approx(direct, rel=2e-3)
    gain_signal = 1 - g.sse(np.array([0])) / g.sse(None)
    gain_noise = 1 - g.sse(np.array([1])) / g.sse(None)
    assert gain_signal > 0.3 and gain_noise < 0.01


def test_ljung_box_rejects_autocorrelation_only():
    rng = np.random.default_rng(2)
    white = rng.normal(size=2000)
    ar = np.zeros(2000)
    for i in range(1, 2000):
        ar[i] = 0.8 * ar[i - 1] + white[i]
    assert stats.ljung_box(white)[1] > 0.01
    assert stats.ljung_box(ar)[1] < 1e-6
