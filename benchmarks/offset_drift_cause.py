#!/usr/bin/env python
"""Why "how far it shrinks" falls short for the shunt offset drift at the tip tier: the member's drift estimate
against the simulator's, trial by trial, and what the chain fitted beside it costs.

    python benchmarks/offset_drift_cause.py --seed 20261232 --cases 0,17,24,25,26,30,52,70,93,103,110,111,123 \\
        --jobs 2 --out benchmarks/gap_tip/seed_20261232/offset_drift_cause.md

For each case of the tip campaign (:func:`selfsense.gap.blind.draw_tip_case`; the cases given should be those whose
effect is ``slow.offset_drift``) the case and its effect-free twin (same device, drive and noise) are simulated as
``run_tip_case`` simulates them and the project's default estimator (``SensingConfig()``) is fitted on each. Per case:

* the charge drift the member finds at the end of every trial (:meth:`SelfSensingEstimator.rest_drift` on the trial
  as the estimate reads it: the temperature member's scale and the links applied, the leakage-corrected charge),
  whether or not the fitted chain adopted the member, against the true one (the case's measured charge minus the
  twin's; the two differ by the drift alone), and their ratio (median over the trials);
* Table 3 of the case as fitted and with the member switched off at estimate time, of the twin, and of the case's
  fitted chain fed the twin's charge, as fitted (the member on where adopted) and with the member off (does the chain
  fitted beside the drift still fit the device?), and the member's form (the ramp or a wandering offset) per trial.

Measures only; changes nothing in the project.
"""
from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _args import int_ranges  # noqa: E402


def _case(args) -> dict:
    from selfsense.gap.blind import FS_CASE, T_CASE, draw_tip_case
    from selfsense.gap.blindsim import simulate_family_case
    from selfsense.gap.counterfactual import _summary, tip_table
    from selfsense.sensing.estimator import SelfSensingEstimator, SensingConfig, _with_column

    i, seed = args
    c = draw_tip_case(i, seed)
    fam, ds, ns, eff = c["family"], c["device_seed"], c["noise_seed"], c["effects"]
    tr, me, rig = simulate_family_case(fam, ds, eff, ns, T_CASE, FS_CASE)
    tr0, me0, rig0 = simulate_family_case(fam, ds, {}, ns, T_CASE, FS_CASE)
    mk = lambda r: SelfSensingEstimator(config=SensingConfig(), rig=r)  # noqa: E731
    est, est0 = mk(rig).fit(tr, me), mk(rig0).fit(tr0, me0)
    score = lambda trials, e: _summary(tip_table(trials, me, rig, mk, estimator=e))["mean"]  # noqa: E731
    rows = []
    for t, df in tr.items():
        rel = df["relay"].to_numpy() < 0.5
        true = df["q"].to_numpy() - tr0[t]["q"].to_numpy()
        # the trial as the estimate reads it (estimate(): the temperature member's charge scale, then the links)
        s_t = est.temperature_scale(t)
        d = est._with_links(df if s_t == 1.0 else _with_column(df, "q", df["q"].to_numpy(dtype=float) / s_t))
        dq, info = est.rest_drift(d, est._charge(d, drift=False))
        rows.append({"trial": t, "role": str(me.loc[t, "role"]), "form": info.get("form", "-"),
                     "true_end_c": float(true[rel][-1] - true[rel][0]), "member_end_c": float(dq[rel][-1])})
    twin_q = {t: df.assign(q=tr0[t]["q"].to_numpy()) for t, df in tr.items()}
    out = {"case": i, "family": fam, "magnitude": float(eff.get("slow.offset_drift", float("nan"))),
           "adopted": bool(est.offset_drift_), "h": est.hysteresis_.label(), "h_twin": est0.hysteresis_.label(),
           "table3": score(tr, est), "twin": _summary(tip_table(tr0, me0, rig0, mk, estimator=est0))["mean"],
           "twin_charge_as_fitted": score(twin_q, est), "trials": rows}
    adopted = est.offset_drift_
    est.offset_drift_ = False   # the member off at estimate time (the fitted H and coefficients kept)
    out["twin_charge_member_off"] = score(twin_q, est)
    out["case_member_off"] = score(tr, est)
    est.offset_drift_ = adopted
    ratios = [r["member_end_c"] / r["true_end_c"] for r in rows if r["true_end_c"]]
    out["ratio_median"] = float(statistics.median(ratios)) if ratios else float("nan")
    out["ratio_spread"] = float(np.ptp(ratios)) if ratios else float("nan")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--cases", type=int_ranges, required=True, help="case indices, e.g. 0,17,24-26")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    from selfsense.determinism import single_thread_blas

    single_thread_blas()
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as ex:
        recs = list(ex.map(_case, [(i, a.seed) for i in a.cases]))
    cmd = " ".join(argv if argv is not None else sys.argv[1:])
    lines = [f"# Offset drift at the tip tier: the member's drift against the simulator's (seed {a.seed})", "",
             f"Command: `python benchmarks/offset_drift_cause.py {cmd}` "
             f"({datetime.now(timezone.utc).strftime('%Y-%m-%d')})", "",
             "Table 3 = mean of the displacement and force means [% of range]. *Member / true drift*: the member's "
             "charge drift at the end of each trial over the true one (the case's charge minus its twin's), median "
             "over the eight trials (spread = max - min). *Twin charge*: the case's fitted chain fed the twin's "
             "charge (the drift removed exactly), as fitted (the member on where adopted) and with the member off at "
             "estimate time; where the member is not adopted, both are the chain as fitted.", "",
             "| case | family | adopted | member / true drift (spread) | forms | Table 3: case | twin | case, member "
             "off | twin charge, as fitted | twin charge, member off | H(q) case / twin |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in recs:
        forms = ",".join(sorted({x["form"] for x in r["trials"]}))
        lines.append(f"| {r['case']} | {r['family']} | {r['adopted']} | {r['ratio_median']:.2f} "
                     f"({r['ratio_spread']:.2f}) | {forms} | {r['table3']:.2f} | {r['twin']:.2f} | "
                     f"{r['case_member_off']:.2f} | {r['twin_charge_as_fitted']:.2f} | "
                     f"{r['twin_charge_member_off']:.2f} | {r['h']} / {r['h_twin']} |")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
