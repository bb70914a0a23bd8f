"""selfsense.signals.true_runs: the runs of True in a mask, the one definition the relay, clipping and
current-limit checks share."""
from __future__ import annotations

import numpy as np
import pytest

from selfsense.signals import true_runs


def test_runs_cover_exactly_the_true_samples():
    rng = np.random.default_rng(5)
    for _ in range(50):
        mask = rng.random(int(rng.integers(0, 40))) < rng.random()
        starts, ends = true_runs(mask)
        rebuilt = np.zeros(mask.size, bool)
        for a, b in zip(starts, ends):
            assert a < b
            rebuilt[a:b] = True
        assert np.array_equal(rebuilt, mask)
        # maximal runs: the sample before each run and the one after it are False (or outside the mask)
        assert all(a == 0 or not mask[a - 1] for a in starts)
        assert all(b == mask.size or not mask[b] for b in ends)
        assert np.all(np.diff(starts) > 0)


@pytest.mark.parametrize(("mask", "starts", "ends"), [
    ([], [], []),
    ([0, 0, 0], [], []),
    ([1, 1, 1], [0], [3]),
    ([1, 0, 1], [0, 2], [1, 3]),
    ([0, 1, 1, 0, 0, 1], [1, 5], [3, 6]),
])
def test_runs_of_small_masks(mask, starts, ends):
    s, e = true_runs(np.array(mask, bool))
    assert s.tolist() == starts and e.tolist() == ends


def test_a_mask_of_more_than_one_dimension_is_refused():
    with pytest.raises(ValueError, match="1-D mask"):
        true_runs(np.ones((2, 3), bool))
