"""Statistics of the gap diagnostic: exact Shapley axioms."""

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
