"""Statistics for the gap diagnostic: exact Shapley values (the counterfactual's "all together" game,
:func:`selfsense.gap.counterfactual.counterfactual`)."""
from __future__ import annotations

import itertools
from collections.abc import Callable, Hashable, Sequence
from math import factorial

__all__ = ["shapley_exact"]


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
