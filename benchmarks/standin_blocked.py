#!/usr/bin/env python
"""How well the gap diagnostic's stand-in H carries the free tip's loop to the blocked tip, on effect-free devices.

    python benchmarks/standin_blocked.py --seed 8080 --cases 100-123 --out benchmarks/gap_stages/standin_blocked.md

The blocked stage of :mod:`selfsense.gap.stages` models the actuator voltage of the blocked-tip trials as
``a Q + b H^(Q)`` plus a constant per trial, H^ the stand-in's H identified on the free-tip calibration trial
(:mod:`selfsense.gap.standin`). On a device without any effect that relation is exact for the true H, so the stage's
held-out residual (blocked CV, the stage's own score) is the stand-in's model error, which hides the effects the stage
tests (stress-dependent hysteresis, a remanent state). Cases: the blind campaign's effect-free draws
(:func:`selfsense.gap.blind.draw_case` families in turn, :func:`selfsense.gap.blindsim.simulate_family_case`, no
effects) of a seed; per case the held-out RMS of the blocked stage's nominal model over the RMS of V on the blocked
trials. Writes a Markdown table and the records (``.jsonl`` beside it).
"""
from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _args import int_ranges  # noqa: E402  (benchmarks/ is on sys.path when run as a script)



def run_case(i: int, seed: int) -> dict:
    from selfsense.gap.blind import FS_CASE, T_CASE, draw_case
    from selfsense.gap.blindsim import simulate_family_case
    from selfsense.gap.stages import build_stage, prepare_signals

    c = draw_case(i, seed)
    tr, me, rig = simulate_family_case(c["family"], c["device_seed"], {}, c["noise_seed"], T_CASE, FS_CASE)
    sigs, ctx = prepare_signals(tr, me, rig)
    sm = build_stage("blocked", sigs, ctx, nominal_only=True)
    return {"case": i, "seed": seed, "family": c["family"], "rms_heldout_v": sm.r(sm.nominal), "rms_v": sm.y_rms,
            "relative": sm.r(sm.nominal) / sm.y_rms}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--cases", required=True, help="case indices, e.g. 100-123")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    recs = [run_case(i, a.seed) for i in int_ranges(a.cases)]
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    rel = np.array([r["relative"] for r in recs])
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    L = ["# The stand-in H on the blocked tip, effect-free devices", "",
         f"Command: `python benchmarks/standin_blocked.py --seed {a.seed} --cases {a.cases} --out {a.out}` "
         f"(commit {rev or 'unknown'}, {datetime.now(timezone.utc):%Y-%m-%d}).", "",
         "Held-out RMS of the blocked stage's nominal model (a Q + b H^(Q) + a constant per trial) over the RMS of V on "
         "the blocked trials: the stand-in's model error where the device has no effect.", "",
         "| family | cases | median | largest |", "|---|---|---|---|"]
    for fam in sorted({r["family"] for r in recs}) + ["all"]:
        v = rel if fam == "all" else np.array([r["relative"] for r in recs if r["family"] == fam])
        L.append(f"| {fam} | {len(v)} | {100 * np.median(v):.2f} % | {100 * v.max():.2f} % |")
    out.write_text("\n".join(L) + "\n")
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
