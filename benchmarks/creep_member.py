"""Charge-free creep cases of the tip tier: would a creep member of the displacement output carry the effect?

    python benchmarks/creep_member.py --seed 8080 --cases 25,33,99,155,188,271,316 --jobs 2 \\
        --out benchmarks/gap_tip/creep_member_8080.md

The gap diagnostic names ``slow.creep`` (charge-free creep strain: after a step the tip keeps moving while the charge
does not; docs/gap.md) but the estimator carries no member for it, so "how far" is a stage correction with fixed
coefficients. This script measures, before any such member is built, what the member the diagnostic's own column
suggests would give. Per case (a single-effect ``slow.creep`` case of ``selfsense gap blind --tip``), the displacement
half of Table 3 (validation trials, mean |error| in % of the reference range):

- **case**: the project's default estimator (``SensingConfig()``) on the dataset as simulated;
- **member**: its displacement output replaced by the two-port with a creep bank on each of its signals,
  ``dx = A1 Q + A2 V_p + sum_tau (a_tau (LP_tau[Q] - Q) + b_tau (LP_tau[V_p] - V_p))`` (thesis eq. 52 and the
  diagnostic's creep column ``LP_tau Q - Q``; the creep strain follows the elastic strain, a combination of Q and V_p
  that the blocked trial's rows fix), ``tau`` in ``BANK_S``, every coefficient fitted at once on the estimator's
  displacement calibration rows (free-tip laser rows and the blocked trial's ``dx = 0`` rows); the calibration's
  blocked-CV error (5 contiguous blocks per trial) with the bank over without it;
- **twin**: the effect-free twin (same device, drive and noise, the effect removed), the tip tier's truth;
- each of them again with the estimator's offset-drift member forced off (``members={"offset_drift": "off"}``);
- where the member's error comes from: the same bank fitted on the simulator's own actuator charge and piezo voltage
  (the simulator's truth), and with the default estimator's charge in place of the true one, scored against the
  simulated tip.

``--member`` scores the member as it was then built into the estimator (``selfsense.chain.creep``, config
``tip_creep``) instead, on the case and its twin, force as well as displacement::

    python benchmarks/creep_member.py --member --seed 20261210 --cases 3,16,35,64,81,85,93,96 --jobs 2 \\
        --out benchmarks/gap_tip/creep_member_built_first_20261210.md
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _args import int_ranges

#: the member's creep bank [s]: log-spaced over the trial lengths (not the simulator's own time constants)
BANK_S = (0.3, 1.0, 3.0, 10.0, 30.0)


def _simulate(c: dict, effects: dict):
    """``selfsense.gap.blindsim.simulate_family_case`` of the case with ``effects``."""
    from selfsense.gap.blind import FS_CASE, T_CASE
    from selfsense.gap.blindsim import simulate_family_case

    return simulate_family_case(c["family"], c["device_seed"], effects, c["noise_seed"], T_CASE, FS_CASE,
                                with_truth=True)


def _bank(q, vp, dt: float, bank=BANK_S):
    """``[Q, V_p, LP_tau[Q] - Q, LP_tau[V_p] - V_p for tau in bank]``: the two-port (thesis eq. 52) with a creep bank
    on each of its signals (the charge-free creep strain follows the elastic strain, a combination of both)."""
    from selfsense.gap.stages import lp

    return np.column_stack([q, vp] + [lp(v, tau, dt) - v for tau in bank for v in (q, vp)])


def _fit_bank(trials, me, signals):
    """The bank's coefficients on the displacement calibration rows (free-tip laser rows, the blocked trial's dx = 0
    rows) and the blocked-CV error (5 contiguous blocks per trial) with and without the bank. ``signals(t)``:
    ``(Q, V_p)`` of trial ``t``."""
    from selfsense.hysteresis.models.select import blocked_folds

    X, y, lens = [], [], []
    for t, row in me[me["role"] == "calibration"].iterrows():
        if row["reference"] != "displacement" and row["tip"] != "blocked":
            continue
        df = trials[t]
        yt = df["dx_ref"].to_numpy(float) if row["reference"] == "displacement" else np.zeros(len(df))
        m = (df["relay"].to_numpy() < 0.5) & np.isfinite(yt)
        X.append(_bank(*signals(t), float(np.median(np.diff(df["t"].to_numpy(float)))))[m])
        y.append(yt[m])
        lens.append(int(m.sum()))
    X, y = np.vstack(X), np.concatenate(y)

    def cv(cols):
        err = [X[h][:, cols] @ np.linalg.lstsq(X[~h][:, cols], y[~h], rcond=None)[0] - y[h]
               for h in blocked_folds(lens, 5, rotate=False)]
        return float(np.sqrt(np.mean(np.concatenate(err) ** 2)))

    return np.linalg.lstsq(X, y, rcond=None)[0], cv(slice(None)) / cv(slice(0, 2))


def _one(args) -> dict:
    from selfsense.gap.blind import draw_tip_case
    from selfsense.gap.counterfactual import _summary, tip_table
    from selfsense.sensing.estimator import (
        SelfSensingEstimator,
        SensingConfig,
        limit_to_range,
    )

    i, seed = args
    c = draw_tip_case(i, seed)
    (name,), (mag,) = c["effects"], c["effects"].values()
    if name != "slow.creep":
        raise ValueError(f"case {i} of seed {seed} is a {name} case, not slow.creep")
    tr, me, rig, truth = _simulate(c, c["effects"])
    tr0, me0, rig0, _ = _simulate(c, {})

    def fitted(trials, meta, r, drift_off: bool):
        est = SelfSensingEstimator(config=SensingConfig(), rig=r)
        if drift_off:
            est.members = {"offset_drift": "off"}
        return est.fit(trials, meta)

    def disp(trials, meta, r, est, post=None) -> float:
        rows = tip_table(trials, meta, r, None, estimator=est)
        for t, row in rows.items():
            if row["measurement"] == "displacement" and post is not None:
                y, yh = trials[t]["dx_ref"].to_numpy(float), post(t)
                ok = np.isfinite(y) & np.isfinite(yh)
                row["error"] = float(np.mean(np.abs(yh[ok] - y[ok])) * 100.0 / np.ptp(y[ok]))
        return float(_summary(rows)["displacement"])

    out, member = {}, {}
    for drift_off in (False, True):
        key = "drift_off" if drift_off else "default"
        est = fitted(tr, me, rig, drift_off)
        out[f"case_{key}"] = disp(tr, me, rig, est)
        out[f"twin_{key}"] = disp(tr0, me0, rig0, fitted(tr0, me0, rig0, drift_off))
        X = {t: est._regressors(est._with_links(df)) for t, df in tr.items()}
        w, ratio = _fit_bank(tr, me, lambda t, X=X: (X[t][:, 0], X[t][:, 1]))

        def post(t, w=w, est=est, X=X):
            dx = _bank(X[t][:, 0], X[t][:, 1], float(np.median(np.diff(tr[t]["t"].to_numpy(float))))) @ w
            return limit_to_range(np.where(tr[t]["relay"].to_numpy() >= 0.5, 0.0, dx), *est.ranges_["dx"])

        out[f"member_{key}"] = disp(tr, me, rig, est, post)
        member[f"cv_ratio_{key}"] = ratio
        member[f"offset_drift_adopted_{key}"] = bool(est.offset_drift_)
        if not drift_off:
            X_default = X

    # the same bank on the simulator's own actuator charge and piezo voltage, and with the default estimator's charge
    # in place of the true one: where the member's error comes from
    def truth_error(charge: str) -> float:
        def sig(t):
            q = truth[t]["q_act"].to_numpy(float) if charge == "true" else X_default[t][:, 0]
            return q, truth[t]["V_p"].to_numpy(float)

        w, _ = _fit_bank(tr, me, sig)
        errs = []
        for t, row in me[(me["role"] == "validation") & (me["reference"] == "displacement")].iterrows():
            y = truth[t]["dx_tip"].to_numpy(float)
            yh = np.where(tr[t]["relay"].to_numpy() >= 0.5, 0.0,
                          _bank(*sig(t), float(np.median(np.diff(tr[t]["t"].to_numpy(float))))) @ w)
            errs.append(float(np.mean(np.abs(yh - y)) * 100.0 / np.ptp(y)))
        return float(np.mean(errs))

    out["true_signals_bank"] = truth_error("true")
    out["estimated_charge_bank"] = truth_error("estimated")
    return {"case": i, "seed": seed, "family": c["family"], "magnitude": float(mag), "creep_m": float(mag) * 0.02,
            "table3_disp": out, "member": member}


def _one_member(args) -> dict:
    """``--member``: the estimator's creep member (``selfsense.chain.creep``, ``tip_creep``) as built, on the case
    and its effect-free twin: the default estimator with the member forced off against the default (``auto``)."""
    from selfsense.gap.blind import draw_tip_case
    from selfsense.gap.counterfactual import _summary, tip_table
    from selfsense.sensing.estimator import SelfSensingEstimator, SensingConfig

    i, seed = args
    c = draw_tip_case(i, seed)
    (name,), (mag,) = c["effects"], c["effects"].values()
    if name != "slow.creep":
        raise ValueError(f"case {i} of seed {seed} is a {name} case, not slow.creep")
    out = {"case": i, "seed": seed, "family": c["family"], "magnitude": float(mag), "creep_m": float(mag) * 0.02}
    for lab, eff in (("case", c["effects"]), ("twin", {})):
        tr, me, rig, _ = _simulate(c, eff)
        for mode in ("off", "auto"):
            est = SelfSensingEstimator(config=SensingConfig(), rig=rig, members={"tip_creep": mode}).fit(tr, me)
            s = _summary(tip_table(tr, me, rig, None, estimator=est))
            tc = est.tip_creep_
            out[f"{lab}_{mode}"] = {
                "displacement": float(s["displacement"]), "force": float(s["force"]),
                "tip_creep": bool(tc.get("applied")), "offset_drift": bool(est.offset_drift_),
                "cv_ratio": (float(tc["cv_rms_m_with"] / tc["cv_rms_m_without"]) if "cv_rms_m_with" in tc else None),
                "offset_drift_dropped": bool(tc.get("offset_drift_check") and
                                             not tc["offset_drift_check"]["offset_drift_kept"])}
    return out


def _member_table(recs: list, cmd: str) -> list:
    lines = ["# Charge-free creep: the estimator's creep member (tip_creep) on creep cases and their twins", "",
             f"Command: `{cmd}` ({datetime.now(UTC):%Y-%m-%d})", "",
             ("Table 3 of the validation trials (object contacts), displacement / force, % of range. \"off\": the "
              "default estimator with the member forced off; \"auto\": the default (the member where the "
              "calibration's blocked CV supports it; the offset-drift member re-decided beside it). Twin: the same "
              "device, drive and noise without the creep."), "",
             "| case | family | creep m | case, off | case, auto | member adopted (CV ratio) | offset drift dropped "
             "| twin, off | twin, auto | member adopted on the twin (CV ratio) |",
             "|---|---|---|---|---|---|---|---|---|---|"]

    def cell(x):
        return f"{x['displacement']:.2f} / {x['force']:.2f}"

    def ratio(x):
        return f"{x['tip_creep']} ({x['cv_ratio']:.2f})" if x["cv_ratio"] is not None else str(x["tip_creep"])

    for r in recs:
        lines.append(f"| {r['case']} | {r['family']} | {r['creep_m']:.3f} | {cell(r['case_off'])} | "
                     f"{cell(r['case_auto'])} | {ratio(r['case_auto'])} | {r['case_auto']['offset_drift_dropped']} | "
                     f"{cell(r['twin_off'])} | {cell(r['twin_auto'])} | {ratio(r['twin_auto'])} |")
    med = {k: (statistics.median(r[k]["displacement"] for r in recs), statistics.median(r[k]["force"] for r in recs))
           for k in ("case_off", "case_auto", "twin_off", "twin_auto")}
    lines += ["", "Medians (displacement / force): " + "; ".join(f"{k.replace('_', ', ')} {v[0]:.2f} / {v[1]:.2f} %"
                                                                   for k, v in med.items()) + "."]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--cases", type=int_ranges, required=True)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--member", action="store_true",
                    help="score the estimator's creep member as built (tip_creep off against auto) on case and twin")
    a = ap.parse_args(argv)
    from selfsense.determinism import single_thread_blas

    single_thread_blas()   # one BLAS thread per process and its workers, as the selfsense command runs
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as ex:
        recs = list(ex.map(_one_member if a.member else _one, [(i, a.seed) for i in a.cases]))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.with_suffix(".jsonl").write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in recs))
    cmd = "python benchmarks/creep_member.py " + " ".join(sys.argv[1:] if argv is None else argv)
    if a.member:
        lines = _member_table(recs, cmd)
        a.out.write_text("\n".join(lines) + "\n")
        print("\n".join(lines))
        return 0
    cols = [("case_default", "case"), ("member_default", "member"), ("twin_default", "twin"),
            ("case_drift_off", "case, drift off"), ("member_drift_off", "member, drift off"),
            ("twin_drift_off", "twin, drift off"), ("true_signals_bank", "bank on true Q, V_p"),
            ("estimated_charge_bank", "bank on estimated Q, true V_p")]
    lines = ["# Charge-free creep: a creep member of the displacement output, measured before it is built", "",
             f"Command: `{cmd}` ({datetime.now(UTC):%Y-%m-%d})", "",
             ("Displacement half of Table 3 of the validation trials (contact with an object), % of range. \"drift "
              "off\": the offset-drift member forced off (case and twin). \"member\": the creep bank fitted on the "
              "calibration rows with that estimator's Q and V_p. CV ratio: the calibration rows' blocked-CV error "
              "with the bank over without it."), "",
             ("| case | family | creep m | " + " | ".join(h for _, h in cols)
              + " | CV ratio | offset drift adopted (case) |"),
             "|---|---|---|" + "---|" * len(cols) + "---|---|"]
    for r in recs:
        t = r["table3_disp"]
        lines.append(f"| {r['case']} | {r['family']} | {r['creep_m']:.3f} | "
                     + " | ".join(f"{t[k]:.2f}" for k, _ in cols)
                     + f" | {r['member']['cv_ratio_default']:.2f} | {r['member']['offset_drift_adopted_default']} |")
    med = {h: statistics.median(r["table3_disp"][k] for r in recs) for k, h in cols}
    lines += ["", "Medians: " + "; ".join(f"{k} {v:.2f} %" for k, v in med.items()) + "."]
    a.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
