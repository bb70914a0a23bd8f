"""Would a calibration-side check of the amplifier member have caught the cases where it makes Table 3 worse?

    python benchmarks/amplifier_member_check.py --cases 20261213/8,20261213/36,20261213/37,20261213/55,20261213/62,\\
        20261213/74,4711/60 --out benchmarks/gap_tip/amplifier_member_check.md

Per tip case of the gap diagnostic (``seed/case`` of ``selfsense gap blind --tip``) with an amplifier at its limits:
Table 3 (mean of displacement and force, % of range) of the default estimator with the amplifier member decided by
the data (``auto``) and forced off; the same error on the calibration trials after the relay release (in sample,
``member_ab.calibration_error``: what a check of the member on the calibration references could read); Table 3 of
the excitation-matched twin (the same device and noise without the effect, driven with the voltage the case's
amplifier applied: ``selfsense.gap.blind.matched_twin_error``), what a perfect amplifier model could reach; and,
beside it, Table 3 of the case's own log with the command channel showing the applied voltage (``V = V_c - V_s`` with
the simulator truth's ``V_c``; the charge and the shunt signal as measured): the same question asked of the case's
data instead of a twin's. Beside them: the member's rebuilt voltage against the simulator's, the H(q) form selected
with the member and with the applied voltage, and what the limit took from the excitation (the applied voltage's span
and the validation references' ranges against the effect-free twin's).
"""
from __future__ import annotations

import argparse
import sys
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from member_ab import calibration_error  # noqa: E402


def check(seed: int, i: int) -> dict:
    from selfsense.gap.blind import FS_CASE, T_CASE, draw_tip_case, matched_twin_error
    from selfsense.gap.blindsim import simulate_family_case
    from selfsense.gap.counterfactual import _summary, tip_table
    from selfsense.sensing.estimator import SelfSensingEstimator, SensingConfig

    c = draw_tip_case(i, seed)
    tr, me, rig, truth = simulate_family_case(c["family"], c["device_seed"], c["effects"], c["noise_seed"], T_CASE,
                                              FS_CASE, with_truth=True)
    row = {"case": f"{seed}/{i}", "family": c["family"], "magnitude": c["effects"].get("rate.amplifier")}
    for mode in ("auto", "off"):
        est = SelfSensingEstimator(config=SensingConfig(), rig=rig, members={"amplifier": mode}).fit(tr, me)
        row[f"table3_{mode}"] = float(_summary(tip_table(tr, me, rig, None, estimator=est))["mean"])
        row[f"cal_{mode}"] = calibration_error(est, tr, me)
        if mode == "auto":
            row["adopted"] = bool((est.amplifier_ or {}).get("applied"))   # the current-limit rebuild
            row["slew_adopted"] = bool(((est.amplifier_ or {}).get("slew") or {}).get("applied"))
            row["form_auto"] = (est.selected_form() or (("-", {}),))[-1][0]
            # the member's rebuilt actuator voltage against the simulator's: RMS [V], the largest over the trials
            row["rebuild_rms_v"] = max(float(np.sqrt(np.mean((est._with_voltage(df)["V"].to_numpy(float)
                                                              - truth[t]["V"].to_numpy(float)) ** 2)))
                                       for t, df in tr.items())
    # what the limit took from the excitation: the applied voltage's span against the effect-free twin's (the voltage
    # asked for), and the validation references' ranges against the twin's; the smallest ratio over the trials
    tr0, me0, _, truth0 = simulate_family_case(c["family"], c["device_seed"], {}, c["noise_seed"], T_CASE, FS_CASE,
                                               with_truth=True)
    row["v_span_ratio"] = min(np.ptp(truth[t]["V"].to_numpy(float)) / np.ptp(truth0[t]["V"].to_numpy(float))
                              for t in tr)
    rng = []
    for t, m in me.iterrows():
        if m["role"] == "validation":
            ref = "dx_ref" if m["reference"] == "displacement" else "f_ref"
            rng.append(np.nanmax(tr[t][ref]) - np.nanmin(tr[t][ref]))
            rng[-1] /= np.nanmax(tr0[t][ref]) - np.nanmin(tr0[t][ref])
    row["range_ratio"] = float(min(rng))
    mk = lambda r: SelfSensingEstimator(config=SensingConfig(), rig=r)  # noqa: E731
    row["matched"] = matched_twin_error(c, mk, truth)
    # the case's own log with the command channel showing the applied voltage: V = V_c(applied) - V_s, the charge
    # and the shunt signal as measured (what a perfect amplifier model would hand the estimator)
    told = {}
    for t, df in tr.items():
        d = df.copy()
        d["V_c"] = truth[t]["V_c"].to_numpy(float)
        d["V"] = d["V_c"] - d["V_s"]
        told[t] = d
    est_told = mk(rig).fit(told, me)
    row["told"] = float(_summary(tip_table(told, me, rig, None, estimator=est_told))["mean"])
    row["form_told"] = (est_told.selected_form() or (("-", {}),))[-1][0]
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", required=True, help="comma-separated seed/case of the tip tier")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    try:
        cases = [tuple(int(x) for x in s.strip().split("/")) for s in a.cases.split(",") if s.strip()]
        assert all(len(c) == 2 for c in cases)
    except (ValueError, AssertionError):
        sys.exit(f"amplifier_member_check.py: --cases expects seed/case,seed/case,... (found {a.cases!r})")
    rows = [check(s, i) for s, i in cases]
    f = lambda x: f"{x:.2f}"  # noqa: E731
    md = ["# Amplifier member: Table 3 against a calibration-side check", "",
          "Command: `python benchmarks/amplifier_member_check.py "
          + " ".join(argv if argv is not None else sys.argv[1:]) + "`", "",
          f"Made {datetime.now(timezone.utc):%Y-%m-%d}. " + __doc__.split("\n\n", 2)[2].strip(), "",
          "| case | family | limit magnitude | adopted | Table 3 auto | Table 3 off | calibration trials auto | "
          "calibration trials off | excitation-matched twin | case's log, applied voltage | rebuilt V, RMS error [V] "
          "(largest trial) | H(q) form: auto / applied voltage | applied / asked voltage span (smallest trial) | "
          "validation reference range / effect-free twin's (smallest trial) |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        md.append(f"| {r['case']} | {r['family']} | {r['magnitude']:.2f} | {'yes' if r['adopted'] else 'no'} | "
                  f"{f(r['table3_auto'])} | {f(r['table3_off'])} | {f(r['cal_auto'])} | {f(r['cal_off'])} | "
                  f"{f(r['matched'])} | {f(r['told'])} | {f(r['rebuild_rms_v'])} | {r['form_auto']} / "
                  f"{r['form_told']} | {f(r['v_span_ratio'])} | {f(r['range_ratio'])} |")
    worse = [r for r in rows if r["adopted"] and r["table3_auto"] > r["table3_off"]]
    caught = [r for r in worse if r["cal_auto"] > r["cal_off"]]
    md += ["", f"Adopted and Table 3 worse than with the member off: {len(worse)} of {len(rows)}; of those, the "
           f"calibration trials' error also worse with it (a calibration-side check would have caught it): "
           f"{len(caught)}. Adopted and the calibration trials' error lower with it: "
           f"{sum(r['adopted'] and r['cal_auto'] < r['cal_off'] for r in rows)} of {len(rows)}."]
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text("\n".join(md) + "\n")
    print("\n".join(md[-len(rows) - 4:]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
