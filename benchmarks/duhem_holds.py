#!/usr/bin/env python
"""Why a Duhem H(q) fit with a creep bank failed the holds of whole-device randomised devices (issue 23).

    python benchmarks/duhem_holds.py --family bouc_wen --seeds 6,9 --out benchmarks/cross_device/whole_device/duhem_holds.md

Per device (``draw_device(family, seed, "clean", randomise="device")``, thesis protocol: the two sines calibrate, the
mixed-drive validation trials give hold rows), with the pipeline's default estimator:

1. **the hold rows against the simulator's truth**: per hold, the change of the H target ``V - slope Q`` (measured V
   and Q) against the change the ideal gauge-H makes (true ``V_H`` plus ``(c_free - slope) q_act``, ``c_free`` the
   true free-tip ``dV_p / dq_act`` of the free sine);
2. **the Duhem model with creep, fitted on the calibration and hold rows** with several creep banks: the default
   (0.1-30 s), the bank cut at 3 s, the default plus 100 s, the device's own three dielectric lags; in-sample RMS on
   the calibration rows, RMS of the hold differences, largest creep weight;
3. **the selection** (blocked CV of the selected model and of the two Duhem candidates) and Table 3.

Run on a checkout before and after a change of the Duhem model to compare; the table is written to ``--out``.
"""
from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from _args import int_ranges  # noqa: E402  (benchmarks/ is on sys.path when run as a script)



def device(family: str, seed: int) -> dict:
    import selfsense.hysteresis.models.select as S
    from selfsense import io as sio
    from selfsense.hysteresis.models import DEFAULT_CREEP_TAU_S, make_model
    from selfsense.report import tables
    from selfsense.sensing import SelfSensingEstimator
    from selfsense.signals import prepare_trial
    from selfsense.sim.families import draw_device
    from selfsense.sim.simulate import simulate_dataset
    from selfsense.stages import sensing_config

    sc = draw_device(family, seed, "clean", randomise="device")
    sc["trials"] = [t for t in sc["trials"] if not (t["role"] == "calibration" and t.get("signal") == "mixed")]
    cap: dict = {}
    orig = S.select_h_model

    def spy(qs, ys, dt, **kw):   # the selection's inputs: calibration rows, joint columns, hold rows
        if not cap:
            cap.update(qs=qs, ys=ys, dt=dt, **kw)
        return orig(qs, ys, dt, **kw)

    with tempfile.TemporaryDirectory(prefix="selfsense-duhem-holds-") as tmp:
        ds, tr = Path(tmp) / sc["name"], Path(tmp) / (sc["name"] + ".truth")
        simulate_dataset(sc, out_dir=ds, truth_dir=tr, contributions=False)
        rig = sio.load_rig(ds)
        meta = sio.load_trials(ds).set_index("trial")
        sigs = {t: prepare_trial(sio.trial_signals(ds, t, rig=rig), rig) for t in meta.index}
        S.select_h_model = spy
        try:
            est = SelfSensingEstimator(config=sensing_config({"calibration": {}, "estimation": {}}), rig=rig
                                       ).fit(sigs, meta)
        finally:
            S.select_h_model = orig
        ests = {}
        for t, s in sigs.items():
            e = est.estimate(s, trial=t)
            e["dx_ref"], e["f_ref"] = s["dx_ref"].to_numpy(), s["f_ref"].to_numpy()
            ests[t] = e
        t3 = tables.table3(tables.per_trial_table(ests, meta.reset_index())).set_index("measurement")
        truth = {t: pd.read_parquet(tr / f"{t}.parquet") for t in meta.index}
        relay = {t: pd.read_parquet(ds / f"{t}.parquet")["relay"].to_numpy() for t in meta.index}
    qs, ys, dt, ex, H = cap["qs"], cap["ys"], cap["dt"], cap["extras"], cap["holds"]
    slope = est.h_slope_
    free = truth["cal_free_sine"]
    c_free = float(np.polyfit(free["q_act"], free["V_p"], 1)[0])
    # 1. hold targets against the truth
    dev = []
    for i, (name, hs) in enumerate(zip(H.names, H.holds)):
        T = truth[name][relay[name] < 0.5].reset_index(drop=True)
        VH, qa = T["V_H"].to_numpy(), T["q_act"].to_numpy()
        for a, b in hs:
            ideal = (VH[b - 1] - VH[a]) + (c_free - slope) * (qa[b - 1] - qa[a])
            dev.append(abs((H.ys[i][b - 1] - H.ys[i][a]) - ideal))
    # 2. the Duhem model with creep on calibration + hold rows, several banks
    lags = tuple(sc["randomise"]["dielectric_tau_s"])
    banks = {"default 0.1-30 s": DEFAULT_CREEP_TAU_S, "cut at 3 s": tuple(t for t in DEFAULT_CREEP_TAU_S if t <= 3.0),
             "default + 100 s": DEFAULT_CREEP_TAU_S + (100.0,),
             "device lags " + "/".join(f"{t:.3g}" for t in lags) + " s": lags}
    fits = {}
    for label, taus in banks.items():
        m = make_model("duhem", degree=3, ridge=1e-7, creep_tau_s=taus).fit(qs, ys, dt, extra=ex, holds=H)
        cal = [float(np.sqrt(np.mean((m.predict(q, dt) + e @ m.extra_coef_[:e.shape[1]] - y) ** 2)))
               for q, y, e in zip(qs, ys, ex)]
        r = []
        for i, hs in enumerate(H.holds):
            p = m.predict(H.qs[i], dt)
            r += [(p[a + 1:b] - p[a]) - (H.ys[i][a + 1:b] - H.ys[i][a]) for a, b in hs]
        fits[label] = {"cal_rms_v": float(np.sqrt(np.mean(np.square(cal)))),
                       "hold_rms_v": float(np.sqrt(np.mean(np.concatenate(r) ** 2))),
                       "max_creep_weight_v": float(np.max(np.abs(m.lin_coef_[:len(taus)])))}
    sel = est.fit_report_["hysteresis"]["selection"]
    cv = {r["label"]: r["cv_rms_mean_v"] for r in sel}
    chosen = next(r["label"] for r in sel if r["selected"])
    return {"family": family, "seed": seed, "lags_s": lags, "n_holds": len(dev), "hold_target_max_dev_v": max(dev),
            "fits": fits, "selected": chosen, "cv_selected_v": cv[chosen],
            "cv_duhem_creep_v": cv.get("duhem(degree=3, ridge=1e-07, creep)"),
            "cv_duhem_v": cv.get("duhem(degree=3, ridge=1e-07)"),
            "displacement_pct": float(t3.loc["displacement", "percent_of_range"]),
            "force_pct": float(t3.loc["force", "percent_of_range"])}


def markdown(recs: list[dict]) -> str:
    out = ["| device | lags [s] | hold target vs truth, max [V] | Duhem + creep on calibration and hold rows: bank: "
           "calibration RMS / hold RMS / largest creep weight [V] | selected (CV [V]) | CV Duhem + creep / Duhem [V] "
           "| Table 3 displacement / force [%] |", "|---|---|---|---|---|---|---|"]
    for r in recs:
        fits = "; ".join(f"{k}: {v['cal_rms_v']:.3f} / {v['hold_rms_v']:.3f} / {v['max_creep_weight_v']:.3g}"
                         for k, v in r["fits"].items())
        out.append(f"| {r['family']} {r['seed']} | {'/'.join(f'{t:.3g}' for t in r['lags_s'])} | "
                   f"{r['hold_target_max_dev_v']:.3f} ({r['n_holds']} holds) | {fits} | {r['selected']} "
                   f"({r['cv_selected_v']:.3f}) | {r['cv_duhem_creep_v']:.3f} / {r['cv_duhem_v']:.3f} | "
                   f"{r['displacement_pct']:.2f} / {r['force_pct']:.2f} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--family", default="bouc_wen")
    ap.add_argument("--seeds", default="6,9")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    recs = [device(a.family, s) for s in int_ranges(a.seeds)]
    text = markdown(recs)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
