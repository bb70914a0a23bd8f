"""Small signal helpers of the excitation check (:mod:`selfsense.gap.protocol`)."""
from __future__ import annotations

import numpy as np

__all__ = ["active", "dt_of"]


def dt_of(t: np.ndarray) -> float:
    """Median sample period [s]."""
    return float(np.median(np.diff(t))) if len(t) > 1 else 1e-3


def active(df) -> np.ndarray:
    """True where the actuator leads are not shorted (relay == 0)."""
    return df["relay"].to_numpy() < 0.5
