"""The gap diagnostic: where (budget), which (library screening, selection, confirmation), how far (shrink).

docs/gap.md. Errors are mean absolute errors in % of the measurement's range (the reference's
peak-to-peak over the dataset), evaluated on validation trials only ("held-out"); every "after" number comes from a
refit on calibration trials (CONTRACTS.md augmentation protocol), never from the residual regression.

Held-out rows per measurement: displacement = dx_ref on displacement-reference trials and
dx = 0 on blocked tips; force = f_ref on force-reference trials and f = 0 on free tips.
"""
from __future__ import annotations

import json
import logging
import sys
import time
from dataclasses import dataclass, field
from importlib import resources
from typing import Any, Sequence

import numpy as np
import pandas as pd

from . import stats

_log = logging.getLogger(__name__)
from .data import Case
from .library import FAMILIES, LIBRARY, Effect, effect
from .model import make_estimator
from .protocol import excitation_check, proposal
from .signals import active, branch, deriv, dt_of, first_loading, lowpass, t_active

__all__ = ["Diagnosis", "diagnose", "load_thresholds", "Evaluator", "MEASUREMENTS", "generic_features"]

MEASUREMENTS = ("displacement", "force")
_COL = {"displacement": ("dx_ref", "dx_hat"), "force": ("f_ref", "f_hat")}

DEFAULT_THRESHOLDS = {"screen_member": 0.0, "confirm_rel": 0.05, "unexplained": 0.10}


def load_thresholds(kind: str = "device") -> dict:
    """Thresholds calibrated on effect-free simulations (package data ``thresholds.json``; the command that made
    them is stored beside them). ``kind`` = ``benchmark.threshold_key(simulator, estimator, tier)``: "device"
    (device simulator + fast estimator), "device_sensing" (project estimator), "device_sensing_ri" (RI + creep,
    the benchmark's default), "toy". A kind without a calibration raises ``KeyError`` naming the command that
    makes one (thresholds are specific to simulator, estimator and tier; falling back silently to another kind's
    thresholds gave 8 false alarms in 8 effect-free cases in an earlier full-tier run)."""
    d = json.loads(resources.files("selfsense.gap").joinpath("thresholds.json").read_text())
    block = d if kind == "device" else d.get(kind)
    if not isinstance(block, dict) or "thresholds" not in block:
        known = ["device"] + sorted(k for k, v in d.items() if isinstance(v, dict) and "thresholds" in v)
        parts = kind.split("_")
        est = "sensing_ri" if "ri" in parts else ("sensing" if "sensing" in parts else "fast")
        tier = "full" if parts[-1] == "full" else "fast"
        raise KeyError(f"gap thresholds: no null calibration for {kind!r} in selfsense/gap/thresholds.json "
                       f"(calibrated: {', '.join(known)}); make one with `selfsense gap calibrate --n 240 --seed 1 "
                       f"--tier {tier} --sim {parts[0]} --estimator {est} --jobs 2 --out FILE` and merge it under "
                       f"{kind!r}")
    return {**DEFAULT_THRESHOLDS, **block["thresholds"]}


# ----------------------------------------------------------------------------------------------- evaluation


def held_out_rows(case: Case, roles=("validation",)) -> dict:
    """measurement -> list of (trial, mask, reference array) for trials of the given roles."""
    out = {m: [] for m in MEASUREMENTS}
    for tid, row in case.meta.iterrows():
        if row["role"] not in roles:
            continue
        df = case.trials[tid]
        act = active(df)
        for m in MEASUREMENTS:
            refc = _COL[m][0]
            if row["reference"] == m:
                ref = df[refc].to_numpy(float)
                mask = act & np.isfinite(ref)
            elif (m == "displacement" and row["tip"] == "blocked") or (m == "force" and row["tip"] == "free"):
                ref = np.zeros(len(df))
                mask = act.copy()
            else:
                continue
            if mask.sum() > 10:
                out[m].append((tid, mask, ref))
    return out


def measurement_ranges(case: Case) -> dict:
    """Peak-to-peak of each reference over all trials that measure it [m, N]."""
    rng = {}
    for m in MEASUREMENTS:
        vals = [case.trials[t][_COL[m][0]].to_numpy(float) for t, r in case.meta.iterrows() if r["reference"] == m]
        v = np.concatenate(vals) if vals else np.array([])
        v = v[np.isfinite(v)]
        rng[m] = float(np.ptp(v)) if len(v) and np.ptp(v) > 0 else 1.0
    return rng


@dataclass
class Evaluation:
    """Held-out errors of one fitted model: per measurement / per trial [% of range], and the signed errors."""

    error: dict            # measurement -> % of range
    per_trial: dict        # (measurement, trial) -> % of range
    e: dict                # measurement -> concatenated signed error [% of range] (held-out rows)
    estimates: dict = field(repr=False, default_factory=dict)
    model: Any = field(repr=False, default=None)

    @property
    def score(self) -> float:
        vals = [v for v in self.error.values() if np.isfinite(v)]
        return float(np.mean(vals)) if vals else float("nan")


class Evaluator:
    """Refit the estimator with a set of augmentations on the calibration trials; evaluate held-out (cached)."""

    def __init__(self, case: Case, estimator: str = "fast", roles=("validation",), **est_kw):
        self.case, self.kind, self.kw = case, estimator, est_kw
        self.rows = held_out_rows(case, roles)
        self.ranges = measurement_ranges(case)
        self.cache: dict[frozenset, Evaluation] = {}
        self.n_fits = 0
        self.bar = None  # optional tqdm bar advanced by one per refit (see diagnose(progress=...))

    def blocks(self, n_per_trial: int = 8) -> dict:
        out = {}
        for m, rows in self.rows.items():
            labs = np.concatenate([np.full(int(mask.sum()), i) for i, (_, mask, _) in enumerate(rows)]) if rows else np.array([], int)
            out[m] = stats.contiguous_blocks(labs, n_per_trial) if len(labs) else labs
        return out

    def __call__(self, names: frozenset | Sequence[str] = frozenset()) -> Evaluation:
        key = frozenset(names)
        if key in self.cache:
            return self.cache[key]
        augs = [effect(n).augmentation() for n in sorted(key)]
        model = make_estimator(self.kind, self.case.rig, augs, **self.kw)
        model.fit(self.case.trials, self.case.meta)
        self.n_fits += 1
        if self.bar is not None:
            if self.bar.total is not None and self.bar.n >= self.bar.total:
                self.bar.total = self.bar.n + 1
            self.bar.update(1)
        need = {t for rows in self.rows.values() for t, _, _ in rows}
        est = {t: model.estimate(self.case.trials[t]) for t in need}
        error, per_trial, e = {}, {}, {}
        for m, rows in self.rows.items():
            parts = []
            for tid, mask, ref in rows:
                d = (est[tid][_COL[m][1]].to_numpy(float) - ref)[mask] / self.ranges[m] * 100.0
                per_trial[(m, tid)] = float(np.mean(np.abs(d)))
                parts.append(d)
            if parts:
                e[m] = np.concatenate(parts)
                error[m] = float(np.mean(np.abs(e[m])))
            else:
                e[m] = np.array([])
                error[m] = float("nan")
        ev = Evaluation(error, per_trial, e, est, model)
        self.cache[key] = ev
        return ev


# ----------------------------------------------------------------------------------------------- screening


def static_features(df: pd.DataFrame) -> np.ndarray:
    """Nuisance basis of the screening: a static function of (V, branch) -- the part of the residual that the
    thesis' free-case subtraction (000_18d138f03f1777c3.txt sec. 5.3, Fig. 39) attributes to the base hysteresis
    mismatch. Effects are screened on what they explain *beyond* it."""
    V = df["V"].to_numpy(float)
    Vm = float(np.max(np.abs(V))) or 1.0
    v = V / Vm
    b = branch(V, 0.02 * Vm)
    return np.column_stack([v, v**2, v**3, b, b * v, b * v**2])


def generic_features(df: pd.DataFrame) -> np.ndarray:
    """Model-error-model basis for the 'unexplained structure' test (Ljung & Guo):
    polynomials of V, branch terms, lags, derivatives, time. Inputs only (never the residual)."""
    dt = dt_of(df["t"].to_numpy())
    V = df["V"].to_numpy(float)
    Vm = float(np.max(np.abs(V))) or 1.0
    v = V / Vm
    b = branch(V, 0.02 * Vm)
    ta = t_active(df)
    T = max(ta.max(), 1e-9)
    cols = [v, v**2, v**3, b, b * v, b * v**2, np.sqrt(np.abs(v)), np.maximum(v - 0.1, 0), ta / T, v * ta / T]
    for tau in (0.003, 0.03, 0.3, 3.0):
        cols.append(lowpass(v, tau, dt) - v)
    d1 = deriv(v, dt, 0.002)
    cols += [d1 / (np.max(np.abs(d1)) or 1.0)]
    d2 = deriv(d1, dt, 0.002)
    cols += [d2 / (np.max(np.abs(d2)) or 1.0)]
    return np.column_stack(cols)


class Screen:
    """Residual-regression screening data for one model's held-out residual (per measurement, decimated)."""

    def __init__(self, case: Case, ev: Evaluation, rows: dict, effects: Sequence[Effect], max_rows: int = 2500,
                 n_blocks: int = 8, extra: dict | None = None):
        self.meas = [m for m in MEASUREMENTS if len(ev.e.get(m, [])) > 50]
        self.F, self.y, self.blocks, self.slices = {}, {}, {}, {}
        self.names = [e.name for e in effects if e.screen is not None]
        feats_cache = {}
        for m in self.meas:
            n_tot = len(ev.e[m])
            step = max(1, n_tot // max_rows)
            blocks_all = []
            mats = []
            for i, (tid, mask, _) in enumerate(rows[m]):
                if tid not in feats_cache:
                    df, est = case.trials[tid], ev.estimates[tid]
                    fl = {e.name: np.asarray(e.screen(df, est), float) for e in effects if e.screen is not None}
                    fl["__generic__"] = generic_features(df)
                    fl["__static__"] = static_features(df)
                    feats_cache[tid] = fl
                fl = feats_cache[tid]
                mats.append({k: v[mask] for k, v in fl.items()})
                blocks_all.append(np.full(int(mask.sum()), i))
            lab = stats.contiguous_blocks(np.concatenate(blocks_all), n_blocks)
            sl = slice(None, None, step)
            self.y[m] = ev.e[m][sl]
            self.blocks[m] = lab[sl]
            cols, idx, j = [], {}, 0
            for k in self.names + ["__generic__", "__static__"]:
                A = np.vstack([mm[k] for mm in mats])[sl]
                A = A / np.where(A.std(axis=0) > 0, A.std(axis=0), 1.0)
                cols.append(A)
                idx[k] = np.arange(j, j + A.shape[1])
                j += A.shape[1]
            self.F[m] = np.column_stack(cols)
            self.slices[m] = idx
        self.cv = {m: stats.GramCV(self.F[m], self.y[m], self.blocks[m]) for m in self.meas}

    def cols(self, m: str, names: Sequence[str]) -> np.ndarray | None:
        if not names:
            return None
        return np.concatenate([self.slices[m][n] for n in names])

    def gain(self, add: Sequence[str], base: Sequence[str] = (), weights: dict | None = None) -> float:
        """Mean over measurements of the blocked-CV gain of adding ``add`` feature groups to ``base``
        (leave-one-block-out ridge, contiguous blocks; ``weights`` = block-bootstrap counts per measurement)."""
        g = []
        for m in self.meas:
            c = None if weights is None else weights[m]
            cv = self.cv[m]
            base_ = ["__static__"] + list(base)
            sb = cv.sse(self.cols(m, base_), c)
            sa = cv.sse(self.cols(m, base_ + list(add)), c)
            g.append(1 - sa / sb if sb > 0 else 0.0)
        return float(np.mean(g)) if g else 0.0

    def forward_select(self, thr: float, max_k: int = 3, weights: dict | None = None,
                       candidates: Sequence[str] | None = None) -> list[tuple[str, float]]:
        chosen: list[tuple[str, float]] = []
        cands = list(candidates or self.names)
        while len(chosen) < max_k:
            base = [c for c, _ in chosen]
            gains = {n: self.gain([n], base, weights) for n in cands if n not in base}
            if not gains:
                break
            best = max(gains, key=gains.get)
            if gains[best] <= thr:
                break
            chosen.append((best, gains[best]))
        return chosen

    def bootstrap_weights(self, rng: np.random.Generator) -> dict:
        """Block-bootstrap counts per block (whole contiguous blocks drawn with replacement)."""
        w = {}
        for m in self.meas:
            nb = len(self.cv[m].labels)
            w[m] = np.bincount(rng.integers(0, nb, nb), minlength=nb).astype(float)
        return w


# ----------------------------------------------------------------------------------------------- result


@dataclass
class Diagnosis:
    attribution: pd.DataFrame
    budget: pd.DataFrame
    shrink: pd.DataFrame
    verdict: dict
    figures_data: dict = field(default_factory=dict, repr=False)


def diagnose(case: Case, estimator: str = "fast", thresholds: dict | None = None, n_boot: int = 30,
             seed: int = 0, max_effects: int = 3, with_budget: bool = True, ci_boot: int = 200,
             max_candidates: int = 14, progress: bool | None = False, **est_kw) -> Diagnosis:
    """Run the whole diagnostic on one dataset (no truth needed; the truth folder only adds the stage budget).

    Returns :class:`Diagnosis` with the contract tables (attribution, budget, shrink) and the verdict.
    ``progress``: a terminal progress bar (stderr) counting model refits, the time-consuming unit; its total is an
    upper bound (base fit, structural search, Shapley refits) refined as the search proceeds. ``None`` shows it
    only on a terminal, ``False`` (default) never.
    """
    from tqdm import tqdm

    thr = {**load_thresholds("device" if estimator == "fast" else f"device_{estimator}"), **(thresholds or {})}
    excitation = excitation_check(case.trials, case.meta)
    ev = Evaluator(case, estimator, **est_kw)
    ev.bar = bar = tqdm(total=1, desc="gap diagnose: base fit", unit="refit", disable=None if progress is None else not progress,
                        file=sys.stderr) if progress is not False else None
    t0 = time.perf_counter()
    base = ev(frozenset())
    _log.info("gap diagnose: nominal model (%s) fitted and scored in %.1f s; held-out error %.2f %% of range",
              estimator, time.perf_counter() - t0, base.score)
    screen = Screen(case, base, ev.rows, LIBRARY)

    # --- which: screening gains, forward selection, block-bootstrap selection frequencies
    gains = {n: screen.gain([n]) for n in screen.names}
    fam_gain = {f: screen.gain([e.name for e in LIBRARY if e.family == f and e.name in screen.names])
                for f in FAMILIES if any(e.family == f and e.name in screen.names for e in LIBRARY)}
    # candidates for the structural search: positive screening gain, best first (the residual regression only
    # ranks; every selection below is decided by refit on calibration + held-out error)
    cands = [n for n in sorted(gains, key=lambda n: -gains[n]) if gains[n] > thr["screen_member"]][:max_candidates]
    blocks = ev.blocks()
    _log.info("gap diagnose: %d candidate effects from the residual screening: %s", len(cands), ", ".join(cands))
    if bar is not None:  # upper bound: greedy path over the candidates, then Shapley subsets of <= max_effects
        bar.total = bar.n + sum(max(len(cands) - k, 0) for k in range(max_effects)) + 2 ** min(max_effects, len(cands))
        bar.set_description("gap diagnose: structural search")
        bar.refresh()

    def block_stats(S):
        e = ev(S)
        out = {}
        for m in e.e:
            if len(e.e[m]):
                nb = int(blocks[m].max()) + 1
                out[m] = (np.bincount(blocks[m], np.abs(e.e[m]), nb), np.bincount(blocks[m], None, nb))
        return out

    bs_cache: dict = {}

    def score_w(S, w=None):
        S = frozenset(S)
        if S not in bs_cache:
            bs_cache[S] = block_stats(S)
        vals = []
        for m, (sums, cnt) in bs_cache[S].items():
            c = np.ones_like(sums) if w is None else w[m]
            vals.append(float(c @ sums) / max(float(c @ cnt), 1.0))
        return float(np.mean(vals)) if vals else float("nan")

    member_thr = thr.get("confirm_rel_member", {}) or {}

    def _thr(c):
        return float(member_thr.get(c, thr["confirm_rel"]))

    def greedy(w=None):
        cur, path, rels = frozenset(), [], []
        s0 = score_w(cur, w)
        cur_s = s0
        while len(path) < max_effects:
            opts = [c for c in cands if c not in cur]
            if w is not None:  # bootstrap replicates re-use the refits of the main path (no new fits)
                opts = [c for c in opts if frozenset(cur | {c}) in ev.cache]
            if not opts:
                break
            sc = {c: score_w(cur | {c}, w) for c in opts}
            # margin over the member's own null threshold (calibrated on effect-free simulations)
            margin = {c: ((cur_s - sc[c]) / s0 if s0 > 0 else 0.0) - _thr(c) for c in opts}
            best = max(margin, key=margin.get)
            rel = (cur_s - sc[best]) / s0 if s0 > 0 else 0.0
            if margin[best] <= 0:
                break
            cur, cur_s = cur | {best}, sc[best]
            path.append(best)
            rels.append(rel)
        return path, rels

    confirmed, rels = greedy()
    tried = {c: (base.score - score_w({c})) / base.score for c in cands}
    rng = np.random.default_rng(seed)
    freq = {n: 0.0 for n in screen.names}
    for _ in range(n_boot):
        w = {m: np.bincount(rng.integers(0, int(blocks[m].max()) + 1, int(blocks[m].max()) + 1),
                            minlength=int(blocks[m].max()) + 1).astype(float) for m in blocks if len(blocks[m])}
        for n in greedy(w)[0]:
            freq[n] += 1.0 / n_boot
    chosen = [(n, gains[n]) for n in cands]

    # --- attribution: exact Shapley over confirmed effects (2^k refits), per measurement and overall
    _log.info("gap diagnose: structural search and %d bootstrap replicates done after %d refits (%.1f s); "
              "confirmed: %s", n_boot, ev.n_fits, time.perf_counter() - t0, ", ".join(confirmed) or "none")
    if bar is not None:
        bar.total = bar.n + 2 ** len(confirmed) + len(confirmed)
        bar.set_description("gap diagnose: attribution")
        bar.refresh()

    def val(m):
        return lambda S: base.error[m] - ev(S).error[m] if m != "mean" else base.score - ev(S).score

    meas_all = [m for m in MEASUREMENTS if np.isfinite(base.error.get(m, np.nan))]
    phi = {m: stats.shapley_exact(confirmed, val(m)) for m in meas_all + ["mean"]} if confirmed else {}
    inter = stats.shapley_interactions(confirmed, val("mean")) if len(confirmed) > 1 else {}
    final = ev(frozenset(confirmed))

    # --- unexplained structure: generic model-error model on the final residual
    scr_final = Screen(case, final, ev.rows, []) if confirmed else screen
    g_generic = scr_final.gain(["__generic__"])
    unexplained = bool(g_generic > thr["unexplained"])
    where = _where(case, ev, final) if unexplained else None

    # --- tables
    rows = []
    for e in LIBRARY:
        for m in meas_all:
            alone = ev.cache.get(frozenset([e.name]))
            rows.append({
                "effect": e.name, "family": e.family, "selected": e.name in confirmed,
                "selection_frequency": freq.get(e.name, 0.0), "cv_gain": gains.get(e.name, 0.0),
                "error_before": base.error[m],
                "error_after": alone.error[m] if alone is not None else np.nan,
                "shapley_share": phi[m].get(e.name, 0.0) if e.name in confirmed else 0.0,
                "measurement": m,
            })
    attribution = pd.DataFrame(rows, columns=["effect", "family", "selected", "selection_frequency", "cv_gain",
                                              "error_before", "error_after", "shapley_share", "measurement"])
    shrink = shrink_table(ev, confirmed, seed=seed, n_boot=ci_boot)
    budget = error_budget(case, ev, base) if with_budget else pd.DataFrame()
    fams = list(dict.fromkeys(effect(n).family for n in confirmed))
    verdict = {
        "effects": confirmed,
        "families": fams,
        "unexplained": unexplained,
        "unexplained_where": where,
        "message": ("no effect beyond the noise floor and the base model mismatch" if not confirmed and not unexplained
                    else "; ".join([f"{n} (shrinks held-out error by {phi['mean'][n]:.2f} % of range)" for n in confirmed]
                                   + ([f"unexplained structure at {where}"] if unexplained else []))),
        "screened": [{"effect": n, "cv_gain": g} for n, g in chosen],
        "family_cv_gain": fam_gain,
        "confirm_rel_gain": tried,
        "shapley_pts": {m: {k: float(v) for k, v in d.items()} for m, d in phi.items()},
        "interactions": {f"{a}|{b}": float(v) for (a, b), v in inter.items()},
        "generic_cv_gain_after": g_generic,
        "generic_cv_gain_before": screen.gain(["__generic__"]),
        "error_before": base.error, "error_after_all": final.error,
        "score_before": base.score, "score_after_all": final.score,
        "thresholds": thr, "n_refits": ev.n_fits, "estimator": estimator,
        "suggestions": {n: {"model_change": effect(n).suggestion, "confirming_experiment": effect(n).experiment}
                        for n in confirmed},
        "excitation": excitation,
        "protocol_proposal": proposal(excitation),
    }
    figs = {"base": base, "final": final, "ev": ev}
    _log.info("gap diagnose: done, %d refits in %.1f s", ev.n_fits, time.perf_counter() - t0)
    if bar is not None:
        bar.total = bar.n
        bar.close()
        ev.bar = None
    return Diagnosis(attribution, budget, shrink, verdict, figs)


# ----------------------------------------------------------------------------------------------- how far


def shrink_table(ev: Evaluator, confirmed: Sequence[str], seed: int = 0, n_boot: int = 200) -> pd.DataFrame:
    """Thesis Table 3 style: per measurement and per trial, held-out error before / after each effect alone /
    after all, with block-bootstrap 90 % intervals (paired resamples of contiguous blocks)."""
    configs = [("before", frozenset())] + [(f"after {n}", frozenset([n])) for n in confirmed]
    if len(confirmed) > 1:
        configs.append(("after all", frozenset(confirmed)))
    elif confirmed:
        configs.append(("after all", frozenset(confirmed)))
    blocks = ev.blocks()
    rows = []
    for m, trows in ev.rows.items():
        if not trows:
            continue
        evs = {lab: ev(S) for lab, S in configs}
        # per-trial offsets into the concatenated error
        off = np.cumsum([0] + [int(mk.sum()) for _, mk, _ in trows])
        scopes = [("all", slice(0, off[-1]))] + [(tid, slice(off[i], off[i + 1])) for i, (tid, _, _) in enumerate(trows)]
        for scope, sl in scopes:
            b = blocks[m][sl]
            rng = np.random.default_rng(seed)
            idxs = [stats.block_bootstrap_indices(b, rng) for _ in range(n_boot)]
            for lab, e in evs.items():
                a = np.abs(e.e[m][sl])
                boots = np.array([a[i].mean() for i in idxs]) if n_boot else np.array([a.mean()])
                rows.append({"measurement": m, "trial": scope, "model": lab, "error_pct": float(a.mean()),
                             "ci_low": float(np.quantile(boots, 0.05)), "ci_high": float(np.quantile(boots, 0.95))})
    return pd.DataFrame(rows, columns=["measurement", "trial", "model", "error_pct", "ci_low", "ci_high"])


# ----------------------------------------------------------------------------------------------- where


def regime_labels(df: pd.DataFrame, est: pd.DataFrame, f_range: float) -> dict:
    """Operating-regime labels per sample (docs/gap.md)."""
    t = df["t"].to_numpy(float)
    dt = dt_of(t)
    V = df["V"].to_numpy(float)
    Vm = float(np.max(np.abs(V))) or 1.0
    lvl = np.select([V < Vm / 3, V < 2 * Vm / 3], ["low", "mid"], "high")
    b = branch(V, 0.02 * Vm)
    dV = np.abs(deriv(V, dt, 0.005))
    moving = dV > 0.05 * Vm  # > 5 % of the range per second
    br = np.where(~moving, "hold", np.where(b > 0, "rising", "falling"))
    fl = first_loading(V, 0.01 * Vm).astype(bool) & (b > 0) & moving
    u = df["u_cmd"].to_numpy(float) if "u_cmd" in df else V
    jumps = np.flatnonzero(np.abs(np.diff(u)) > 0.05 * (np.ptp(u) or 1.0)) + 1
    last = np.full(len(t), -np.inf)
    if len(jumps):
        ix = np.searchsorted(jumps, np.arange(len(t)), side="right") - 1
        last = np.where(ix >= 0, t[jumps[np.maximum(ix, 0)]], -np.inf)
    since = t - last
    since_lab = np.select([since < 0.1, since < 1.0, np.isfinite(since)], ["<0.1 s", "0.1-1 s", ">1 s"], "no step")
    hold = np.where(moving, "moving", np.where(V < 0.1 * Vm, "hold 0 V", np.where(V > 0.5 * Vm, "hold high V", "hold mid V")))
    f = est["f_hat"].to_numpy(float)
    contact = f > 0.05 * f_range
    was = np.maximum.accumulate(contact)
    cstate = np.where(contact, "contact", np.where(was, "release", np.where(b > 0, "approach", "free")))
    ta = t_active(df)
    q = np.minimum((ta / (ta.max() or 1.0) * 4).astype(int), 3)
    elapsed = np.array(["0-25 %", "25-50 %", "50-75 %", "75-100 %"])[q]
    return {"input_level": lvl, "branch": br, "loading": np.where(fl, "first loading", "later"),
            "time_since_step": since_lab, "hold": hold, "contact": cstate, "elapsed": elapsed}


def _where(case: Case, ev: Evaluator, evn: Evaluation) -> str:
    best, bscore = "all regimes", 0.0
    for m, trows in ev.rows.items():
        if not trows:
            continue
        labs = {}
        for tid, mask, _ in trows:
            rl = regime_labels(case.trials[tid], evn.estimates[tid], ev.ranges["force"])
            for k, v in rl.items():
                labs.setdefault(k, []).append(v[mask])
        a = np.abs(evn.e[m])
        tot = a.mean() if len(a) else 0
        for k, parts in labs.items():
            lab = np.concatenate(parts)
            for val in np.unique(lab):
                sel = lab == val
                if sel.mean() < 0.05:
                    continue
                r = a[sel].mean() / tot if tot else 0
                if r > bscore:
                    best, bscore = f"{m}: {k} = {val} ({a[sel].mean():.2f} % vs {tot:.2f} % of range overall)", r
    return best


def error_budget(case: Case, ev: Evaluator, base: Evaluation) -> pd.DataFrame:
    """Where: overall and per-trial error, error by regime, free-case decomposition (thesis Fig. 39),
    sensitivity of tip error to PZT-level error, noise floor, and (simulated data) the stage Shapley budget."""
    rows = []

    def add(section, item, m, err, share=np.nan, n=np.nan, unit="% of range"):
        rows.append({"section": section, "item": item, "measurement": m, "value": float(err), "share": float(share),
                     "n": float(n), "unit": unit})

    for m, trows in ev.rows.items():
        if not trows:
            continue
        a = np.abs(base.e[m])
        add("total", "held-out error", m, a.mean(), 1.0, len(a))
        for tid, _, _ in trows:
            add("trial", tid, m, base.per_trial[(m, tid)])
        # regimes
        labs = {}
        for tid, mask, _ in trows:
            rl = regime_labels(case.trials[tid], base.estimates[tid], ev.ranges["force"])
            for k, v in rl.items():
                labs.setdefault(k, []).append(v[mask])
        for k, parts in labs.items():
            lab = np.concatenate(parts)
            for val in np.unique(lab):
                sel = lab == val
                add(f"regime:{k}", str(val), m, a[sel].mean(), a[sel].sum() / a.sum() if a.sum() else np.nan, sel.sum())
        # noise floor: RMS of the first difference / sqrt(2) of the error (white part), % of range
        d = np.diff(base.e[m])
        add("floor", "white-noise part of the error (RMS of diff / sqrt 2)", m, np.sqrt(np.mean(d**2) / 2), n=len(d))
    rows += free_case_rows(case, ev, base)
    rows += sensitivity_rows(case, ev, base)
    if case.truth:
        try:
            rows += stage_budget_rows(case, ev, base)
        except Exception as exc:  # truth folder in an unexpected layout: report, do not fail the diagnosis
            rows.append({"section": "stage", "item": f"unavailable: {exc}", "measurement": "", "value": np.nan,
                         "share": np.nan, "n": np.nan, "unit": ""})
    return pd.DataFrame(rows, columns=["section", "item", "measurement", "value", "share", "n", "unit"])


def _lookup(V_src, b_src, err_src, V, b, nbins=40):
    """Mean error of the source (free) trial by (V bin, branch), interpolated at (V, branch)."""
    lo, hi = float(np.min(V_src)), float(np.max(V_src))
    edges = np.linspace(lo, hi + 1e-12, nbins + 1)
    cent = 0.5 * (edges[1:] + edges[:-1])
    out = np.zeros_like(V)
    for s in (-1, 1):
        sel = b_src == s
        if sel.sum() < 5:
            sel = np.ones_like(b_src, bool)
        k = np.clip(np.digitize(V_src[sel], edges) - 1, 0, nbins - 1)
        sums = np.bincount(k, err_src[sel], nbins)
        cnt = np.bincount(k, None, nbins)
        ok = cnt > 0
        if not ok.any():
            continue
        mean = sums[ok] / cnt[ok]
        tgt = b == s
        out[tgt] = np.interp(V[tgt], cent[ok], mean)
    return out


def free_case_rows(case: Case, ev: Evaluator, base: Evaluation) -> list[dict]:
    """Thesis sec. 5.3 / Fig. 39: the force (displacement) error of the free calibration case at the same input
    history (V level and branch) is the hysteresis-mismatch part; subtracting it leaves the load-dependent part."""
    cal_free = [t for t, r in case.meta.iterrows() if r["role"] == "calibration" and r["tip"] == "free"]
    if not cal_free:
        return []
    tid0 = cal_free[0]
    df0 = case.trials[tid0]
    est0 = base.model.estimate(df0)
    act0 = active(df0)
    V0 = df0["V"].to_numpy(float)[act0]
    Vm = float(np.max(np.abs(V0))) or 1.0
    b0 = branch(df0["V"].to_numpy(float), 0.02 * Vm)[act0]
    src = {"force": est0["f_hat"].to_numpy(float)[act0] / ev.ranges["force"] * 100}
    if np.isfinite(df0["dx_ref"].to_numpy(float)[act0]).all():
        src["displacement"] = (est0["dx_hat"].to_numpy(float) - df0["dx_ref"].to_numpy(float))[act0] / ev.ranges["displacement"] * 100
    out = []
    for m, trows in ev.rows.items():
        if m not in src or not trows:
            continue
        parts = []
        for tid, mask, _ in trows:
            df = case.trials[tid]
            V = df["V"].to_numpy(float)
            b = branch(V, 0.02 * Vm)
            parts.append(_lookup(V0, b0, src[m], V[mask], b[mask]))
        mis = np.concatenate(parts)
        e = base.e[m]
        before, after = np.mean(np.abs(e)), np.mean(np.abs(e - mis))
        out.append({"section": "free_case", "item": "error before subtraction", "measurement": m, "value": before,
                    "share": 1.0, "n": len(e), "unit": "% of range"})
        out.append({"section": "free_case", "item": "load-dependent remainder (after Fig. 39 subtraction)",
                    "measurement": m, "value": after, "share": after / before if before else np.nan, "n": len(e),
                    "unit": "% of range"})
        out.append({"section": "free_case", "item": "hysteresis-mismatch part (free case at same V history)",
                    "measurement": m, "value": before - after, "share": (before - after) / before if before else np.nan,
                    "n": len(e), "unit": "% of range"})
    return out


def sensitivity_rows(case: Case, ev: Evaluator, base: Evaluation) -> list[dict]:
    """Tip error per PZT-level error: d(dx, f)/dV_p and d(dx, f)/dQ from the fitted eq. (52) coefficients,
    expressed per 10 mV of V_p and per 1 % of the charge range; and the free-tip H(q) mismatch times it."""
    c = base.model.coef_
    cal_free = [t for t, r in case.meta.iterrows() if r["role"] == "calibration" and r["tip"] == "free"]
    df0 = case.trials[cal_free[0]]
    act = active(df0)
    Qr = float(np.ptp(df0["q"].to_numpy(float)[act])) or 1.0
    est0 = base.model.estimate(df0)
    # free-tip eq. (55) residual = H mismatch in V_p units: V_p_model - Q/(n_A C_p) is zero for a perfect H
    from selfsense.sensing.core import h_target

    from .model import rig_params

    p = rig_params(case.rig)
    h_err = h_target(est0["V_p"].to_numpy(float), df0["q"].to_numpy(float), 1.0 / (p["n_A"] * p["C_p"]))[act]
    h_rms = float(np.sqrt(np.mean((h_err - h_err.mean()) ** 2)))
    out = []
    for m, (kq, kv) in {"displacement": ("A1", "A2"), "force": ("B21", "B22")}.items():
        r = ev.ranges[m]
        out.append({"section": "sensitivity", "item": "tip error per 10 mV of V_p", "measurement": m,
                    "value": abs(c[kv]) * 0.01 / r * 100, "share": np.nan, "n": np.nan, "unit": "% of range per 10 mV"})
        out.append({"section": "sensitivity", "item": "tip error per 1 % of the charge range", "measurement": m,
                    "value": abs(c[kq]) * 0.01 * Qr / r * 100, "share": np.nan, "n": np.nan,
                    "unit": "% of range per 1 % of Q range"})
        out.append({"section": "sensitivity", "item": f"free-tip H(q) mismatch ({h_rms * 1e3:.1f} mV RMS) mapped to the tip",
                    "measurement": m, "value": abs(c[kv]) * h_rms / r * 100, "share": np.nan, "n": np.nan,
                    "unit": "% of range (RMS)"})
    return out


def stage_budget_rows(case: Case, ev: Evaluator, base: Evaluation) -> list[dict]:
    """Simulated data only (truth folder): substitute true blocks for model blocks in all 2^3 combinations and
    report each stage's exact Shapley share of the held-out error.

    Blocks: ``charge`` (true q instead of the measured, eq. 57), ``hysteresis`` (true V_p instead of
    V - H(q), eqs. 27/55), ``coefficients`` (oracle least squares of the true tip signals on the chosen (Q, V_p)
    over all trials, instead of the calibration regression of eq. 52 rows on the same inputs). The coefficient
    block is always re-derived for the chosen inputs so every combination is self-consistent.
    """
    from selfsense.sensing.core import piezo_voltage

    model = base.model
    truth = case.truth
    stages = ("charge", "hysteresis", "coefficients")

    def inputs(tid, S):
        df, tr = case.trials[tid], truth[tid]
        n = min(len(df), len(tr))
        Q = tr["q"].to_numpy(float)[:n] if "charge" in S else df["q"].to_numpy(float)[:n]
        if "hysteresis" in S:
            Vp = tr["V_p"].to_numpy(float)[:n]
        else:
            Vp = piezo_voltage(df["V"].to_numpy(float)[:n], model.hysteresis_(Q))   # thesis eq. (27)
        return np.column_stack([Q, Vp]), n

    def coefs(S):
        Xd, yd, Xf, yf = [], [], [], []
        oracle = "coefficients" in S
        for tid, row in case.meta.iterrows():
            if tid not in truth or (not oracle and row["role"] != "calibration"):
                continue
            X, n = inputs(tid, S)
            df, tr = case.trials[tid], truth[tid]
            act = active(df)[:n]
            if oracle:
                Xd.append(X[act]); yd.append(tr["dx_tip"].to_numpy(float)[:n][act])
                Xf.append(X[act]); yf.append(tr["f_tip"].to_numpy(float)[:n][act])
                continue
            if row["reference"] == "displacement":
                r = df["dx_ref"].to_numpy(float)[:n]; ok = act & np.isfinite(r)
                Xd.append(X[ok]); yd.append(r[ok])
            if row["tip"] == "blocked":
                Xd.append(X[act]); yd.append(np.zeros(act.sum()))
            if row["reference"] == "force":
                r = df["f_ref"].to_numpy(float)[:n]; ok = act & np.isfinite(r)
                Xf.append(X[ok]); yf.append(r[ok])
            if row["tip"] == "free":
                Xf.append(X[act]); yf.append(np.zeros(act.sum()))
        from .model import _lstsq

        return _lstsq(np.vstack(Xd), np.concatenate(yd)), _lstsq(np.vstack(Xf), np.concatenate(yf))

    cache: dict = {}

    def E(S):
        S = frozenset(S)
        if S not in cache:
            cd, cf = coefs(S)
            out = {}
            for m, trows in ev.rows.items():
                parts = []
                for tid, mask, ref in trows:
                    X, n = inputs(tid, S)
                    est = X @ (cd if m == "displacement" else cf)
                    parts.append(((est - ref[:n]) / ev.ranges[m] * 100)[mask[:n]])
                out[m] = float(np.mean(np.abs(np.concatenate(parts)))) if parts else np.nan
            cache[S] = out
        return cache[S]

    rows = []
    for m in ev.rows:
        if not ev.rows[m]:
            continue
        phi = stats.shapley_exact(stages, lambda S: E(frozenset())[m] - E(S)[m])
        tot = E(frozenset())[m]
        rows.append({"section": "stage", "item": "error with all model blocks (2-coefficient rows)", "measurement": m,
                     "value": tot, "share": 1.0, "n": np.nan, "unit": "% of range"})
        for s_ in stages:
            rows.append({"section": "stage", "item": s_, "measurement": m, "value": phi[s_],
                         "share": phi[s_] / tot if tot else np.nan, "n": np.nan, "unit": "% of range (Shapley)"})
        rows.append({"section": "stage", "item": "remainder with all true blocks", "measurement": m,
                     "value": E(frozenset(stages))[m], "share": E(frozenset(stages))[m] / tot if tot else np.nan,
                     "n": np.nan, "unit": "% of range"})
    return rows
