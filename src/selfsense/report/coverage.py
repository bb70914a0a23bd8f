"""Drive coverage of the calibration (the excitation check): which features of each trial's drive the calibration
trials never showed H(q), so that the report can say which validation errors rest on an extrapolation of the model.

H(q) (thesis 000_18d138f03f1777c3.txt eqs. 29-40: plays, superposition and creep operators; or another model of the
registry) is identified on the calibration trials only, and a model is only measured where its data went:

* **charge range**: the operators' thresholds are spread over the calibrated charge range (eq. 32); beyond it the
  model is extrapolated;
* **reversals (minor loops)**: every reversal of the drive starts a new branch; a trial that reverses with a smaller
  amplitude than any calibration reversal runs minor loops the calibration never showed. A Prandtl-Ishlinskii
  operator predicts them from the calibration's branches (every branch after a reversal is the same function of the
  travel, eq. 32: a property of the model, not a measurement); a Preisach or Duhem model extrapolates them;
* **holds**: the creep operators' time constants (eq. 40) are only measured over the holds the calibration has; a
  hold longer than any calibration hold extrapolates the creep (a sine-only calibration, the thesis protocol, has
  none);
* **rates**: an excursion faster or slower than any calibration excursion extrapolates the model's rate dependence
  (its creep part, whose time constants are fixed per decade, eq. 40; or an amplifier lag). Rates are taken as the
  excursion's duration, not in V/s: a small reversal at the calibration's frequency is a minor loop, not a slow
  drive.

Reference-free: only ``t``, ``V``, ``q`` and ``relay`` of each trial are read, never a reference, and nothing here is
fitted or chosen -- Table 3 does not depend on it. The report then sets the validation trials' Table 3 errors with
and without such a feature side by side (:func:`coverage_markdown`).

Definitions (samples with the relay open; V smoothed by block means of about 2 ms):

* reversal: a confirmed turning point of V with a dead band of :data:`DEAD_BAND` of the calibration trials' V span
  (at least :data:`BAND_NOISE` noise sd of a block mean); its amplitude is the change of V since the previous
  reversal (the first excursion from rest and the last, unconfirmed one are no reversals);
* hold: V steady for at least :data:`MIN_HOLD_S` -- a stretch of 50-ms block means of V that all stay within
  ``tol = max(0.5 % of the calibration's V span, 4 noise sd of a block mean)`` of its first block (so a ramp slower
  than ``tol`` per 0.5 s counts as held) -- leaving out the rest before V first leaves its starting level by 10 % of
  the span (before the drive moves, nothing relaxes). Block means, not samples: noise does not break a hold;
* excursion duration: the time V takes from 10 % to 90 % of an excursion (from the start of the record or a
  reversal to the next reversal), less the holds within it, over 0.8 (a ramp's own duration).
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
import pandas as pd

__all__ = ["DEAD_BAND", "RANGE_TOL", "MINOR_FACTOR", "HOLD_FACTOR", "RATE_FACTOR", "drive_features",
           "coverage_table", "coverage_markdown", "FEATURES"]

#: reversal dead band, as a fraction of the calibration trials' V span (noise and ripple never reverse the drive)
DEAD_BAND = 0.02
#: charge beyond the calibrated range that counts, as a fraction of the calibrated charge span
RANGE_TOL = 0.05
#: a trial's smallest reversal below this fraction of the calibration's smallest one: minor loops it lacks
MINOR_FACTOR = 0.5
#: a trial's longest hold above this multiple of the calibration's longest one (or any hold where the calibration has
#: none): holds it lacks
HOLD_FACTOR = 2.0
#: a trial's shortest (longest) excursion below (above) this fraction (multiple) of the calibration's shortest
#: (longest): rates it lacks
RATE_FACTOR = 2.0
#: block length [s] of the smoothing of V before the reversals are found
BLOCK_S = 0.002
#: block length [s] of the means of V in which holds are found, and the shortest hold [s]
HOLD_BLOCK_S = 0.05
MIN_HOLD_S = 0.5
#: a hold's band, as a fraction of the calibration trials' V span
HOLD_BAND = 0.005
#: the rest before the drive ends where V first leaves its starting level by this fraction of the calibration's span
REST_LEAVE = 0.1
#: the reversal dead band is at least this many noise standard deviations of a block mean of V
BAND_NOISE = 10.0

#: feature key -> words of the report
FEATURES = {"range": "charge beyond the calibrated range", "minor": "reversals smaller than any calibration reversal",
            "holds": "holds longer than any calibration hold", "fast": "excursions faster than the calibration's",
            "slow": "excursions slower than the calibration's"}

_COLUMNS = ["trial", "role", "duration_s", "v_lo_v", "v_hi_v", "q_lo_c", "q_hi_c", "charge_beyond_pct",
            "n_reversals", "min_reversal_v", "longest_hold_s", "n_holds", "excursion_min_s", "excursion_max_s",
            "lacks"]


def _block_means(x: np.ndarray, k: int) -> np.ndarray:
    n = len(x) // k * k
    if n == 0:
        return np.asarray(x, float)[:1]
    return np.asarray(x[:n], float).reshape(-1, k).mean(axis=1)


def _turning_points(v: np.ndarray, band: float) -> tuple[np.ndarray, int]:
    """``(confirmed, last)``: the indices of the confirmed turning points of ``v`` with a dead band ``band`` (a maximum
    is confirmed once ``v`` has fallen ``band`` below it, a minimum likewise), and the index of the running
    excursion's extremum at the end of the record (-1 where ``v`` never moved ``band``): that one is not a reversal."""
    pts: list[int] = []
    i_ext, direction = 0, 0   # direction of the running excursion: +1 rising, -1 falling, 0 not yet moved
    for i in range(1, len(v)):
        x = v[i]
        if direction == 0:
            if abs(x - v[0]) >= band:
                direction = 1 if x > v[0] else -1
                i_ext = i
        elif direction > 0:
            if x > v[i_ext]:
                i_ext = i
            elif v[i_ext] - x >= band:
                pts.append(i_ext)
                direction, i_ext = -1, i
        else:
            if x < v[i_ext]:
                i_ext = i
            elif x - v[i_ext] >= band:
                pts.append(i_ext)
                direction, i_ext = 1, i
    return np.asarray(pts, int), (i_ext if direction != 0 else -1)


def _excursion_durations(v: np.ndarray, t: np.ndarray, bounds: np.ndarray, holds: list[tuple[float, float]]
                         ) -> np.ndarray:
    """The duration [s] of every excursion between consecutive ``bounds`` (indices into ``v``, ``t``): the time from
    its 10 % to its 90 % crossing, less the time spent in ``holds`` ((start, end) [s]) within it, over 0.8."""
    out = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        seg = v[a:b + 1]
        amp = seg[-1] - seg[0]
        if amp == 0 or len(seg) < 3:
            continue
        rel = (seg - seg[0]) / amp
        t10 = float(t[a + int(np.argmax(rel >= 0.1))])
        t90 = float(t[a + int(np.argmax(rel >= 0.9))])
        held = sum(max(0.0, min(e, t90) - max(s, t10)) for s, e in holds)
        if t90 - t10 - held > 0:
            out.append((t90 - t10 - held) / 0.8)
    return np.asarray(out, float)


def _noise_sd(V: np.ndarray) -> float:
    """White-noise standard deviation of V per sample: the data contract's own estimate (the median absolute first
    difference, :func:`selfsense.io.plausibility._noise_sigma`; slow drives do not count)."""
    from selfsense.io.plausibility import _noise_sigma

    return _noise_sigma(np.asarray(V, float))


def _holds(t: np.ndarray, V: np.ndarray, dt: float, v_span: float) -> list[tuple[float, float]]:
    """``(start, end)`` [s] of the holds of V (module docstring), the rest before the drive left out: the record is
    cut into stretches of 50-ms block means that stay within ``tol`` of their first block; a stretch of at least
    :data:`MIN_HOLD_S` is a hold (a ramp slower than ``tol`` per :data:`MIN_HOLD_S` is held too), unless it lies
    before V first leaves its starting level by :data:`REST_LEAVE` of the span."""
    k = max(1, round(HOLD_BLOCK_S / dt))
    b, tb = _block_means(V, k), _block_means(t, k)
    if len(b) < 3:
        return []
    tol = max(HOLD_BAND * v_span, 4.0 * _noise_sd(V) / np.sqrt(k))
    left = np.flatnonzero(np.abs(b - b[0]) > REST_LEAVE * v_span)
    if left.size == 0:
        return []                                      # the drive never moved: all rest
    out, a = [], 0
    for i in range(1, len(b) + 1):
        if i == len(b) or abs(b[i] - b[a]) > tol:
            t0, t1 = float(tb[a]) - 0.5 * k * dt, float(tb[i - 1]) + 0.5 * k * dt
            if a >= left[0] and t1 - t0 >= MIN_HOLD_S:
                out.append((t0, t1))
            a = i
    return out


def drive_features(df: pd.DataFrame, v_band: float, name: str = "trial", v_span: float | None = None) -> dict:
    """The drive features of one trial (module docstring) from its prepared signals (``t``, ``V``, ``q``,
    ``relay``); ``v_band``: the reversal dead band [V] (widened to :data:`BAND_NOISE` noise sd of a block mean where
    the trial's V is noisier); ``v_span``: the calibration's V span [V] (the scale of the holds' band;
    ``v_band / DEAD_BAND`` where not given)."""
    missing = [c for c in ("t", "V", "q", "relay") if c not in df.columns]
    if missing:
        raise ValueError(f"drive coverage: trial {name!r} has no column(s) {missing} (expected the prepared signals "
                         "t, V, q, relay of the ingest stage)")
    open_ = df["relay"].to_numpy(dtype=float) < 0.5
    t = df["t"].to_numpy(dtype=float)[open_]
    V = df["V"].to_numpy(dtype=float)[open_]
    q = df["q"].to_numpy(dtype=float)[open_]
    ok = np.isfinite(t) & np.isfinite(V) & np.isfinite(q)
    t, V, q = t[ok], V[ok], q[ok]
    if len(t) < 10:
        raise ValueError(f"drive coverage: trial {name!r} has {len(t)} finite samples with the relay open "
                         "(expected at least 10)")
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        raise ValueError(f"drive coverage: trial {name!r}: column 't' does not increase (median step {dt:g} s; "
                         "expected increasing time stamps)")
    span = v_band / DEAD_BAND if v_span is None else v_span
    k = max(1, round(BLOCK_S / dt))
    vb, tb, qb = _block_means(V, k), _block_means(t, k), _block_means(q, k)
    band = max(v_band, BAND_NOISE * _noise_sd(V) / np.sqrt(k))
    pts, last = _turning_points(vb, band)
    holds = _holds(t, V, dt, span)
    # reversals: between confirmed turning points only; excursions: also the first one, from the start of the
    # record (its 10-90 % crossing is the drive's own), not the last, which the record may cut short
    amps = np.abs(np.diff(vb[pts]))
    bounds = np.concatenate(([0], pts)) if last >= 0 else pts
    rates = _excursion_durations(vb, tb, bounds, holds)
    return {"duration_s": float(t[-1] - t[0]), "v_lo_v": float(vb.min()), "v_hi_v": float(vb.max()),
            "q_lo_c": float(qb.min()), "q_hi_c": float(qb.max()), "amplitudes_v": amps, "excursions_s": rates,
            "holds_s": [e - s for s, e in holds], "n_reversals": len(pts)}


_READ = ["t", "V", "q", "relay"]


def _frame(x, name: str) -> pd.DataFrame:
    """A trial's signals: the frame itself, or its Parquet file read (only the columns used here)."""
    if isinstance(x, pd.DataFrame):
        return x
    import pyarrow.parquet as pq

    have = set(pq.read_schema(x).names)
    missing = [c for c in _READ if c not in have]
    if missing:
        raise ValueError(f"drive coverage: {x}: no column(s) {missing} (expected the prepared signals t, V, q, relay "
                         f"of trial {name!r})")
    return pd.read_parquet(x, columns=_READ)


def coverage_table(signals: Mapping[str, pd.DataFrame | str], meta: pd.DataFrame) -> pd.DataFrame:
    """One row per trial (in the order of ``meta``, trials.csv): its drive features and ``lacks``, the features
    (:data:`FEATURES` keys, ``;``-separated) that the calibration trials do not cover; empty for a calibration trial,
    which defines the coverage. ``signals``: trial -> prepared signals (a frame, or its Parquet file, read one trial
    at a time)."""
    meta = meta.set_index("trial") if "trial" in meta.columns else meta
    trials = [t for t in meta.index if t in signals]
    listed = [t for t in meta.index if str(meta.loc[t, "role"]) == "calibration"]
    if not listed:
        raise ValueError("drive coverage: trials.csv lists no calibration trial (column 'role': expected at least "
                         "one 'calibration')")
    absent = [t for t in listed if t not in signals]
    if absent:
        raise ValueError(f"drive coverage: calibration trial(s) {absent} of trials.csv have no signals (expected "
                         "the prepared signals of every calibration trial: the coverage is theirs)")
    cal = listed
    v_span = 0.0
    lo, hi = np.inf, -np.inf
    for c in cal:
        df = _frame(signals[c], c)
        v = df["V"].to_numpy(dtype=float)[df["relay"].to_numpy(dtype=float) < 0.5]
        v = v[np.isfinite(v)]
        if v.size:
            lo, hi = min(lo, float(v.min())), max(hi, float(v.max()))
    v_span = hi - lo if hi > lo else 0.0
    if not v_span > 0:
        raise ValueError(f"drive coverage: the calibration trials {cal} do not move the actuator voltage (column 'V': "
                         "expected a drive)")
    band = DEAD_BAND * v_span
    feats = {t: drive_features(_frame(signals[t], t), band, t, v_span) for t in trials}

    def union(key):
        return np.concatenate([np.atleast_1d(np.asarray(feats[c][key], float)) for c in cal])

    q_lo = min(feats[c]["q_lo_c"] for c in cal)
    q_hi = max(feats[c]["q_hi_c"] for c in cal)
    q_span = q_hi - q_lo
    if not q_span > 0:
        raise ValueError(f"drive coverage: the charge of the calibration trials {cal} does not vary (column 'q': "
                         "expected the integrated shunt charge of a drive)")
    cal_amp, cal_rate, cal_hold = union("amplitudes_v"), union("excursions_s"), union("holds_s")
    min_amp = float(cal_amp.min()) if cal_amp.size else np.inf
    longest = float(cal_hold.max()) if cal_hold.size else 0.0
    r_lo, r_hi = (float(cal_rate.min()), float(cal_rate.max())) if cal_rate.size else (np.nan, np.nan)
    rows = []
    for t in trials:
        f = feats[t]
        beyond = max(0.0, f["q_hi_c"] - q_hi, q_lo - f["q_lo_c"]) / q_span * 100.0
        amps, rates, holds = f["amplitudes_v"], f["excursions_s"], f["holds_s"]
        lacks = []
        if t not in cal:
            if beyond > RANGE_TOL * 100.0:
                lacks.append("range")
            if amps.size and np.isfinite(min_amp) and amps.min() < MINOR_FACTOR * min_amp:
                lacks.append("minor")
            if holds and max(holds) > HOLD_FACTOR * longest:
                lacks.append("holds")
            if rates.size and np.isfinite(r_lo) and rates.min() < r_lo / RATE_FACTOR:
                lacks.append("fast")
            if rates.size and np.isfinite(r_hi) and rates.max() > RATE_FACTOR * r_hi:
                lacks.append("slow")
        rows.append({"trial": t, "role": str(meta.loc[t, "role"]), "duration_s": f["duration_s"],
                     "v_lo_v": f["v_lo_v"], "v_hi_v": f["v_hi_v"], "q_lo_c": f["q_lo_c"], "q_hi_c": f["q_hi_c"],
                     "charge_beyond_pct": float(beyond), "n_reversals": int(f["n_reversals"]),
                     "min_reversal_v": float(amps.min()) if amps.size else np.nan,
                     "longest_hold_s": float(max(holds)) if holds else 0.0, "n_holds": len(holds),
                     "excursion_min_s": float(rates.min()) if rates.size else np.nan,
                     "excursion_max_s": float(rates.max()) if rates.size else np.nan, "lacks": ";".join(lacks)})
    return pd.DataFrame(rows, columns=_COLUMNS)


def _num(x, fmt: str) -> str:
    """``x`` formatted, ``-`` where missing; no negative zero (a rest at -0.003 V reads 0.0)."""
    if x is None or not np.isfinite(x):
        return "-"
    s = format(x, fmt)
    return s[1:] if s.startswith("-") and float(s) == 0 else s


def coverage_markdown(cov: pd.DataFrame, per_trial: pd.DataFrame | None = None,
                      hold_rows: Mapping | None = None) -> str:
    """The coverage table for people, and, with the score rule's ``per_trial`` table, the validation trials' mean
    Table 3 error (% of range) with and without each feature the calibration lacks (a description of this run,
    not a fit: nothing is chosen on it). ``hold_rows``: the fitted model's hold-row record (``fit_report_
    ["hysteresis"]["hold_rows"]``, docs/method.md 6b'): where it was applied, a trial's holds that the calibration
    lacks are marked as fitted from that trial's own V and Q (the creep of H(q) within them, not its level)."""
    hr = hold_rows or {}
    held = set(hr.get("trials") or ()) if hr.get("applied") and hr.get("fitted", True) else set()
    cov = cov.assign(lacks=[x if isinstance(x, str) else "" for x in cov["lacks"]])   # a CSV read back: NaN = ""
    cal = cov[cov["role"] == "calibration"]
    lines = ["### Drive coverage of the calibration", "",
             f"What the calibration trials ({', '.join(cal['trial'])}) show H(q), and which drive features of the "
             "other trials they do not cover: there the model is extrapolated (reversals found with a dead band of "
             f"{DEAD_BAND * 100:g} % of the calibration's V span; holds of at least "
             f"{MIN_HOLD_S:g} s after the drive has moved; "
             "excursion durations from the 10-90 % crossing time).", "",
             "| trial | role | duration [s] | V range [V] | charge beyond the calibrated range [%] | reversals | "
             "smallest reversal [V] | longest hold [s] | excursion durations [s] | calibration lacks |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for _, r in cov.iterrows():
        lacks = "; ".join(FEATURES[k] + (" (their creep fitted from this trial's V and Q: hold rows)"
                                          if k == "holds" and r["trial"] in held else "")
                          for k in str(r["lacks"]).split(";") if k) or \
            ("(defines the coverage)" if r["role"] == "calibration" else "nothing")
        lines.append(f"| {r['trial']} | {r['role']} | {r['duration_s']:.1f} | {_num(r['v_lo_v'], '.1f')} to "
                     f"{_num(r['v_hi_v'], '.1f')} | {r['charge_beyond_pct']:.1f} | {r['n_reversals']} | "
                     f"{_num(r['min_reversal_v'], '.2f')} | "
                     f"{r['longest_hold_s']:.1f} | {_num(r['excursion_min_s'], '.3g')} to "
                     f"{_num(r['excursion_max_s'], '.3g')} | {lacks} |")
    val = cov[cov["role"] == "validation"]
    lacking = val[val["lacks"] != ""]
    lines.append("")
    if not (cal["n_reversals"] > 0).any():
        lines.append("The calibration trials have no reversal: minor loops and excursion rates are not assessed.")
        lines.append("")
    if val.empty:
        lines.append("No validation trial.")
    elif lacking.empty:
        lines.append("The calibration covers every drive feature of the validation trials listed here.")
    else:
        lines.append(f"{len(lacking)} of {len(val)} validation trials rely on drive features the calibration lacks: "
                     "their Table 3 errors include the H(q) model's extrapolation there.")
    if per_trial is not None and not lacking.empty:
        missing = [c for c in ("trial", "role", "measurement", "percent_of_range") if c not in per_trial.columns]
        if missing:
            raise ValueError(f"drive coverage: the per-trial errors (per_trial.csv) have no column(s) {missing}")
        pt = per_trial[per_trial["role"] == "validation"].set_index("trial")
        keys = [k for k in FEATURES if any(k in str(x).split(";") for x in val["lacks"])]
        lines += ["", "| validation trials | displacement: trials, mean % of range | force: trials, mean % of range |",
                  "|---|---|---|"]

        def cell(names, measurement):
            sub = pt[(pt.index.isin(names)) & (pt["measurement"] == measurement)]
            return f"{len(sub)}, {sub['percent_of_range'].mean():.2f} %" if len(sub) else "0, -"

        for label, names in ([("covered by the calibration", list(val.loc[val["lacks"] == "", "trial"]))]
                             + [(f"with {FEATURES[k]}", [r["trial"] for _, r in val.iterrows()
                                                         if k in str(r["lacks"]).split(";")]) for k in keys]):
            lines.append(f"| {label} | {cell(names, 'displacement')} | {cell(names, 'force')} |")
    return "\n".join(lines) + "\n"
