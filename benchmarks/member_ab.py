#!/usr/bin/env python
"""A chain member's first contact on tip cases of a seed not used in its development: Table 3 with the default
estimator (the member decided by the data, ``auto``, its configuration key set to ``auto`` where it has one) against the same estimator with the member forced off, and the
case's effect-free twin (same device, drive and noise, the effect removed).

    python benchmarks/member_ab.py --member amplifier --effect rate.amplifier --seed 20261126 --n 8 --jobs 2 \\
        --out benchmarks/gap_tip/amplifier_blind.md

The cases are the first ``--n`` of the tip campaign's draw (``selfsense.gap.blind.draw_tip_case``) at ``--seed``
whose effect is ``--effect``. Writes the table (Markdown) and the records (``.jsonl.gz`` beside it).
"""
from __future__ import annotations

import argparse
import gzip
import json
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from datetime import datetime, timezone
from pathlib import Path


def calibration_error(est, trials, meta) -> float:
    """The calibration trials' own error (their references), what a guard could see: mean over the calibration trials
    of mean |estimate - reference| after the relay release, in % of the trial's reference range."""
    import numpy as np

    cal = []
    for t, m in meta.iterrows():
        if m["role"] != "calibration":
            continue
        ref, col = ("dx_ref", "dx_hat") if m["reference"] == "displacement" else ("f_ref", "f_hat")
        y = trials[t][ref].to_numpy(float)
        yh = est.estimate(trials[t], trial=t)[col].to_numpy(float)
        ok = np.isfinite(y) & (trials[t]["relay"].to_numpy() < 0.5)
        cal.append(float(np.mean(np.abs(yh[ok] - y[ok])) * 100 / np.ptp(y[ok])))
    return float(np.mean(cal))


def _config(member: str):
    """The default configuration with the member's own key at "auto" (a member off by default, such as the stress or
    the temperature member, is otherwise never decided by the data)."""
    import dataclasses

    from selfsense.sensing.estimator import SensingConfig

    keys = {f.name for f in dataclasses.fields(SensingConfig)}
    return SensingConfig(**({member: "auto"} if member in keys else {}))


def _one(args):
    import numpy as np

    from selfsense.gap.blind import FS_CASE, T_CASE, draw_tip_case, simulate_family_case
    from selfsense.gap.counterfactual import _summary, tip_table
    from selfsense.sensing.estimator import SelfSensingEstimator

    i, seed, member = args
    c = draw_tip_case(i, seed)
    fam, ds, ns, eff = c["family"], c["device_seed"], c["noise_seed"], c["effects"]
    tr, me, rig = simulate_family_case(fam, ds, eff, ns, T_CASE, FS_CASE)
    tr0, me0, rig0 = simulate_family_case(fam, ds, {}, ns, T_CASE, FS_CASE)
    out = {"case": int(i), "seed": int(seed), "family": fam, "effect": next(iter(eff)),
           "magnitude": float(next(iter(eff.values())))}
    cfg = _config(member)
    for mode in ("auto", "off"):
        est = SelfSensingEstimator(config=cfg, rig=rig, members={member: mode}).fit(tr, me)
        out[f"table3_{mode}"] = _summary(tip_table(tr, me, rig, None, estimator=est))["mean"]
        if mode == "auto":
            dec = getattr(est, f"{member}_", None)
            out["adopted"] = bool(dec.get("applied")) if isinstance(dec, dict) else None
        out[f"calibration_{mode}"] = calibration_error(est, tr, me)
    # the twin with the member decided by the data too (a member that is off by default would never be adopted on
    # it otherwise); where it is adopted there (a false adoption), the twin's Table 3 is the one with the member off
    est0 = SelfSensingEstimator(config=cfg, rig=rig0, members={member: "auto"}).fit(tr0, me0)
    dec0 = getattr(est0, f"{member}_", None)
    out["adopted_twin"] = bool(dec0.get("applied")) if isinstance(dec0, dict) else None  # a false adoption
    if out["adopted_twin"]:
        out["table3_twin_auto"] = _summary(tip_table(tr0, me0, rig0, None, estimator=est0))["mean"]
        est0 = SelfSensingEstimator(config=cfg, rig=rig0, members={member: "off"}).fit(tr0, me0)
    out["table3_twin"] = _summary(tip_table(tr0, me0, rig0, None, estimator=est0))["mean"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--member", required=True, help="SelfSensingEstimator.members key, e.g. amplifier")
    ap.add_argument("--effect", required=True, help="tip-campaign effect whose cases to take, e.g. rate.amplifier")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    from selfsense.determinism import single_thread_blas

    single_thread_blas()   # one BLAS thread per process and its workers, as the selfsense command runs
    from selfsense.gap.blind import draw_tip_case

    cases, i = [], 0
    while len(cases) < a.n and i < 100_000:
        if next(iter(draw_tip_case(i, a.seed)["effects"])) == a.effect:
            cases.append(i)
        i += 1
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as ex:
        recs = list(ex.map(_one, [(c, a.seed, a.member) for c in cases]))
    rows = [("| case | family | member adopted | Table 3, member auto [points] | member off | effect-free twin | "
             "calibration trials' error, auto / off |"), "|---|---|---|---|---|---|---|"]
    for r in recs:
        rows.append(f"| {r['case']} | {r['family']} | {r['adopted']} | {r['table3_auto']:.2f} | {r['table3_off']:.2f} "
                    f"| {r['table3_twin']:.2f} | {r['calibration_auto']:.2f} / {r['calibration_off']:.2f} |")
    ad = [r for r in recs if r["adopted"]]
    better = sum(r["table3_auto"] < r["table3_off"] for r in ad)
    cmd = "python benchmarks/member_ab.py " + " ".join(sys.argv[1:] if argv is None else argv)
    text = (f"# Member first contact: {a.member} on {a.effect} cases of seed {a.seed}\n\nCommand: `{cmd}` "
            f"({datetime.now(timezone.utc).strftime('%Y-%m-%d')})\n\n" + "\n".join(rows) + "\n\n"
            f"Adopted in {len(ad)} of {len(recs)} cases; where adopted, Table 3 (mean of displacement and force, % of "
            f"range) lower than with the member off in {better} of {len(ad)}, median "
            f"{statistics.median(r['table3_off'] for r in ad) if ad else float('nan'):.2f} -> "
            f"{statistics.median(r['table3_auto'] for r in ad) if ad else float('nan'):.2f} (effect-free twins: median "
            f"{statistics.median(r['table3_twin'] for r in ad) if ad else float('nan'):.2f})."
            + (f" Adopted on the effect-free twins (a false adoption): {sum(bool(r['adopted_twin']) for r in recs)} of "
               f"{len(recs)}." if all("adopted_twin" in r for r in recs) else "") + "\n")
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    with open(out.with_suffix(".jsonl.gz"), "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0) as fh:
        for r in recs:
            fh.write((json.dumps(r, sort_keys=True) + "\n").encode())
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
