"""Post-processing of estimates: limiting and sliding DC offset (thesis 000_18d138f03f1777c3.txt sec. 5.2,
Fig. 24 "Effect of limiting and sliding DC offset")."""
from __future__ import annotations

import numpy as np

from .charge import SignalError

__all__ = ["limit_to_range", "sliding_dc_offset"]


def limit_to_range(x, lo: float, hi: float) -> np.ndarray:
    """Clip an estimate to its physically possible range ``[lo, hi]`` (same unit as ``x``).

    Thesis sec. 5.2 (Fig. 24): "The force and displacement measurements were limited to their respective
    maximum and minimum values", e.g. displacement to ``[0, tip_free_displacement_m]`` [m] and force to
    ``[0, blocked tip force]`` [N]. NaN stays NaN. Raises :class:`SignalError` if ``lo > hi`` or a bound is NaN.
    """
    if np.isnan(lo) or np.isnan(hi) or lo > hi:
        raise SignalError(f"limit_to_range needs lo <= hi, got lo={lo!r}, hi={hi!r}")
    return np.clip(np.asarray(x, dtype=np.float64), lo, hi)


def sliding_dc_offset(x, u_cmd, zero_level: float = 5e-3, return_offset: bool = False):
    """Remove slow drift with a sliding DC offset (thesis sec. 5.2, Fig. 24).

    "The offset reset as the current displacement measurement whenever the input voltage was zero": at every
    sample where ``|u_cmd| <= zero_level`` [V] the offset becomes the current value of ``x``; between such
    samples it holds its last value; before the first zero-input sample it is 0. The result is
    ``x - offset``, which is therefore exactly 0 whenever the input is zero (the actuator at rest at zero
    voltage must be at zero displacement).

    Parameters
    ----------
    x : estimate to correct (e.g. displacement [m]).
    u_cmd : control voltage of the amplifier [V] (the "input voltage"), same length as ``x``.
    zero_level : |u_cmd| at or below this counts as zero input [V] (default 5 mV, above DAQ noise).
    return_offset : also return the offset signal.
    """
    x = np.asarray(x, dtype=np.float64)
    u = np.asarray(u_cmd, dtype=np.float64)
    if x.shape != u.shape or x.ndim != 1:
        raise SignalError(f"x and u_cmd must be 1-D of equal length, got {x.shape} and {u.shape}")
    if not (zero_level >= 0):
        raise SignalError(f"zero_level must be >= 0, got {zero_level!r}")
    zero = np.abs(u) <= zero_level
    idx = np.arange(x.size)
    last = np.maximum.accumulate(np.where(zero, idx, -1)) if x.size else idx
    off = np.where(last >= 0, x[np.maximum(last, 0)], 0.0) if x.size else np.zeros(0)
    y = x - off
    return (y, off) if return_offset else y
