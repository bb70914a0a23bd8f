#!/usr/bin/env python
"""False adoptions of the charge link's absorption member on virtual devices without dielectric absorption.

    python benchmarks/absorption_null.py --families preisach,gpi,bouc_wen,jiles_atherton,rate_kp --seeds 0-5 \\
        --out benchmarks/gap_tip/absorption_null.md

The devices of the stage-chain benchmark (``selfsense.sim.families.draw_device``, presets ``clean`` and ``drift``:
leakage, offset drift and creep, never an absorption branch), thesis protocol (the free-tip mixed calibration trial
dropped). For each, :func:`selfsense.chain.charge.fit_absorption` on the free-tip calibration trials, exactly as the
estimator calls it: whether the member would be adopted, its blocked-CV gain and time constant. Writes the table
(Markdown) and the records (``.jsonl.gz`` beside it).
"""
from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import gzip  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402
from _args import int_ranges  # noqa: E402  (benchmarks/ is on sys.path when run as a script)



def run_device(family: str, preset: str, seed: int) -> dict:
    from selfsense import io as sio
    from selfsense.chain.charge import fit_absorption
    from selfsense.signals import prepare_trial
    from selfsense.sim.families import draw_device
    from selfsense.sim.simulate import simulate_dataset

    sc = draw_device(family, seed, preset)
    sc["trials"] = [t for t in sc["trials"] if t["trial"] != "cal_free_mixed"]  # the thesis protocol
    with tempfile.TemporaryDirectory(prefix="selfsense-absnull-") as tmp:
        ds = Path(tmp) / sc["name"]
        simulate_dataset(sc, out_dir=ds, truth_dir=Path(tmp) / (sc["name"] + ".truth"), contributions=False)
        rig = sio.load_rig(ds)
        meta = sio.load_trials(ds).set_index("trial")
        free = [t for t, r in meta.iterrows() if r["role"] == "calibration" and r["tip"] == "free"
                and r["reference"] == "displacement"]
        fit = fit_absorption({t: prepare_trial(sio.trial_signals(ds, t, rig=rig), rig) for t in free})
    inner = [g["cv_gain"] for g in fit.grid[1:-1] if g["c_f"] > 0]
    return {"family": family, "preset": preset, "seed": int(seed), "supported": bool(fit.supported),
            "best_interior_gain": float(max(inner)) if inner else float("nan"),
            "cv_with_over_leak": float(fit.cv_rms_m_with / fit.cv_rms_m_leak),
            "cv_gain": float(fit.cv_gain), "tau_s": float(fit.tau_s), "c_f": float(fit.c_f),
            "absorption_in_device": float(sc["effects"].get("dielectric_absorption", 0.0))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="preisach,gpi,bouc_wen,jiles_atherton,rate_kp")
    ap.add_argument("--presets", default="clean,drift")
    ap.add_argument("--seeds", default="0-5")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    recs = []
    for f in a.families.split(","):
        for s in int_ranges(a.seeds):
            for p in a.presets.split(","):
                r = run_device(f, p, s)
                recs.append(r)
                print(f"{f} {p} {s}: supported {r['supported']}, gain {r['cv_gain']:.3f}, tau {r['tau_s']:.3g} s",
                      flush=True)
    rows = ["| family | preset | devices | adopted | largest blocked-CV gain (threshold 0.3) | largest gain at an interior "
            "time constant with c > 0 | smallest RMS ratio, absorption / leakage column (adopted only <= 0.9) |",
            "|---|---|---|---|---|---|---|"]
    for f in a.families.split(","):
        for p in a.presets.split(","):
            v = [r for r in recs if r["family"] == f and r["preset"] == p]
            rows.append(f"| {f} | {p} | {len(v)} | {sum(r['supported'] for r in v)} | "
                        f"{max(r['cv_gain'] for r in v):.3f} | "
                        f"{max((r['best_interior_gain'] for r in v if r['best_interior_gain'] == r['best_interior_gain']), default=float('nan')):.3f} | "
                        f"{min((r['cv_with_over_leak'] for r in v if r['cv_with_over_leak'] == r['cv_with_over_leak']), default=float('nan')):.3f} |")
    cmd = "python benchmarks/absorption_null.py " + " ".join(sys.argv[1:] if argv is None else argv)
    n_ad = sum(r["supported"] for r in recs)
    text = (f"# Absorption member on devices without an absorption branch\n\nCommand: `{cmd}` "
            f"({datetime.now(timezone.utc).strftime('%Y-%m-%d')})\n\n" + "\n".join(rows) + "\n\n"
            f"Adopted (a false adoption) on {n_ad} of {len(recs)} devices.\n")
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
