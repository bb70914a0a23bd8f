"""Actuator voltage and charge from the shunt measurement (thesis 000_18d138f03f1777c3.txt sec. 5.1.1).

All inputs are 1-D float arrays in SI units: time ``t`` [s], voltages [V], resistance [ohm], charge [C].
"""
from __future__ import annotations

import numpy as np

__all__ = ["SignalError", "actuator_voltage", "charge_from_shunt", "relay_offset"]


class SignalError(ValueError):
    """Signals that cannot be processed as asked (e.g. no relay segment to estimate the offset from)."""


def actuator_voltage(V_c, V_s) -> np.ndarray:
    """Voltage across the actuators, ``V = V_c - V_s`` [V] (000_18d138f03f1777c3.txt eq. (56)).

    ``V_c`` is the amplifier output (amplifier gain times the control voltage), ``V_s`` the drop across the
    shunt resistor in series with the actuators.
    """
    V_c = np.asarray(V_c, dtype=np.float64)
    V_s = np.asarray(V_s, dtype=np.float64)
    if V_c.shape != V_s.shape:
        raise SignalError(f"V_c and V_s must have the same shape, got {V_c.shape} and {V_s.shape}")
    return V_c - V_s


def _as_relay(relay, n: int) -> np.ndarray:
    r = np.asarray(relay, dtype=np.float64)
    if r.shape != (n,):
        raise SignalError(f"relay must have shape ({n},), got {r.shape}")
    if not np.all((r == 0) | (r == 1)):
        raise SignalError("relay must contain only 0 and 1")
    return r == 1


def relay_offset(V_s, relay) -> float:
    """In-amp/ADC offset [V]: the mean of ``V_s`` over the first contiguous shorted (relay == 1) segment.

    While the leads are shorted no charge flows onto the actuators, so whatever ``V_s`` reads there is the
    offset of the measurement chain (a 0.3 mV offset integrates to volts' worth of
    charge error). Only the first segment is used: shorting a charged actuator later in a trial makes a
    discharge transient flow through the shunt. Raises :class:`SignalError` when there is no such segment.
    """
    V_s = np.asarray(V_s, dtype=np.float64)
    shorted = _as_relay(relay, V_s.size)
    if not shorted.any():
        raise SignalError("no relay == 1 (shorted) segment: cannot estimate the V_s offset "
                          "(pass offset=<value> or offset=None to skip)")
    i0 = int(np.argmax(shorted))
    stop = np.flatnonzero(~shorted[i0:])
    i1 = i0 + (int(stop[0]) if stop.size else shorted.size - i0)
    return float(np.mean(V_s[i0:i1]))


def charge_from_shunt(t, V_s, relay, R: float, offset: str | float | None = "relay") -> tuple[np.ndarray, float]:
    """Charge on the actuators from the shunt voltage, ``q(t) = (1/R) * integral_0^t V_s dtau`` [C]
    (000_18d138f03f1777c3.txt eq. (57)), trapezoidal rule on the (possibly non-uniform) time grid.

    Parameters
    ----------
    t : sample times [s], strictly increasing.
    V_s : voltage across the shunt resistor [V] (already divided by the in-amp gain).
    relay : 0/1; while 1 the actuator leads are shorted to ground (thesis sec. 5.1.1: a known initial
        state), so ``q`` is reset to 0 there and integration restarts when the relay opens.
    R : shunt resistance [ohm], > 0.
    offset : ``"relay"`` (default): subtract the mean of ``V_s`` over the first shorted segment
        (:func:`relay_offset`; raises :class:`SignalError` if there is none); a number [V]: subtract it;
        ``None``: no offset removal.

    Returns
    -------
    q : charge [C], same length as ``t``; exactly 0 wherever ``relay == 1``.
    offset_v : the offset that was subtracted from ``V_s`` [V].
    """
    t = np.asarray(t, dtype=np.float64)
    V_s = np.asarray(V_s, dtype=np.float64)
    if t.ndim != 1 or V_s.shape != t.shape:
        raise SignalError(f"t and V_s must be 1-D of equal length, got {t.shape} and {V_s.shape}")
    if not (np.isfinite(R) and R > 0):
        raise SignalError(f"shunt resistance R must be finite and > 0 ohm, got {R!r}")
    shorted = _as_relay(relay, t.size)
    if t.size and not np.all(np.diff(t) > 0):
        raise SignalError("t must be strictly increasing")
    if isinstance(offset, str):
        if offset != "relay":
            raise SignalError(f"offset must be 'relay', a number or None, got {offset!r}")
        off = relay_offset(V_s, shorted.astype(np.float64))
    elif offset is None:
        off = 0.0
    else:
        off = float(offset)
    if t.size == 0:
        return np.zeros(0), off
    # the integrand and the trapezoidal increment: the definitions the streaming integrator inlines too
    from .kernels import shunt_current, trapezoid_increment

    i = shunt_current(V_s, off, R)  # current [A]
    inc = np.zeros_like(t)
    inc[1:] = trapezoid_increment(i[:-1], i[1:], np.diff(t))
    inc[shorted] = 0.0
    c = np.cumsum(inc)
    idx = np.arange(t.size)
    last_reset = np.maximum.accumulate(np.where(shorted, idx, -1))
    base = np.where(last_reset >= 0, c[np.maximum(last_reset, 0)], 0.0)
    q = c - base
    q[shorted] = 0.0
    return q, off
