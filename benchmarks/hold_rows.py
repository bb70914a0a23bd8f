#!/usr/bin/env python
"""The reference-free hold rows of the H(q) fit (``hold_rows: auto`` against ``off``) on the thesis protocol.

    python benchmarks/hold_rows.py --seeds 0-2 --holds 0,8 --jobs 2 --out benchmarks/hold_rows

Virtual devices of every truth family (``selfsense.sim.families``), presets ``clean`` and ``drift`` (leakage + offset
drift + creep), **thesis protocol** (calibration on the free-tip and blocked sines only: the free-tip mixed
calibration trial is dropped). ``--holds``: hold lengths of the mixed drives [s], 0 = the family's default (1.2 s);
a longer hold lengthens its trials to at least 40 s. Each device is fitted twice on the same data, with the
calibration's ``hold_rows`` off and auto (everything else the pipeline default), and scored on its validation trials
(Table 3: mean |estimate - reference| / reference range, % per trial, mean over trials).

Records are appended to ``records.jsonl`` (resumable: a device already recorded is skipped); ``summary.md`` is
rewritten from all records.
"""
from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _args import int_ranges  # noqa: E402  (benchmarks/ is on sys.path when run as a script)



def run_device(family: str, preset: str, seed: int, hold_s: float) -> dict:
    from selfsense import io as sio
    from selfsense.report import tables
    from selfsense.sensing import SelfSensingEstimator
    from selfsense.signals import prepare_trial
    from selfsense.sim.families import draw_device
    from selfsense.sim.simulate import simulate_dataset
    from selfsense.stages import sensing_config

    sc = draw_device(family, seed, preset)
    sc["trials"] = [t for t in sc["trials"] if t["trial"] != "cal_free_mixed"]  # the thesis protocol
    if hold_s:
        for tr in sc["trials"]:
            if tr.get("signal") == "mixed":
                tr["hold_s"] = float(hold_s)
                tr["duration"] = max(float(tr["duration"]), 40.0)
    rec = {"family": family, "preset": preset, "seed": int(seed), "hold_s": float(hold_s or 1.2)}
    with tempfile.TemporaryDirectory(prefix="selfsense-holds-") as tmp:
        ds = Path(tmp) / sc["name"]
        simulate_dataset(sc, out_dir=ds, truth_dir=Path(tmp) / (sc["name"] + ".truth"), contributions=False)
        rig = sio.load_rig(ds)
        meta = sio.load_trials(ds).set_index("trial")
        sigs = {t: prepare_trial(sio.trial_signals(ds, t, rig=rig), rig) for t in meta.index}
        for mode in ("off", "auto"):
            est = SelfSensingEstimator(config=sensing_config({"calibration": {"hold_rows": mode}, "estimation": {}}),
                                       rig=rig).fit(sigs, meta)
            ests = {}
            for t, s in sigs.items():
                e = est.estimate(s, trial=t)
                e["dx_ref"], e["f_ref"] = s["dx_ref"].to_numpy(), s["f_ref"].to_numpy()
                ests[t] = e
            t3 = tables.table3(tables.per_trial_table(ests, meta.reset_index())).set_index("measurement")
            hr = est.fit_report_["hysteresis"].get("hold_rows", {})
            rec[mode] = {"displacement_pct": float(t3.loc["displacement", "percent_of_range"]),
                         "force_pct": float(t3.loc["force", "percent_of_range"]),
                         "h_model": est.hysteresis_.label(), "n_holds": int(hr.get("n_holds", 0))}
    return rec


def summary(recs: list[dict]) -> str:
    lines = ["# Hold rows of the H(q) fit, thesis protocol", "",
             "Command: `python benchmarks/hold_rows.py --seeds 0-2 --holds 0,8 --jobs 2 --out benchmarks/hold_rows`", "",
             "Median Table 3 (% of range, displacement / force) over devices; the same devices and data fitted with "
             "`hold_rows: off` and `auto`. 'better' counts devices whose displacement error fell by more than 10 % "
             "of its value, 'worse' those where it rose by more than 10 %.", "",
             "| family | preset | hold [s] | devices | off: displacement / force % | auto: displacement / force % | "
             "better / worse |", "|---|---|---|---|---|---|---|"]
    keys = sorted({(r["family"], r["preset"], r["hold_s"]) for r in recs})
    for fam, preset, hold in keys:
        rs = [r for r in recs if (r["family"], r["preset"], r["hold_s"]) == (fam, preset, hold)]
        med = {m: (np.median([r[m]["displacement_pct"] for r in rs]), np.median([r[m]["force_pct"] for r in rs]))
               for m in ("off", "auto")}
        ratio = [r["auto"]["displacement_pct"] / max(r["off"]["displacement_pct"], 1e-9) for r in rs]
        lines.append(f"| {fam} | {preset} | {hold:g} | {len(rs)} | {med['off'][0]:.2f} / {med['off'][1]:.2f} | "
                     f"{med['auto'][0]:.2f} / {med['auto'][1]:.2f} | {sum(x < 0.9 for x in ratio)} / "
                     f"{sum(x > 1.1 for x in ratio)} |")
    for hold in sorted({r["hold_s"] for r in recs}):
        rs = [r for r in recs if r["hold_s"] == hold]
        lines.append("")
        lines.append(f"All devices with holds of {hold:g} s ({len(rs)}): median displacement "
                     f"{np.median([r['off']['displacement_pct'] for r in rs]):.2f} % (off) -> "
                     f"{np.median([r['auto']['displacement_pct'] for r in rs]):.2f} % (auto), force "
                     f"{np.median([r['off']['force_pct'] for r in rs]):.2f} -> "
                     f"{np.median([r['auto']['force_pct'] for r in rs]):.2f} %.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    from selfsense.sim.families import FAMILIES

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0-2")
    ap.add_argument("--holds", default="0,8", help="hold lengths of the mixed drives [s], 0 = the family default")
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--presets", default="clean,drift")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/hold_rows"))
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    rec_path = a.out / "records.jsonl"
    recs = [json.loads(x) for x in rec_path.read_text().splitlines()] if rec_path.exists() else []
    done = {(r["family"], r["preset"], r["seed"], r["hold_s"]) for r in recs}
    todo = [(f, p, s, float(h)) for f in a.families.split(",") for p in a.presets.split(",") for s in int_ranges(a.seeds)
            for h in a.holds.split(",") if (f, p, s, float(h) or 1.2) not in done]
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        for rec in pool.map(run_device, *zip(*todo)) if todo else []:
            recs.append(rec)
            with rec_path.open("a") as fh:
                fh.write(json.dumps(rec, sort_keys=True) + "\n")
            print(json.dumps(rec), flush=True)
    (a.out / "summary.md").write_text(summary(recs))
    print(f"summary: {a.out / 'summary.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
