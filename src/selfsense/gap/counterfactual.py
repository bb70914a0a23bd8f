"""How far it shrinks: each confirmed effect applied as a correction with its stage-fitted coefficients FIXED
(docs/gap.md: refitting eq. 52 with free extra columns re-fits the nominal mismatch; a fixed
correction predicted the counterfactual tip-error change to ~0.02 points).

A correction acts where the stage says the effect acts:

* mechanical-stage charge path (leakage, offset drift, dielectric absorption, temperature): the laser follows
  ``a Q/q_span + c col``, so the actuator's charge is ``Q + q_span c col / a``;
* charge-free motion (creep, a tip mode): ``dx^ <- dx^ + c col``, taken out of the calibration references too
  (moving them into the charge instead also moves V_p = V - H(Q) and made the tip error worse by 5-11 points in
  the tip tier);
* charge path (electrical stage): ``Q = G[V] + c col`` -> ``Q - c col``;
* amplifier: ``V <- V + (rate_limit(V_c) - V_c)`` (the actuator saw the limited amplifier output);
* operator state / virgin curve (electrical stage): ``V <- V + v_span c col / b`` (the voltage at which the
  nominal charge response gives the measured charge);
* load-stage members: ``f^ <- f^ + c col`` (and the same taken out of the calibration references).

Members of the stage chain that the estimator carries (:data:`CHAIN_MEMBERS`: the charge link's leakage and offset drift
and dielectric absorption, :mod:`selfsense.chain.charge`; the voltage link's amplifier slew and current limits,
:mod:`selfsense.chain.amplifier`; the load link's stress and charge-free creep members, :mod:`selfsense.chain.load`,
:mod:`selfsense.chain.creep`) are not
corrected with the stage's coefficients: the estimator is recalibrated with the member forced on, so that "how far it
shrinks" is the error of the chain the user would get with that member, identified jointly with H(q) (the whole H(q)
selection runs again, :func:`_make`) and the sensing coefficients. For a member the fitted estimator already carries
(adopted for Table 3), "how far it shrinks" is its own contribution: Table 3 of the chain recalibrated with it forced
off, minus Table 3 (the same number as :func:`chain_contributions`), so the shrink is always measured from the chain
without the effect's model.

The estimator is then recalibrated on the corrected calibration trials and scored on the corrected validation
trials (thesis Table 3 style: mean |error| in % of the reference range per trial, then per measurement), for no
effect, each effect alone and all of them together; exact Shapley values over the effects of that joint game; a
paired block bootstrap over contiguous blocks of the validation trials gives the sampling spread of each change; its
upper side is widened by :data:`INTERVAL_UPPER_WIDEN` for what the recalibrated chain leaves of the effect (the 90 %
interval, :func:`widened_interval`). "All
together" joins the confirmed effects whose model, added alone, does not make Table 3 worse; the others keep their own
(negative) number and are listed with the reason (``joint_left_out``).
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import pandas as pd

from selfsense.parallel import fork_map

from .stages import MEMBERS

__all__ = ["CORRECTION_KIND", "CHAIN_MEMBERS", "INTERVAL_UPPER_WIDEN", "corrections", "tip_table", "counterfactual",
           "chain_contributions", "widened_interval"]

#: factor on the upper side (prediction to the bootstrap's 95 % quantile) of the 90 % interval of "how far it
#: shrinks". The block bootstrap holds the spread of the validation blocks around the recalibrated chain's change,
#: not what the chain with the effect's model still leaves of the effect against the world without it: in six blind
#: tip campaigns (seeds 20261213-20261219, 208 scored cases) 65 % of the truths fell inside the bootstrap interval,
#: and most of those outside lay above it (the member recovers part of the cost, not more). Split-conformal
#: calibration on those cases, the lower side kept as the bootstrap gives it: the smallest factor that puts
#: ceil(0.9 (n + 1)) of the n truths inside, rounded up to 0.01. The cases are those the tip tier scores (a true
#: shrink beyond 3 tip noise floors); where the truth is within noise of 0 the interval covers less (0.59 on the 142
#: such named cases of those campaigns, docs/gap.md). ``python benchmarks/interval_calibration.py``
#: derives it from the committed campaign records and scores it leave-one-campaign-out
#: (benchmarks/gap_tip/interval_calibration.md); ``tests/gap/test_interval.py`` checks this value against that
#: derivation. A device unlike the simulator's families may need another factor: the raw bootstrap interval is kept
#: beside it (``*_interval_90_blocks``).
INTERVAL_UPPER_WIDEN = 3.26


def widened_interval(shrink: float, blocks: Sequence[float], upper: float = INTERVAL_UPPER_WIDEN) -> list:
    """The 90 % interval of a predicted change ``shrink`` from its block-bootstrap interval ``blocks`` = [lo, hi]:
    ``[min(lo, shrink), shrink + upper * max(hi - shrink, 0)]`` (the lower side as the bootstrap gives it, the upper
    side widened, :data:`INTERVAL_UPPER_WIDEN`). Always contains the bootstrap interval and the prediction."""
    if not upper >= 1.0:   # also NaN
        raise ValueError(f"widened_interval: upper factor {upper!r}: expected a number >= 1 (a smaller one would "
                         "narrow the bootstrap interval)")
    lo, hi = float(blocks[0]), float(blocks[1])
    s = float(shrink)
    if not (np.isfinite(lo) and np.isfinite(hi) and np.isfinite(s)):
        return [lo, hi]   # nothing to widen around: the bootstrap's interval as it is
    return [min(lo, s), max(hi, s + upper * max(hi - s, 0.0))]

#: effect -> the estimator's charge-link member that carries it (``SelfSensingEstimator.members``)
CHAIN_MEMBERS = {"slow.leakage": "leakage", "slow.offset_drift": "offset_drift", "rate.amplifier": "amplifier",
                 "slow.absorption": "absorption", "load.stress_hysteresis": "stress", "slow.creep": "tip_creep",
                 "slow.temperature": "temperature"}

CORRECTION_KIND = {
    "slow.leakage": "charge_mech", "slow.offset_drift": "charge_mech", "slow.absorption": "charge_mech",
    "slow.temperature": "charge_mech", "slow.creep": "dx_out", "rate.mechanism_mode": "dx_out",
    "slow.leakage@el": "charge_el", "slow.offset_drift@el": "charge_el", "slow.temperature@el": "charge_el",
    "rate.amplifier": "voltage_amp", "hysteresis.preload": "voltage_el", "hysteresis.one_sided": "voltage_el",
    "load.stress_hysteresis": "f_out", "load.contact": "f_out", "load.stress_hysteresis@blocked": "voltage_blk",
    "load.stress_hysteresis@blocked_h": "voltage_blk", "hysteresis.one_sided@mechanical": "charge_mech"}
#: chain members that enter no row of the chain's H(q) calibration (the tip's charge-free creep: columns of the
#: sensing regression; the temperature member: decided after it): forced on, a recalibration keeps the held H(q) form
#: and shares the H(q) calibration of the same inputs without it (:func:`_make`)
OUTSIDE_H_MEMBERS = frozenset({"tip_creep", "temperature"})
#: of those, forced on, these select H(q) again on their corrected charges (``SelfSensingEstimator._temperature_refit``:
#: seconds, against a fraction of one for the shared calibration): each a pool unit of its own, started first
RESELECTING_MEMBERS = frozenset({"temperature"})
N_BLOCKS = 6


def corrections(verdict: dict, chain: bool = False) -> dict:
    """effect -> trial -> {"q"|"V"|"dx"|"f": additive correction over the samples after the relay release}.
    ``chain``: the estimator carries the :data:`CHAIN_MEMBERS` (they get no data correction: it is recalibrated
    with the member on instead)."""
    sigs, ctx = verdict["_signals"], verdict["_context"]
    out = {}
    for e in verdict["effects"]:
        if chain and e["effect"] in CHAIN_MEMBERS:  # carried by the estimator's chain: recalibrated with the member on
            out[e["effect"]] = {}
            continue
        acc = [x for x in sorted(e["acceptances"], key=lambda x: -x["score"]) if x["member"] in CORRECTION_KIND]
        if not acc:  # named from a stage without a correction (the relay-short trend): no tip change predicted
            out[e["effect"]] = {}
            continue
        st = verdict["stages"][acc[0]["stage"]]
        a = next(x for x in st["accepted"] if x["member"] == acc[0]["member"])
        m = MEMBERS[a["member"]]
        kind = CORRECTION_KIND[m.name]
        c = np.asarray(a["coef"], float)
        per = {}
        for s in sigs:
            if m.stage in ("load", "blocked") and not {"f_hat", "v_h"} <= set(s.extra):
                continue
            cols = m.cols(s, ctx, a["grid_value"])
            col = cols[:, 0] if kind == "voltage_amp" else cols @ c
            if kind == "charge_mech":
                per[s.name] = {"q": ctx["q_span"] * col / a["coef_ref"]}
            elif kind == "charge_el":
                per[s.name] = {"q": -col}
            elif kind == "voltage_amp":
                per[s.name] = {"V": col}
            elif kind == "voltage_el":
                per[s.name] = {"V": ctx["v_span"] * col / a["coef_ref"]}
            elif kind == "voltage_blk":  # the blocked stage's target is V itself: take the stress part out
                per[s.name] = {"V": -col}
            elif kind == "dx_out":
                per[s.name] = {"dx": col}
            else:
                per[s.name] = {"f": col}
        out[e["effect"]] = per
    return out


def _add(df: pd.DataFrame, col: str, a: int, v: np.ndarray) -> None:
    """``df[col][a:] += v`` on a fresh array (the frame may share its columns with the uncorrected one)."""
    x = df[col].to_numpy(float).copy()
    x[a:] += v
    df[col] = x


def _apply(trials: dict, corr: list[dict], meta: pd.DataFrame | None = None) -> tuple[dict, dict]:
    """Corrected trials and the output corrections. An output correction (charge-free motion, load stage) is also
    taken out of the calibration trials' references, so that the recalibrated estimator does not fit it twice."""
    new, outc = {}, {}
    for t, df in trials.items():
        parts = [c[t] for c in corr if t in c]
        if not parts:
            new[t] = df
            continue
        df = df.copy()
        n = len(df)
        oc = {}
        for p in parts:
            for k, v in p.items():
                a = n - len(v)
                if k in ("q", "V"):
                    _add(df, k, a, v)
                    if k == "V" and "V_c" in df:
                        _add(df, "V_c", a, v)
                else:
                    o = oc.setdefault(k, np.zeros(n))
                    o[a:] += v
                    if meta is not None and t in meta.index and meta.loc[t, "role"] == "calibration":
                        _add(df, "dx_ref" if k == "dx" else "f_ref", a, -v)
        new[t] = df
        outc[t] = oc
    return new, outc


def _make(make_estimator: Callable, rig, members: dict | None = None, form: tuple = (), reuse=None,
          held: dict | None = None):
    """An unfitted estimator of the configuration, with ``members`` forced and, when ``form`` is given (the fitted
    estimator's :meth:`~selfsense.sensing.estimator.SelfSensingEstimator.selected_form`), its H(q) form held: a
    recalibration refits the selected form beside the straight line instead of repeating the whole selection, so
    that before and after differ by the correction alone, not by a change of the selected form.
    ``reuse``: the fitted estimator's leakage search (:func:`_search_of`), taken over by a recalibration on the same
    calibration inputs (the estimator checks their digest) instead of searched again. The held form is refitted
    without the blocked CV between it and the straight line (``h_selection_cv = False``: the same model bit for bit
    wherever the CV would select the form; where it would not, the form is still held -- the recalibration scores
    the correction, not a change of form).

    With a member forced *on* the form is not held: the member is identified jointly with H(q) (its columns, or its
    change of the charge or voltage, enter the H fit's rows) and the whole H(q) selection runs on those rows, as in the
    estimator the user gets with it. Held, it answered another question: on the joint tip cases 37 and 5 of seed
    20261204 (stress-dependent hysteresis, effect-free twins 3.52 and 4.23 %) the stress member gave 15.79 and 11.57 %
    with the form held, 2.16 and 3.97 % with the selection (a Duhem form, ranked 1st and 8th without the member). A
    carried member forced *off* (its contribution) keeps the form it was selected with. So does a member forced on
    that enters no row of the H(q) fit (:data:`OUTSIDE_H_MEMBERS`: the tip's charge-free creep, identified after H(q)
    in the sensing regression): its H(q) selection would run on the very rows of the chain without the member
    (measured on tweezer_sim: three such selections, 8-10 s each, of the gap job's 52 s, each selecting the held
    form). Where the creep member then calibrates H(q) again without an adopted offset drift (docs/method.md 6h), that
    refit keeps the held form too, as a member forced off does.

    ``held`` (:func:`_held_members`): members whose decision the recalibration takes from the fitted chain, under the
    ``members`` forced here: the voltage link's lag member where the fitted chain does not carry it (its gate, a
    blocked CV of the held form with and without the lag column, would otherwise run in every recalibration: 9 s of
    the 35 s gap job on tweezer_sim, where the chain does not adopt it)."""
    est = make_estimator(rig)
    if hasattr(est, "h_selection_prune"):   # only the selected row is read here: dominated candidates are stopped
        est.h_selection_prune = True
    forced_on = {k for k, v in (members or {}).items() if v == "on"}
    if form and not (forced_on - OUTSIDE_H_MEMBERS) and hasattr(est, "h_candidates"):
        est.h_candidates, est.h_selection_cv = tuple(form), False
    if reuse and hasattr(est, "leakage_search_reuse"):
        est.leakage_search_reuse = dict(reuse)
    if members:
        if not hasattr(est, "members"):
            raise TypeError(f"{type(est).__name__} carries no chain members; cannot force {sorted(members)}")
        est.members = dict(members)
    if held and hasattr(est, "members"):
        est.members = {**dict(held), **dict(est.members or {})}
    return est


def _held_members(fitted) -> dict:
    """Members a recalibration of ``fitted`` takes over undecided (:func:`_make`): the amplifier lag off where the fitted
    chain does not carry it."""
    if fitted is None or not hasattr(fitted, "amplifier_lag_"):
        return {}
    return {} if (fitted.amplifier_lag_ or {}).get("applied") else {"amplifier_lag": "off"}


def _splits_fit(est) -> bool:
    """Whether ``est.fit`` is :meth:`~selfsense.sensing.estimator.SelfSensingEstimator.fit` itself (H(q) calibrated,
    then the sensing regression), so that a recalibration may run the two apart and share the first."""
    from selfsense.sensing.estimator import SelfSensingEstimator

    return isinstance(est, SelfSensingEstimator) and type(est).fit is SelfSensingEstimator.fit


def adopted_members(fitted) -> dict:
    """member -> whether the fitted estimator carries it (the Table 3 configuration)."""
    if fitted is None or not hasattr(fitted, "members"):
        return {}
    hold_rows = (getattr(fitted, "fit_report_", {}) or {}).get("hysteresis", {}).get("hold_rows", {})
    amp = amplifier_parts(fitted)
    return {"leakage": bool(getattr(fitted, "leakage_s_", 0.0)), "offset_drift": bool(getattr(fitted, "offset_drift_",
                                                                                              False)),
            "hold_rows": bool(hold_rows.get("applied", False)),
            "amplifier": amp["current_limit"] or amp["slew"],
            "absorption": bool((getattr(fitted, "absorption_", None) or {}).get("applied", False)),
            "quantiser": bool((getattr(fitted, "quantiser_", None) or {}).get("applied", False)),
            "stress": bool((getattr(fitted, "stress_", None) or {}).get("applied", False)),
            "tip_creep": bool((getattr(fitted, "tip_creep_", None) or {}).get("applied", False)),
            "temperature": bool((getattr(fitted, "temperature_", None) or {}).get("applied", False)),
            "amplifier_lag": amp["lag"]}


def amplifier_parts(fitted) -> dict:
    """Which parts of the voltage link's amplifier member the fitted estimator carries: the current-limit rebuild, the
    slew limit (never both, :mod:`selfsense.chain.amplifier`) and the bandwidth lag."""
    a = getattr(fitted, "amplifier_", None) or {}
    return {"current_limit": bool(a.get("applied", False)), "slew": bool((a.get("slew") or {}).get("applied", False)),
            "lag": bool((getattr(fitted, "amplifier_lag_", None) or {}).get("applied", False))}


def _search_of(fitted):
    """The fitted estimator's leakage search (:func:`selfsense.sensing.estimator.leakage_search_of`), or None."""
    from selfsense.sensing.estimator import leakage_search_of

    return leakage_search_of(fitted)


def _form_of(fitted) -> tuple:
    """The fitted estimator's selected H(q) form (held in the recalibrations of the diagnostic, see :func:`_make`),
    or ``()``."""
    return fitted.selected_form() if fitted is not None and hasattr(fitted, "selected_form") else ()


def tip_table(trials: dict, meta: pd.DataFrame, rig, make_estimator: Callable, out_corr: dict | None = None,
              estimator=None, members: dict | None = None, form: tuple = (), reuse=None,
              seen: dict | None = None, inputs_of: Callable | None = None, held: dict | None = None):
    """Per validation trial: thesis Table 3's error (mean |estimate - reference| in % of the trial's reference
    range, every finite sample, :func:`selfsense.report.tables.trial_errors`) and the same per contiguous block
    (for the bootstrap). ``estimator``: an already fitted one (else ``make_estimator(rig)`` is fitted).

    ``seen`` and ``inputs_of`` (with ``estimator``): estimates already made by this estimator, kept in ``seen`` under
    ``(id(estimator), trial, inputs_of(trial))``, where ``inputs_of(trial)`` names the corrections of the trial's
    estimator inputs (Q, V) applied to ``trials``: tables that differ only by output corrections (charge-free motion,
    load stage) score the same estimate of the same inputs, which is made once (the same numbers: ``estimate`` is a
    deterministic function of the fitted estimator and the trial's columns)."""
    est = (estimator if estimator is not None else
           _make(make_estimator, rig, members, form, reuse, held).fit(trials, meta))
    keep = seen is not None and inputs_of is not None and estimator is not None
    rows = {}
    for t, m in meta.iterrows():
        if m["role"] != "validation":
            continue
        df = trials[t]
        meas = "displacement" if m["reference"] == "displacement" else "force"
        ref, col, ok = ("dx_ref", "dx_hat", "dx") if meas == "displacement" else ("f_ref", "f_hat", "f")
        key = (id(est), t, inputs_of(t)) if keep else None
        if key is not None and key in seen:
            yh = seen[key]
        else:
            yh = _estimate(est, df, t)[col].to_numpy(float)
            if key is not None:
                yh.flags.writeable = False
                seen[key] = yh
        y = df[ref].to_numpy(float)
        if out_corr and t in out_corr and ok in out_corr[t]:
            yh = yh + out_corr[t][ok]
        fin = np.isfinite(y) & np.isfinite(yh)
        rng_ = float(np.ptp(y[fin])) or 1.0
        err = np.abs(yh[fin] - y[fin]) * 100.0 / rng_
        rows[t] = {"measurement": meas, "error": float(np.mean(err)),
                   "blocks": [float(np.mean(b)) for b in np.array_split(err, N_BLOCKS)]}
    return rows


def _estimate(est, df, trial):
    """``est.estimate`` of a trial, with its name where the estimator takes one (the chain's temperature member)."""
    import inspect

    return est.estimate(df, trial=trial) if "trial" in inspect.signature(est.estimate).parameters else est.estimate(df)


def _summary(rows: dict) -> dict:
    out = {}
    for meas in ("displacement", "force"):
        v = [r["error"] for r in rows.values() if r["measurement"] == meas]
        if v:
            out[meas] = float(np.mean(v))
    out["mean"] = float(np.mean(list(out.values()))) if out else float("nan")
    return out


def counterfactual(trials: dict, meta: pd.DataFrame, rig, verdict: dict, make_estimator: Callable,
                   n_boot: int = 200, seed: int = 0, max_effects: int = 5, fitted=None,
                   refit_outputs: bool = True, workers: int = 1, also_members: Sequence[dict] = ()) -> dict:
    """Tip error before / after each confirmed effect's fixed correction and all together, Shapley values and
    bootstrap intervals. ``make_estimator(rig)`` returns an unfitted estimator with ``fit`` / ``estimate``.

    "How far it shrinks once the effect is modelled" is always measured from the chain *without* the effect's model:

    - a confirmed chain member the fitted estimator does not carry is forced on: shrink = Table 3 - Table 3 of the
      chain recalibrated with it;
    - a confirmed chain member the fitted estimator already carries (adopted for Table 3): shrink = Table 3 of the
      chain recalibrated with it forced off - Table 3, and that table is the effect's ``base``; the estimate a user
      gets and the diagnosis cannot disagree, and the number is the member's own contribution, not 0;
    - any other effect: Table 3 - Table 3 after its stage-fitted correction.

    All together and the Shapley values are the game on the chain with every carried confirmed member off (``base``
    of the result; Table 3 itself where none is carried): v(S) = base - Table 3 with the members of S on and the
    corrections of S applied.

    ``workers``: recalibrations run this many at a time (:func:`selfsense.parallel.fork_map`; each is the same
    deterministic fit, so the result has the same bits for any count). ``also_members``: forced-member sets of the
    uncorrected chain to recalibrate in the same pool for a later :func:`chain_contributions` (their tables join
    ``_tables``)."""
    from itertools import combinations

    from .stats import shapley_exact

    can_force = hasattr(fitted if fitted is not None else make_estimator(rig), "members")
    corr = corrections(verdict, chain=can_force)
    names = [e["effect"] for e in verdict["effects"]][:max_effects]
    tabs: dict = {}
    ests: dict = {}   # estimators refitted for (input corrections, forced members), with refit_outputs=False
    carried = adopted_members(fitted)
    form = _form_of(fitted)

    def is_carried(n) -> bool:
        return can_force and n in CHAIN_MEMBERS and bool(carried.get(CHAIN_MEMBERS[n]))

    def members_of(S, bare: bool) -> dict:
        """Chain members switched on by S (those the fitted estimator does not carry yet); with ``bare``, the carried
        confirmed members outside S switched off."""
        if not can_force:
            return {}
        d = {CHAIN_MEMBERS[n]: "on" for n in S if n in CHAIN_MEMBERS and not is_carried(n)}
        if bare:
            d.update({CHAIN_MEMBERS[n]: "off" for n in names if is_carried(n) and n not in S})
        return d

    def touches_inputs(n) -> bool:  # a correction of Q or V changes the calibration: the estimator is refitted
        return any(k in ("q", "V") for per in corr[n].values() for k in per)

    def inputs_touched(S, mem) -> bool:
        return bool(mem) or any(touches_inputs(n) for n in S)

    def refit_key(S: frozenset, mem: dict):
        """The recalibration that scores S with ``mem`` forced: None for the fitted estimator itself, else (the
        corrections it is fitted on, the forced members)."""
        plain = not mem and not any(per for n in S for per in corr[n].values())
        if fitted is not None and (plain or (not refit_outputs and not inputs_touched(S, mem))):
            # output-only corrections (charge-free motion, load stage) leave the estimator's inputs unchanged; with
            # refit_outputs=False the fitted estimator is kept for them (the pipeline: a refit of the configured
            # estimator costs seconds), which ignores the small change of its coefficients
            return None
        if fitted is not None and not refit_outputs:
            # the same rule for a refit: output-only corrections keep the estimator refitted for the input
            # corrections and members of S, so subsets that differ by output corrections share one refit
            return frozenset(n for n in S if touches_inputs(n)), tuple(sorted(mem.items()))
        return S, tuple(sorted(mem.items()))

    searches: dict = {}   # the leakage search of a recalibration, by the input corrections it was fitted on

    h_fits: dict = {}   # estimators with H(q) calibrated, before the sensing regression, by h_key
    h_users: dict = {}  # h_key -> the planned recalibrations (keys) that have not yet read it

    def h_key(k):
        """The part of a recalibration's key that its H(q) calibration reads: the input corrections and the forced
        members that enter the H(q) rows (not :data:`OUTSIDE_H_MEMBERS`)."""
        return k[0], tuple(m for m in k[1] if m[0] not in OUTSIDE_H_MEMBERS)

    def plan(items) -> None:
        """Note the recalibrations that ``items`` ((S, bare, mem) as :func:`planned` yields) will need, so that an
        H(q) calibration is kept for a later one only where one is planned."""
        for S, bare, mem in items:
            k = refit_key(S, members_of(S, bare) if mem is None else mem)
            if k is not None and k not in ests:
                h_users.setdefault(h_key(k), set()).add(k)

    def refit(k):
        S_fit, mem_items = k
        tr_fit, _ = _apply(trials, [corr[n] for n in sorted(S_fit)], meta)
        # the leakage search reads the calibration inputs alone (not the forced members): a recalibration on the
        # same corrected inputs as an earlier one takes that one's search over (the estimator checks the inputs'
        # digest and searches again where it differs), else the fitted estimator's (valid without input corrections)
        est = _make(make_estimator, rig, dict(mem_items), form, searches.get(S_fit) or _search_of(fitted),
                    _held_members(fitted))
        hk = h_key(k)
        later = h_users.get(hk, set()) - {k}
        h_users[hk] = later
        if not _splits_fit(est):
            est = est.fit(tr_fit, meta)
        elif hk in h_fits:
            # the same H(q) calibration as an earlier recalibration's (they differ by members outside the H rows,
            # which its calibration does not read): its state taken over (rig and configuration shared, as a fit
            # shares them), the sensing regression run with these members -- the estimator that est.fit gives,
            # without calibrating H(q) a second time
            done = h_fits[hk] if not later else h_fits[hk].fitted_copy()
            if not later:
                del h_fits[hk]
            done.members, done.leakage_search_reuse = est.members, est.leakage_search_reuse
            est = done.fit_coefficients(tr_fit, meta)
        else:
            est = est.fit_hysteresis(tr_fit, meta)
            if later:   # kept only where a planned recalibration will read it (memory: one estimator's trials)
                h_fits[hk] = est.fitted_copy()
            est = est.fit_coefficients(tr_fit, meta)
        got = _search_of(est)
        if got and got.get("g_folds") is not None and S_fit not in searches:
            searches[S_fit] = got
        return est

    def inputs_in(S: frozenset) -> Callable:
        """trial -> the effects of S whose corrections change that trial's estimator inputs (Q, V), in the order
        :func:`_apply` applies them: the key of an estimate made on ``_apply(trials, S)`` (:func:`tip_table`)."""
        return lambda t: tuple(n for n in sorted(S) if any(k in ("q", "V") for k in corr[n].get(t, {})))

    seen: dict = {}   # estimates of the validation trials by (estimator, trial, input corrections), see tip_table

    def table(S: frozenset, bare: bool = True, mem: dict | None = None):
        mem = members_of(S, bare) if mem is None else mem
        key = (S, tuple(sorted(mem.items())))
        if key not in tabs:
            # a carried member's own correction is the member itself (``corrections(chain=True)`` gives none)
            tr, oc = _apply(trials, [corr[n] for n in sorted(S)], meta)
            k = refit_key(S, mem)
            if k is None:
                est = fitted
            else:
                if k not in ests:
                    ests[k] = refit(k)
                est = ests[k]
            tabs[key] = tip_table(tr, meta, rig, make_estimator, oc, estimator=est, members=mem, form=form,
                                  seen=seen, inputs_of=inputs_in(S))
        return tabs[key]

    def shapley_subsets(players):
        """The subsets of the effects in the joint game (``players``) scored on the chain with the carried members
        off: every one for the exact Shapley values (at most 3 effects), else only all of them together ("after
        all"; with more effects no Shapley value is computed, so the single effects' tables on that chain would be
        read by nothing)."""
        if len(players) <= 3:
            for k in range(1, len(players) + 1):
                yield from combinations(players, k)
        elif players:
            yield tuple(players)

    def planned(players=None):
        """Every (S, bare, mem) this function scores below, in order: with ``workers > 1`` their recalibrations and
        tables are computed in a pool first -- the single effects (``players`` None), then the joint game of
        ``players``. Only a prefetch: a table missing here is computed where it is asked for, so a change of the
        scoring below that is not mirrored here costs time, never a different number."""
        if players is not None:
            for S in shapley_subsets(players):
                yield frozenset(S), True, None
            return
        yield frozenset(), False, None
        for mem in also_members:
            yield frozenset(), True, dict(mem)
        if not names:
            return
        yield frozenset(), True, None
        for n in names:
            yield (frozenset(), True, {CHAIN_MEMBERS[n]: "off"}) if is_carried(n) else (frozenset([n]), False, None)

    def prefetch(players=None):
        if workers <= 1:
            return
        # the recalibrations are independent: each, with the tables scored on it, in a process of its own (the fits
        # hold the GIL most of the time, so threads would take turns); the tables come back, not the estimators
        groups: dict = {}   # unit -> recalibration key -> the tables scored on it: one H(q) calibration per unit
        for S, bare, mem in planned(players):
            mem = members_of(S, bare) if mem is None else mem
            k = refit_key(S, mem)
            if k is not None and (S, tuple(sorted(mem.items()))) not in tabs:
                own = any(m in RESELECTING_MEMBERS and v == "on" for m, v in k[1])
                per = groups.setdefault((h_key(k), k) if own else (h_key(k),), {}).setdefault(k, [])
                if (S, mem) not in per:
                    per.append((S, mem))
        if sum(len(g) for g in groups.values()) > 1:
            def unit(g):
                out = {}
                h_users[g[0]] = set(groups[g])   # an H(q) calibration kept only for this unit's own keys
                for k, wanted in groups[g].items():
                    est, mine = refit(k), {}
                    for S, mem in wanted:
                        tr, oc = _apply(trials, [corr[n] for n in sorted(S)], meta)
                        out[(S, tuple(sorted(mem.items())))] = tip_table(tr, meta, rig, make_estimator, oc,
                                                                         estimator=est, members=mem, form=form,
                                                                         seen=mine, inputs_of=inputs_in(S))
                return out

            units = sorted(groups, key=len, reverse=True)   # the longest first; read back in the planned order
            got = dict(zip(units, fork_map(unit, units, workers)))
            for g, per in groups.items():   # read in the workers: no H(q) calibration is kept here for them
                tabs.update(got[g])
                h_users[g[0]] = h_users.get(g[0], set()) - set(per)

    plan(planned())
    prefetch()
    fitted_tab = table(frozenset(), bare=False)
    res = {"before": _summary(fitted_tab), "per_trial_before": {t: r["error"] for t, r in fitted_tab.items()},
           "effects": {}}
    for mem in also_members:
        table(frozenset(), mem=dict(mem))
    if not names:
        res["after_all"] = res["before"]
        res["_tables"] = {mem: t for (S, mem), t in tabs.items() if not S}
        return res
    base = table(frozenset())
    res["base"] = _summary(base)
    res["base_members_off"] = sorted({CHAIN_MEMBERS[n] for n in names if is_carried(n)})
    rng = np.random.default_rng(seed)
    trials_v = list(fitted_tab)

    def blocks_interval(hi: dict, lo: dict) -> list:
        d = np.concatenate([np.asarray(hi[t]["blocks"]) - np.asarray(lo[t]["blocks"]) for t in trials_v])
        bs = [float(np.mean(d[rng.integers(0, len(d), len(d))])) for _ in range(n_boot)]
        return [float(np.quantile(bs, 0.05)), float(np.quantile(bs, 0.95))]

    def with_interval(entry: dict, hi: dict, lo: dict, key: str = "shrink") -> dict:
        """``entry`` with the block-bootstrap interval of its change (``<key>_interval_90_blocks``) and the 90 %
        interval (``<key>_interval_90``): the bootstrap's, its upper side widened for what the recalibrated chain
        leaves of the effect (:func:`widened_interval`)."""
        raw = blocks_interval(hi, lo)
        entry[f"{key}_interval_90_blocks"] = raw
        entry[f"{key}_interval_90"] = widened_interval(entry[key], raw)
        return entry

    for n in names:
        if is_carried(n):  # the member's own contribution: the chain without it against the fitted chain
            without = table(frozenset(), mem={CHAIN_MEMBERS[n]: "off"})
            res["effects"][n] = with_interval(
                {"after": res["before"], "base": _summary(without),
                 "shrink": _summary(without)["mean"] - res["before"]["mean"],
                 "how": "carried by the estimate (adopted for Table 3): Table 3 of the chain recalibrated without "
                        "it, minus Table 3"}, without, fitted_tab)
            continue
        after = table(frozenset([n]), bare=False)
        res["effects"][n] = with_interval({"after": _summary(after), "base": res["before"],
                                           "shrink": res["before"]["mean"] - _summary(after)["mean"]},
                                          fitted_tab, after)
        if n in CHAIN_MEMBERS and can_force:
            res["effects"][n]["how"] = "the estimator recalibrated with the chain member forced on"
    # the joint game: the named effects whose model, added alone, does not make Table 3 worse. A model that raises
    # the error on its own (a member forced on where the effect is not what the calibration data hold, a stage
    # correction that the estimator's own H(q) already carries in part) is reported with its own number above and
    # left out of "all together", which it would otherwise drag below 0 (benchmarks/gap_tip/joint_20261203)
    joint = [n for n in names if res["effects"][n]["shrink"] >= 0.0]
    res["joint_effects"] = joint
    res["joint_left_out"] = {n: f"its model alone makes Table 3 worse ({res['effects'][n]['shrink']:+.2f} points)"
                             for n in names if n not in joint}
    plan(planned(joint))
    prefetch(joint)
    for S in shapley_subsets(joint):
        table(frozenset(S))
    allS = frozenset(joint)
    all_tab = table(allS) if joint else base
    res["after_all"] = _summary(all_tab)
    res["shrink_all"] = res["base"]["mean"] - res["after_all"]["mean"]
    with_interval(res, base, all_tab, key="shrink_all")
    if len(joint) <= 3:
        res["shapley"] = shapley_exact(joint, lambda S: res["base"]["mean"] - _summary(table(frozenset(S)))["mean"])
    # the uncorrected chain's tables by forced members, for :func:`chain_contributions` (not JSON: pop it)
    res["_tables"] = {mem: t for (S, mem), t in tabs.items() if not S}
    return res


def contribution_sets(fitted) -> list[dict]:
    """The forced-member sets :func:`chain_contributions` scores: each carried member off, and all of them off when
    more than one is carried."""
    on = [m for m, a in adopted_members(fitted).items() if a]
    return [{m: "off"} for m in on] + ([{m: "off" for m in on}] if len(on) > 1 else [])


def chain_contributions(trials: dict, meta: pd.DataFrame, rig, make_estimator: Callable, fitted,
                        tables: dict | None = None) -> dict:
    """Before / after each charge-link member the fitted estimator carries: Table 3 of the chain refitted with that
    member forced off against Table 3 (the fitted chain), and with all carried members off. Members not carried are
    listed with the reason the calibration gave (``fit_report_``). ``tables``: tip tables already computed for the
    same trials and fitted form, by forced members (``counterfactual(...)["_tables"]``), reused instead of refitted."""
    carried = adopted_members(fitted)
    tables = tables or {}

    def without(mem: dict) -> dict:
        key = tuple(sorted(mem.items()))
        if key not in tables:
            tables[key] = tip_table(trials, meta, rig, make_estimator, members=mem, form=form,
                                    reuse=_search_of(fitted), held=_held_members(fitted))
        return _summary(tables[key])

    if not carried:
        return {}
    form = _form_of(fitted)
    base = _summary(tip_table(trials, meta, rig, make_estimator, estimator=fitted))
    drift = fitted.fit_report_.get("hysteresis", {}).get("drift", {})
    out = {"table3": base, "members": {}}
    on = [m for m, a in carried.items() if a]
    for m, a in carried.items():
        row = {"adopted": a, "source": ("holds of every trial" if m == "hold_rows" else
                                        "V-Q rows and current plateau of every trial" if m == "amplifier" else
                                        "laser of the free-tip calibration trials" if m == "absorption" else
                                        "undithered shunt channel, free-tip calibration laser" if m == "quantiser" else
                                        "force-reference calibration rows" if m == "stress" else
                                        "command lead, calibration rows" if m == "amplifier_lag" else
                                        drift.get("source" if m == "leakage" else "offset_drift_source", "none"))}
        if a:
            w = without({m: "off"})
            row.update({"without": w, "contribution": w["mean"] - base["mean"]})
        out["members"][m] = row
    if len(on) > 1:
        none = without({m: "off" for m in on})
        out["without_all"] = none
        out["contribution_all"] = none["mean"] - base["mean"]
    out["note"] = drift.get("note", "")
    return out
