"""Runs of consecutive True samples in a boolean mask (relay segments, clipped samples, current-limit plateaus)."""
from __future__ import annotations

import numpy as np

__all__ = ["true_runs"]


def true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(starts, ends)`` of every run of True in the 1-D ``mask``: run k covers ``mask[starts[k]:ends[k]]``.

    Any nonzero value counts as True (NaN included): pass a boolean mask. Both are int arrays in increasing order;
    empty when ``mask`` holds no True."""
    m = np.asarray(mask)
    if m.ndim != 1:
        raise ValueError(f"true_runs: expected a 1-D mask, got shape {m.shape}")
    d = np.diff(np.concatenate(([0], (m != 0).astype(np.int8), [0])))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)
