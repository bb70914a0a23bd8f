"""Drive waveforms of the virtual tweezer (actuator supply voltage targets, 0-150 V).

Families follow the thesis (000_18d138f03f1777c3.txt Figs. 22 and 23): ``sine`` (a raised sine
whose successive maxima and minima change, so that nested minor loops appear), ``mixed``
(trapezoids with holds at high voltage and at 0 V, mixed with sine cycles) and ``steps``
(symmetric up/down steps with holds).  All functions return the target supply voltage [V] at the
sample times; the DAQ output is ``u_cmd = V / amplifier_gain`` on the 16-bit output grid.
"""
from __future__ import annotations

import numpy as np

__all__ = ["waveform", "SINE_LEVELS"]

#: (maximum, following minimum) of successive sine half-cycle pairs, as fractions of the amplitude
SINE_LEVELS = [(1.0, 0.0), (0.7, 0.25), (1.0, 0.0), (0.45, 0.0), (0.85, 0.35), (0.6, 0.0),
               (1.0, 0.5), (0.9, 0.0), (0.3, 0.0), (1.0, 0.0)]


def _knots_eval(t, knots):
    """knots: list of (time, value, shape) with shape 'lin' or 'cos' for the segment ENDING there."""
    v = np.zeros_like(t)
    for (t0, v0, _), (t1, v1, shape) in zip(knots[:-1], knots[1:]):
        m = (t >= t0) & (t < t1)
        if not m.any():
            continue
        s = (t[m] - t0) / (t1 - t0)
        if shape == "cos":
            s = 0.5 * (1.0 - np.cos(np.pi * s))
        v[m] = v0 + (v1 - v0) * s
    tl, vl, _ = knots[-1]
    v[t >= tl] = vl
    return v


def waveform(t: np.ndarray, spec: dict, start: float) -> np.ndarray:
    """Target supply voltage [V] for a trial spec (keys: signal, amplitude [V], freq [Hz],
    levels, hold_s, ramp_s) beginning at ``start`` [s] (after the relay).

    ``signal: samples``: the target given sample by sample in ``samples_v`` (one value [V] per DAQ sample of the
    trial, from t = 0; the relay's samples are set to 0 by the caller), e.g. the supply voltage an amplifier actually
    applied in another run (the excitation-matched twin of the gap diagnostic's tip tier, docs/gap.md)."""
    sig = spec.get("signal", "sine")
    if sig == "samples":
        v = np.asarray(spec.get("samples_v", ()), dtype=float).ravel()
        if v.shape != t.shape or not np.all(np.isfinite(v)):
            raise ValueError(f"trial {spec.get('trial')!r}: signal 'samples' needs samples_v with one finite value "
                             f"per DAQ sample ({t.size}), found {v.size} values")
        return v.copy()
    A = float(spec.get("amplitude", 150.0))
    f = float(spec.get("freq", 0.5))
    T = float(t[-1]) if t.size else 0.0
    knots = [(0.0, 0.0, "lin"), (start, 0.0, "lin")]
    tc, vc = start, 0.0
    end = T - 0.5   # leave time to return to 0

    def add(dt, v, shape):
        nonlocal tc, vc
        tc += dt
        vc = v
        knots.append((tc, v, shape))

    if sig == "sine":
        levels = spec.get("levels") or SINE_LEVELS
        half = 0.5 / f
        i = 0
        while True:
            hi, lo = levels[i % len(levels)]
            if tc + 2 * half > end:
                break
            add(half, hi * A, "cos")
            add(half, lo * A, "cos")
            i += 1
        if vc != 0.0:
            add(half, 0.0, "cos")
    elif sig == "mixed":
        ramp = float(spec.get("ramp_s", 0.4))
        hold = float(spec.get("hold_s", 1.2))
        half = 0.5 / f
        pattern = [("trap", 1.0), ("sine", 0.8), ("trap", 0.55), ("sine", 1.0), ("sine", 0.5),
                   ("trap", 0.85), ("sine", 0.7)]
        i = 0
        while True:
            kind, lev = pattern[i % len(pattern)]
            need = 2 * ramp + 2 * hold if kind == "trap" else 2 * half
            if tc + need > end:
                break
            if kind == "trap":
                add(ramp, lev * A, "lin")
                add(hold, lev * A, "lin")
                add(ramp, 0.0, "lin")
                add(hold, 0.0, "lin")
            else:
                add(half, lev * A, "cos")
                add(half, 0.0, "cos")
            i += 1
    elif sig == "steps":
        ramp = float(spec.get("ramp_s", 0.05))
        hold = float(spec.get("hold_s", 1.5))
        levels = spec.get("levels") or [1.0, 0.0, 0.5, 0.0, 1.0, 0.5, 1.0, 0.0]
        i = 0
        while tc + ramp + hold <= end:
            add(ramp, float(levels[i % len(levels)]) * A, "lin")
            add(hold, vc, "lin")
            i += 1
        if vc != 0.0:
            add(ramp, 0.0, "lin")
    else:
        raise ValueError(f"unknown signal {sig!r} (sine | mixed | steps | samples)")
    return _knots_eval(t, knots)
