"""Physical plausibility of one trial log: checks that catch data which reads fine but would give wrong numbers.

The contract checks of :mod:`selfsense.io.logs` catch malformed files; these catch well-formed logs whose physics
cannot be right, so that the pipeline never ends with plausible-looking tables computed from them:

* **charge scale** -- the charge measured through the shunt (thesis ``000_18d138f03f1777c3.txt`` eq. (57),
  ``q = (1/R) * integral of V_s dt``) must be of the size the actuators' capacitance gives,
  ``q ~ n_A * C_p * V`` (thesis eq. (55): ``H(q) = V - q / C_p`` per actuator; the hysteresis and the mechanical
  coupling change the ratio by tens of percent, not by orders of magnitude). A shunt resistance, in-amp gain or
  capacitance entered 1000x off in ``rig.yaml`` fails here.
* **charge follows the voltage** -- ``q`` must correlate with the actuator voltage ``V`` (eq. (56)); a shunt
  channel that only carries noise (in-amp unplugged, wrong channel) integrates to a random walk that does not.
* **relay** -- the actuator must be connected (``relay = 0``) for most of the trial and must not be re-shorted
  for good at the end: the charge is reset to 0 while the relay is closed (thesis sec. 5.1.1).
* **reference activity** -- the trial's reference sensor must move in the trial's declared condition: a laser on
  a free tip, a load cell on a blocked tip, either on an object. A "free-tip" trial recorded with the tip blocked
  has a flat laser. On a free tip the displacement must also be of the size the data sheet gives
  (``tip_free_displacement_m * V / max_voltage_v``).
* **flat tops** -- a run of identical values at a channel's extreme is clipping, whatever ``adc_range_v`` says
  (an in-amp or sensor amplifier saturates below the DAQ range); except, on ``v_shunt``, a plateau at the HV
  amplifier's current limit declared in rig.yaml (``amplifier_current_limit_a``): an amplifier at its limit delivers
  a constant current, which an undithered ADC reads as one code (the voltage link's amplifier member rebuilds V
  there, docs/method.md 1a).
* **trial length** -- enough samples with the actuator connected to calibrate or score anything.

Each finding is a :class:`~selfsense.io.errors.Problem` with ``level`` ``"error"`` (the dataset is refused) or
``"warning"`` (reported by ``selfsense validate`` and written to ``validation.json``, which the report shows).
All limits have defaults (:data:`DEFAULTS`) and can be set per rig in ``rig.yaml`` under ``plausibility:``
(``docs/data_format.md``).
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
import pandas as pd

from selfsense.signals.runs import true_runs

from .errors import Problem

__all__ = ["DEFAULTS", "DOCS", "check_plausibility", "check_plausibility_keys"]

#: default limits; every key can be overridden per rig in rig.yaml ``plausibility:``
DEFAULTS: dict[str, float] = {
    "min_samples": 50,               # fewer samples with the relay open: an error
    "min_released_fraction": 0.5,    # share of samples with relay = 0 (actuator connected)
    "max_final_short_fraction": 0.05,  # a closing relay segment at the end longer than this share: re-shorted
    "charge_ratio_min": 0.2,         # ptp(q) / (n_A C_p ptp(V)) below: error (shunt/gain/capacitance scale)
    "charge_ratio_max": 5.0,         # above: error
    "charge_ratio_warn_min": 0.5,    # outside [warn_min, warn_max]: warning
    "charge_ratio_warn_max": 2.0,
    "min_charge_correlation": 0.8,   # corr(q, V) over the connected samples below: error (noise-only shunt)
    "min_reference_snr": 10.0,       # robust range / noise of the reference channel below: error (flat sensor;
                                     # noise alone reads about 5.2: the 0.5-99.5 % range of a Gaussian)
    "warn_reference_snr": 20.0,      # below (and above the error limit): warning (a live but weak reference)
    "free_displacement_ratio_min": 0.1,   # free tip: ptp(dx_ref) / (tip_free_displacement * ptp(V) / V_max)
    "free_displacement_ratio_max": 10.0,
    "flat_top_fraction": 0.002,      # share of samples exactly at the max (or min) value above: clipping
    "flat_top_min_samples": 10,      # ... and at least this many samples
}
#: one line per key for the docs and the error messages
DOCS: dict[str, str] = {
    "min_samples": "minimum number of samples with the relay open (actuator connected)",
    "min_released_fraction": "minimum share of samples with relay = 0",
    "max_final_short_fraction": "maximum share of samples in a relay = 1 segment that closes the log after release",
    "charge_ratio_min": "minimum ptp(q) / (n_actuators * capacitance_f * ptp(V)) (error below)",
    "charge_ratio_max": "maximum of the same ratio (error above)",
    "charge_ratio_warn_min": "the same ratio below this: warning",
    "charge_ratio_warn_max": "the same ratio above this: warning",
    "min_charge_correlation": "minimum correlation of q with V over the connected samples",
    "min_reference_snr": "minimum robust range / noise of the reference channel where it must move (error below)",
    "warn_reference_snr": "robust range / noise of the same channel below which a warning says the reference is weak",
    "free_displacement_ratio_min": "free tip: minimum ptp(dx_ref) / (tip_free_displacement_m * ptp(V) / max_voltage_v)",
    "free_displacement_ratio_max": "free tip: maximum of the same ratio",
    "flat_top_fraction": "share of samples exactly at a channel's max or min above which it is clipped",
    "flat_top_min_samples": "minimum number of such samples for a clipping finding",
}
_INT_KEYS = {"min_samples", "flat_top_min_samples"}


def check_plausibility_keys(d: Any, file: str = "rig.yaml") -> tuple[dict[str, float], list[Problem]]:
    """Parse the optional ``plausibility:`` block of rig.yaml; return ``(limits, problems)``."""
    lim = dict(DEFAULTS)
    if d is None:
        return lim, []
    if not isinstance(d, dict):
        return lim, [Problem(file, "plausibility", None, "a mapping of plausibility limits", type(d).__name__)]
    probs: list[Problem] = []
    for k, v in d.items():
        key = f"plausibility.{k}"
        if k not in DEFAULTS:
            import difflib
            close = difflib.get_close_matches(str(k), list(DEFAULTS), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            probs.append(Problem(file, key, None, "a known plausibility limit" + hint, "unknown key"))
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)) or float(v) < 0:
            probs.append(Problem(file, key, None, "a finite number >= 0", v))
            continue
        if k in _INT_KEYS and not float(v).is_integer():
            probs.append(Problem(file, key, None, "an integer >= 0", v))
            continue
        if k.endswith("fraction") and float(v) > 1:
            probs.append(Problem(file, key, None, "a share between 0 and 1", v))
            continue
        lim[k] = int(v) if k in _INT_KEYS else float(v)
    for lo, hi in (("charge_ratio_min", "charge_ratio_max"), ("charge_ratio_warn_min", "charge_ratio_warn_max"),
                   ("free_displacement_ratio_min", "free_displacement_ratio_max"),
                   ("min_reference_snr", "warn_reference_snr")):
        if lim[lo] > lim[hi]:
            probs.append(Problem(file, f"plausibility.{lo}", None, f"a value <= plausibility.{hi} = {lim[hi]:g}",
                                 lim[lo]))
    return lim, probs


def _noise_sigma(x: np.ndarray) -> float:
    """White-noise standard deviation from the median absolute first difference (robust to slow signals)."""
    d = np.diff(x)
    if d.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


def _robust_range(x: np.ndarray) -> float:
    lo, hi = np.percentile(x, [0.5, 99.5])
    return float(hi - lo)


def _flat_top(x: np.ndarray, moving: np.ndarray, lim: Mapping[str, float],
              at_limit=None) -> tuple[int, float, int] | None:
    """(1-based first row, value, count) of a clipped extreme of ``x``, or None.

    Only samples where the drive ``u_cmd`` is changing (``moving``) count: a plateau of a steps drive legitimately
    holds a noise-free signal constant, a clipped channel stays flat while the drive moves on. ``at_limit(ext,
    is_max)``: True where that extreme is the amplifier's declared current limit (:meth:`Rig.at_current_limit`), which
    is then not a clipped one."""
    xf = x[np.isfinite(x)]
    n = xf.size
    if n < 3:
        return None
    need = max(float(lim["flat_top_min_samples"]), lim["flat_top_fraction"] * n)
    lo, hi = float(xf.min()), float(xf.max())
    if lo == hi:
        return None  # constant: reported by other checks
    if _noise_sigma(xf[(xf != lo) & (xf != hi)]) == 0.0:
        return None  # noise-free (simulated) data repeats values on every linear ramp: identity proves nothing
    for ext in (hi, lo):
        if ext == 0.0:
            continue  # exactly 0 V is a physical floor of noise-free data (no force before contact), not a rail
        if at_limit is not None and at_limit(ext, ext == hi):
            continue  # the amplifier's current-limit plateau (rig.yaml amplifier_current_limit_a)
        at = (x == ext) & moving
        cnt = int(at.sum())
        if cnt < need:
            continue
        # quantised signals legitimately repeat values: an extreme only counts as flat when it is the most
        # crowded level near it by far (a clipped sine piles its excursions onto one value)
        vals, counts = np.unique(xf, return_counts=True)
        k = np.searchsorted(vals, ext)
        nb = counts[max(k - 3, 0): k + 4]
        others = np.delete(nb, min(k, 3))
        if others.size and cnt < 4 * float(np.max(others)):
            continue
        return int(np.flatnonzero(at)[0]) + 1, ext, cnt
    return None


def check_plausibility(df: pd.DataFrame, rig, trial: Mapping[str, Any], name: str,
                       limits: Mapping[str, float] | None = None, metrics: dict | None = None) -> list[Problem]:
    """Plausibility findings for one canonical log frame that passed :func:`selfsense.io.logs.check_signals`.

    ``trial`` is the trials.csv record (``tip``, ``reference``, ``role``); ``rig`` a :class:`~selfsense.io.rig.Rig`.
    Returns problems with ``level`` ``"error"`` or ``"warning"``. If ``metrics`` is a dict it receives the
    measured quantities (``released_fraction``, ``charge_ratio``, ``charge_corr``, ``reference_snr``,
    ``free_displacement_ratio``) so that limits can be set from data (``selfsense validate --metrics``).
    """
    if metrics is None:
        metrics = {}
    lim = dict(DEFAULTS)
    lim.update(limits if limits is not None else (getattr(rig, "plausibility", None) or {}))
    out: list[Problem] = []
    err = lambda field, row, exp, found: out.append(Problem(name, field, row, exp, found))  # noqa: E731
    warn = lambda field, row, exp, found: out.append(Problem(name, field, row, exp, found, level="warning"))  # noqa: E731
    n = len(df)
    relay = df["relay"].to_numpy(np.float64)
    released = relay == 0
    n_rel = int(released.sum())
    # --- length and relay ----------------------------------------------------------------------------
    if n_rel < lim["min_samples"]:
        err("relay", None, f"at least {int(lim['min_samples'])} samples with relay = 0 (actuator connected; "
            "rig.yaml plausibility.min_samples)", f"{n_rel} of {n} samples")
        return out
    frac = n_rel / n
    metrics["released_fraction"] = frac
    if frac < lim["min_released_fraction"]:
        first = int(np.flatnonzero(released)[0]) + 1
        err("relay", first, f"relay = 0 (actuator connected) for at least {100 * lim['min_released_fraction']:g} % "
            "of the trial (rig.yaml plausibility.min_released_fraction)",
            f"{100 * frac:.3g} % (released from row {first})")
    starts, ends = true_runs(relay == 1)
    first_rel = int(np.flatnonzero(released)[0])
    later = [(s, e) for s, e in zip(starts, ends) if s > first_rel]
    if later:
        s, e = later[-1]
        if e == n and (e - s) / n > lim["max_final_short_fraction"]:
            err("relay", int(s) + 1, "the actuator to stay connected to the end once released (relay re-shorted "
                f"for good; rig.yaml plausibility.max_final_short_fraction = {lim['max_final_short_fraction']:g})",
                f"relay = 1 from row {int(s) + 1} to the end ({100 * (e - s) / n:.3g} % of the trial)")
        else:
            warn("relay", int(later[0][0]) + 1, "one shorted segment at the start (the charge restarts from 0 at "
                 "every re-short)", f"{len(later)} later relay = 1 segment{'s' if len(later) > 1 else ''}")
    # --- charge against the capacitance (thesis eqs. 55-57) -------------------------------------------
    t = df["t"].to_numpy(np.float64)
    V_s = df["v_shunt"].to_numpy(np.float64) / rig.inamp_gain
    V_c = rig.amplifier_gain * df["u_cmd"].to_numpy(np.float64)
    sh0 = relay == 1
    s0, e0 = (starts[0], ends[0]) if starts.size else (0, 0)
    off = float(np.mean(V_s[s0:e0])) if e0 > s0 else 0.0
    # integrate over the first connected stretch only (the charge restarts at every re-short)
    a = first_rel
    b = int(next((s for s, _ in later), n))
    from selfsense.signals.kernels import shunt_current, trapezoid_increment   # eq. (57), written once

    tt, i_s = t[a:b], shunt_current(V_s[a:b], off, rig.shunt_resistance_ohm)
    q = np.concatenate(([0.0], np.cumsum(trapezoid_increment(i_s[:-1], i_s[1:], np.diff(tt)))))
    V = (V_c - V_s)[a:b]
    C = rig.n_actuators * rig.actuator_catalog.capacitance_f
    ptp_V = float(np.ptp(V)) if V.size else 0.0
    ptp_q = float(np.ptp(q)) if q.size else 0.0
    del sh0
    if ptp_V > 0 and q.size > 2:
        ratio = ptp_q / (C * ptp_V)
        sq, sv = float(np.std(q)), float(np.std(V))
        corr = float(np.corrcoef(q, V)[0, 1]) if sq > 0 and sv > 0 else 0.0
        metrics["charge_ratio"], metrics["charge_corr"] = ratio, corr
        scale_hint = ("check shunt_resistance_ohm, inamp_gain, n_actuators and actuator_catalog.capacitance_f "
                      "in rig.yaml")
        if not (corr >= lim["min_charge_correlation"]):
            err("v_shunt", None, f"a charge that follows the actuator voltage, corr(q, V) >= "
                f"{lim['min_charge_correlation']:g} (a noise-only or disconnected shunt channel?)",
                f"corr {corr:.3g}")
        elif not (lim["charge_ratio_min"] <= ratio <= lim["charge_ratio_max"]):
            err("v_shunt", None, f"a charge of the size n_actuators * capacitance_f * V gives, ratio in "
                f"[{lim['charge_ratio_min']:g}, {lim['charge_ratio_max']:g}] ({scale_hint})",
                f"ratio {ratio:.3g} (ptp q {ptp_q:.3g} C, n_A C_p ptp V {C * ptp_V:.3g} C)")
        elif not (lim["charge_ratio_warn_min"] <= ratio <= lim["charge_ratio_warn_max"]):
            warn("v_shunt", None, f"a charge close to n_actuators * capacitance_f * V, ratio in "
                 f"[{lim['charge_ratio_warn_min']:g}, {lim['charge_ratio_warn_max']:g}] ({scale_hint})",
                 f"ratio {ratio:.3g}")
    # --- flat tops on the measured channels -----------------------------------------------------------
    ref = trial.get("reference")
    ref_col = {"displacement": "laser", "force": "load_cell"}.get(ref)
    u = df["u_cmd"].to_numpy(np.float64)
    moving = np.concatenate(([False], np.diff(u) != 0))[released]
    at_limit = None
    if getattr(rig, "amplifier_current_limit_a", None):
        def at_limit(ext, is_max):
            return rig.at_current_limit(ext, off * rig.inamp_gain, is_max)

        xs = df["v_shunt"].to_numpy(np.float64)[released]
        xs = xs[np.isfinite(xs)]
        if xs.size:
            for ext, is_max in ((float(xs.max()), True), (float(xs.min()), False)):
                cnt = int(np.sum(xs == ext))
                if cnt >= lim["flat_top_min_samples"] and at_limit(ext, is_max):
                    warn("v_shunt", None, "a shunt current within the amplifier's declared current limit (rig.yaml "
                         "amplifier_current_limit_a)", f"{cnt} samples at {ext:.6g} V, the limit's plateau: taken as "
                         "the amplifier at its limit, not as a clipped channel")
    for c in ("v_shunt",) + ((ref_col,) if ref_col else ()):
        x = df[c].to_numpy(np.float64)[released]
        ft = _flat_top(x, moving, lim, at_limit if c == "v_shunt" else None)
        if ft is not None:
            row, val, cnt = ft
            rows_rel = np.flatnonzero(released)
            err(c, int(rows_rel[row - 1]) + 1, "no flat tops: a run of identical values at the channel's extreme "
                "is clipping (amplifier saturated below the ADC range?)",
                f"{cnt} samples ({100 * cnt / max(n_rel, 1):.2g} %) at {val:.6g} V")
    # --- the reference sensor must move where the condition says it does -----------------------------
    tip = trial.get("tip")
    active = (tip == "free" and ref == "displacement") or (tip == "blocked" and ref == "force") or tip == "object"
    if ref_col and active:
        x = df[ref_col].to_numpy(np.float64)[released]
        x = x[np.isfinite(x)]
        if x.size > 10:
            rr, sig = _robust_range(x), _noise_sigma(x)
            snr = rr / sig if sig > 0 else (math.inf if rr > 0 else 0.0)
            metrics["reference_snr"] = snr
            what = {"free": "a free tip moves the laser spot", "blocked": "a blocked tip presses the load cell",
                    "object": "the tip reaches the object"}[tip]
            if snr < lim["min_reference_snr"]:
                # on an object the tip may legitimately never reach it (small drive): a warning there
                (warn if tip == "object" else err)(ref_col, None, f"an active reference channel ({what}; trials.csv tip = {tip!r}, reference = "
                    f"{ref!r}): robust range >= {lim['min_reference_snr']:g} x noise (wrong tip condition or "
                    "sensor not connected?)", f"range {rr:.3g} V = {snr:.3g} x noise")
            else:
                if snr < lim["warn_reference_snr"]:
                    # a sensor that moves, but little above its noise: the references it gives are scored (and the
                    # calibration regressed) with that noise; a weak sensor is not a broken one (noise alone reads
                    # about 5 x), so the dataset is not refused
                    warn(ref_col, None, f"a reference channel well above its noise ({what}): robust range >= "
                         f"{lim['warn_reference_snr']:g} x noise (a weak reference: its noise enters the calibration "
                         "and the error tables)", f"range {rr:.3g} V = {snr:.3g} x noise")
                if tip == "free" and ptp_V > 0:
                    dx = 2.0 * abs(rig.reference.laser_m_per_v) * rr
                    expect = rig.tip_free_displacement_m * ptp_V / rig.actuator_catalog.max_voltage_v
                    r = dx / expect
                    metrics["free_displacement_ratio"] = r
                    if not (lim["free_displacement_ratio_min"] <= r <= lim["free_displacement_ratio_max"]):
                        err(ref_col, None, "a free-tip displacement of the size tip_free_displacement_m * V / "
                            f"max_voltage_v gives, ratio in [{lim['free_displacement_ratio_min']:g}, "
                            f"{lim['free_displacement_ratio_max']:g}] (tip blocked, or laser_m_per_v wrong?)",
                            f"ratio {r:.3g} ({dx:.3g} m for {expect:.3g} m expected)")
    return out
