"""How precise the amplifier member's voltage rebuild must be: tip cases of the gap diagnostic with an amplifier at its
current limit, scored with the rebuild's reference H(q) swapped for others and for the simulator's own truth.

    python benchmarks/amplifier_rebuild.py --seed 14142 --cases 17,121,129 --out benchmarks/gap_tip/amplifier_rebuild.md

The member (docs/method.md 1a) interpolates ``V - H(q)`` linearly in the charge between the samples where ``V`` is
observed and adds a reference ``H(q)`` back. Per case this script reports Table 3 (mean of displacement and force, %
of range, the default estimator ``SensingConfig()`` with the member forced on) and the mean |V - V_true| over every
trial, for

* the member as it is (reference: Preisach 12 x 12 grid, 6 plays, creep, fitted on the observed samples);
* two other references fitted on the same samples (PI with 20 plays; Preisach 16 x 16 grid, 10 plays);
* an oracle: the rebuild with the simulator's true hysteresis voltage ``V_H`` as its reference;
* an oracle: the simulator's true actuator voltage for every sample, member off;

beside the effect-free twin (same device, drive and noise). The oracles read the simulator's truth, which the
estimator never sees: they bound what a better reference could give, they are not a method.
"""
from __future__ import annotations

import argparse
import sys
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

REFERENCES = {
    "member (Preisach 12, 6 plays)": ("preisach", {"n_grid": 12, "n_play": 6, "ridge": 1e-4}),
    "PI, 20 plays": ("pi", {"n_play": 20, "ridge": 1e-3}),
    "Preisach 16, 10 plays": ("preisach", {"n_grid": 16, "n_play": 10, "ridge": 1e-3}),
}


def _case(i: int, seed: int) -> dict:
    from selfsense.chain.amplifier import rebuild_voltage
    from selfsense.gap.blind import FS_CASE, T_CASE, draw_tip_case
    from selfsense.gap.blindsim import simulate_family_case
    from selfsense.gap.counterfactual import _summary, tip_table
    from selfsense.hysteresis.models import make_model
    from selfsense.sensing.estimator import (SelfSensingEstimator, SensingConfig, _rig_params,
                                             _with_column)
    from selfsense.chain.amplifier import limited_mask
    from selfsense.io.rig import rig_value

    c = draw_tip_case(i, seed)
    if "rate.amplifier" not in c["effects"]:
        raise SystemExit(f"case {i} of seed {seed} has no rate.amplifier effect ({c['effects']})")
    tr, me, rig, truth = simulate_family_case(c["family"], c["device_seed"], c["effects"], c["noise_seed"], T_CASE,
                                              FS_CASE, with_truth=True)
    tr0, me0, rig0 = simulate_family_case(c["family"], c["device_seed"], {}, c["noise_seed"], T_CASE, FS_CASE)
    plain = lambda r: SelfSensingEstimator(config=SensingConfig(), rig=r)  # noqa: E731
    rows = {"effect-free twin": (_summary(tip_table(tr0, me0, rig0, plain))["mean"], float("nan"), "")}
    true_vh = {t: truth[t]["V_H"].to_numpy(dtype=float) for t in tr}

    def v_err(est) -> float:
        return float(np.mean([np.mean(np.abs(est._with_voltage(tr[t])["V"].to_numpy() - truth[t]["V"].to_numpy()))
                              for t in me.index]))

    for label, (kind, params) in REFERENCES.items():
        class Ref(SelfSensingEstimator):
            def _anchor_h(self, trials, meta, lim, kind=kind, params=params):
                R = rig_value(self.rig, "shunt_resistance_ohm")
                meta = meta.set_index("trial") if "trial" in meta.columns else meta
                cal = meta[meta["role"] == "calibration"]
                seen = {t: _with_column(trials[t], "V", np.where(limited_mask(trials[t], R, lim.i_lim, lim.band), np.nan,
                                                                 trials[t]["V"].to_numpy(dtype=float)))
                        for t in cal.index}
                p = _rig_params(self.rig)
                qs, ys, ex, _, _, dt = self._h_segments(seen, cal, 1.0 / (p["n_A"] * p["C_p"]), 0.0, drift_cols=False)
                m = make_model(kind, **params)
                m.fit(qs, ys, dt, extra=ex)
                return m

        mk = lambda r, cls=Ref: cls(config=SensingConfig(), rig=r, members={"amplifier": "on"})  # noqa: E731
        est = mk(rig).fit(tr, me)
        rows[f"rebuild, reference {label}"] = (_summary(tip_table(tr, me, rig, mk, estimator=est))["mean"], v_err(est),
                                               est.fit_report_["hysteresis"]["selected"])

    class TrueVH(SelfSensingEstimator):
        def _with_voltage(self, df):
            df = self._with_lag(self._with_slew(df))
            if not self.amplifier_.get("applied"):
                return df
            from selfsense.chain.amplifier import AmplifierLimit

            lim = AmplifierLimit(**{k: self.amplifier_[k] for k in ("i_lim", "band", "fraction", "longest_run_s",
                                                                    "lag", "supported", "note")})
            q = df["q"].to_numpy()
            t = next(k for k, d in tr.items() if len(d) == len(df) and np.array_equal(d["q"].to_numpy(), q))
            V = rebuild_voltage(df, rig_value(self.rig, "shunt_resistance_ohm"), rig_value(self.rig, "amplifier_gain"),
                                lim, lambda d: true_vh[t][:len(d)])
            return _with_column(df, "V", V)

    mk = lambda r: TrueVH(config=SensingConfig(), rig=r, members={"amplifier": "on"})  # noqa: E731
    est = mk(rig).fit(tr, me)
    rows["rebuild, reference the true V_H (oracle)"] = (_summary(tip_table(tr, me, rig, mk, estimator=est))["mean"],
                                                       v_err(est), est.fit_report_["hysteresis"]["selected"])
    orc = {}
    for t, s in tr.items():
        s = s.copy()
        s["V"] = truth[t]["V"].to_numpy()[:len(s)]
        orc[t] = s
    off = lambda r: SelfSensingEstimator(config=SensingConfig(), rig=r, members={"amplifier": "off"})  # noqa: E731
    est = off(rig).fit(orc, me)
    rows["the true V, member off (oracle)"] = (_summary(tip_table(orc, me, rig, off, estimator=est))["mean"], 0.0,
                                               est.fit_report_["hysteresis"]["selected"])
    return {"case": i, "family": c["family"], "limit_ma": 1.0 / c["effects"]["rate.amplifier"], "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=14142)
    ap.add_argument("--cases", required=True, help="comma-separated tip-campaign case indices with rate.amplifier")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    lines = [f"# Amplifier member: how precise the voltage rebuild must be (tip campaign seed {a.seed})", "",
             f"Command: `python benchmarks/amplifier_rebuild.py --seed {a.seed} --cases {a.cases} --out {a.out}` "
             f"({datetime.now(timezone.utc):%Y-%m-%d})", "",
             "Table 3: mean of displacement and force, % of range, default estimator with the amplifier member forced "
             "on. |V - V_true|: mean over every sample of every trial. The oracles read the simulator's truth.", ""]
    for i in (int(x) for x in a.cases.split(",")):
        r = _case(i, a.seed)
        lines += [f"## Case {r['case']} ({r['family']}, current limit {r['limit_ma']:.3f} mA)", "",
                  "| variant | Table 3 [points] | mean abs(V - V_true) [V] | selected H(q) |", "|---|---|---|---|"]
        for k, (t3, ve, sel) in r["rows"].items():
            lines.append(f"| {k} | {t3:.2f} | {'-' if not np.isfinite(ve) else f'{ve:.2f}'} | {sel} |")
        lines.append("")
        print("\n".join(lines[-(len(r["rows"]) + 4):]), flush=True)
    Path(a.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
