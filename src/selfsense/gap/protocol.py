"""Excitation check and acquisition-protocol proposal (docs/gap.md"excitation design matters as
much as the library").

The slow effects are only separable when the data contain: holds at 0 V (offset drift and dielectric absorption
show there, creep and leakage do not), holds at high V (leakage and creep show there), symmetric up/down steps to
the same level (the hysteresis state is the same on both visits, so any difference is slow), and a rest-then-repeat
pair (the same drive again after a rest: temperature and other campaign-time drifts). :func:`excitation_check`
says which of these a dataset has; :func:`proposal` turns the missing ones into a protocol for the next acquisition.
"""
from __future__ import annotations

import numpy as np

from selfsense.signals.runs import true_runs

__all__ = ["excitation_check", "proposal", "ELEMENTS"]


def dt_of(t: np.ndarray) -> float:
    """Median sample period [s]."""
    return float(np.median(np.diff(t))) if len(t) > 1 else 1e-3


def active(df) -> np.ndarray:
    """True where the actuator leads are not shorted (relay == 0)."""
    return df["relay"].to_numpy() < 0.5

ELEMENTS = {
    "hold_0V": "a hold of >= 0.8 s at 0 V after an excursion above half the range (offset drift, dielectric absorption)",
    "hold_high_V": "a hold of >= 0.8 s above 70 % of the range (leakage, creep)",
    "symmetric_steps": "the same level reached by a step from below and by a step from above (separates slow "
                       "effects from the hysteresis state)",
    "rest_then_repeat": "the same drive repeated in a later trial (temperature and campaign-time drift)",
}


def _holds(V: np.ndarray, t: np.ndarray, act: np.ndarray, Vm: float) -> list[tuple[int, int, float]]:
    """Runs where V stays within 1 % of the range for >= 0.8 s: (start, stop, level)."""
    dt = dt_of(t)
    w = max(1, int(round(0.2 / dt)))
    k = np.ones(w) / w
    lvl = np.convolve(V, k, mode="same")
    flat = act & (np.abs(V - lvl) < 0.01 * Vm) & (np.abs(np.gradient(lvl, dt)) < 0.05 * Vm)
    out = []
    starts, ends = true_runs(flat)
    for a, b in zip(starts.tolist(), ends.tolist()):
        if (b - a) * dt >= 0.8:
            out.append((a, b, float(np.median(V[a:b]))))
    return out


def excitation_check(trials: dict, meta) -> dict:
    """Which protocol elements (``ELEMENTS``) the dataset contains, and in which trials.

    ``trials``: trial -> prepared frame (t, V, relay, u_cmd); ``meta``: trials.csv indexed by trial (in
    acquisition order)."""
    found = {k: [] for k in ELEMENTS}
    Vm = max(float(np.max(np.abs(trials[t]["V"].to_numpy(float)))) for t in meta.index) or 1.0
    for tid in meta.index:
        df = trials[tid]
        t, V = df["t"].to_numpy(float), df["V"].to_numpy(float)
        n1s = int(round(1.0 / dt_of(t)))
        act = active(df)
        holds = _holds(V, t, act, Vm)
        seen_high = np.maximum.accumulate(np.where(act, V, 0.0)) > 0.5 * Vm
        if any(abs(l) < 0.02 * Vm and seen_high[a] for a, _, l in holds):
            found["hold_0V"].append(tid)
        if any(l > 0.7 * Vm for _, _, l in holds):
            found["hold_high_V"].append(tid)
        # symmetric steps: two holds at the same non-zero level, one entered from below, one from above
        ent = []
        for a, _, l in holds:
            if l > 0.1 * Vm and a > 0:
                prev = V[max(0, a - n1s):a]
                if len(prev):
                    ent.append((l, np.sign(l - float(np.min(prev)) - (float(np.max(prev)) - l))))
        for i, (l1, s1) in enumerate(ent):
            if any(abs(l1 - l2) < 0.03 * Vm and s1 != s2 for l2, s2 in ent[i + 1:]):
                found["symmetric_steps"].append(tid)
                break
    # rest-then-repeat: two trials with the same command (within 1 % of the range), not adjacent in time
    cmds = {tid: trials[tid]["u_cmd" if "u_cmd" in trials[tid] else "V"].to_numpy(float) for tid in meta.index}
    ids = list(meta.index)
    for i, a in enumerate(ids):
        for b in ids[i + 2:]:
            ua, ub = cmds[a], cmds[b]
            n = min(len(ua), len(ub))
            if n > 10 and np.max(np.abs(ua[:n] - ub[:n])) < 0.01 * (np.ptp(ua) or 1.0):
                found["rest_then_repeat"].append(f"{a} -> {b}")
    return {"present": {k: v for k, v in found.items() if v}, "missing": [k for k, v in found.items() if not v]}


def proposal(check: dict) -> str:
    """Protocol for the next acquisition, from the missing elements of :func:`excitation_check`."""
    if not check["missing"]:
        return "the dataset contains every protocol element (holds at 0 V and high V, symmetric steps, rest-then-repeat)"
    lines = ["add to the next acquisition (free tip, displacement reference, ramps of >= 0.4 s so the shunt stays "
             "in range):"]
    steps = {"hold_0V": "steps 0 -> high -> 0 with >= 1.5 s holds at 0 V",
             "hold_high_V": ">= 1.5 s holds at the highest level used",
             "symmetric_steps": "the levels hi, 0, mid, 0, hi, mid, hi, 0 (mid reached from below and from above)",
             "rest_then_repeat": "the same step trial repeated after a >= 60 s rest, later in the session"}
    lines += [f"- {steps[k]} ({ELEMENTS[k].split(' (')[-1].rstrip(')')})" for k in check["missing"]]
    return "\n".join(lines)
