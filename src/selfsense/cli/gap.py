"""``selfsense gap ...``: the stage-wise sim-to-real gap diagnostic and its blind check (docs/gap.md).

  selfsense gap diagnose DATASET_DIR --out OUT_DIR [--configfile config.yaml] [--seed S] [--jobs J]
  selfsense gap blind --n N --seed S --out DIR [--jobs J] [--thresholds FILE.json] [--tip]
  selfsense gap blind-calibrate --n N --seed S --out FILE.json [--jobs J]     (null thresholds)
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["main"]


def _diagnose(a) -> int:
    import yaml

    from selfsense.gap.pipeline import run_stage_diagnose

    cfg = yaml.safe_load(Path(a.configfile).read_text()) if a.configfile else {}
    v = run_stage_diagnose(a.dataset_dir, a.out, cfg, seed=a.seed, figures=not a.no_figures, force=a.force,
                           workers=a.jobs)
    print(f"gap diagnose {a.dataset_dir}: {v['message']} Wrote {a.out}")
    return 0


def _blind(a) -> int:
    from selfsense.io.outputs import MARKER, check_output_dir, output_lock

    from selfsense.gap.blind import load_stage_thresholds, run_campaign

    out = Path(a.out)
    cmd = f"selfsense gap blind --n {a.n} --seed {a.seed} --jobs {a.jobs} --out {a.out}"
    thr = load_stage_thresholds(a.thresholds) if a.thresholds else None
    if a.tip:
        from selfsense.gap.blind import run_tip_tier

        cmd = f"selfsense gap blind --tip --n {a.n} --seed {a.seed} --jobs {a.jobs} --out {a.out}"
        with output_lock(out):
            if not (out / MARKER).exists():
                check_output_dir(out, force=a.force)
            out.mkdir(parents=True, exist_ok=True)
            (out / MARKER).write_text("written by selfsense gap blind\n")
            sc = run_tip_tier(a.n, a.seed, a.jobs, out, cmd)
        print(f"{a.n} tip cases in {sc['seconds']:.0f} s; median tip shrink error "
              f"{sc['median_tip_shrink_error']:.3f} over {sc['n_scored']} -> {out}/tip_scores.md")
        return 0
    with output_lock(out):
        if not (out / MARKER).exists():
            check_output_dir(out, force=a.force)
        out.mkdir(parents=True, exist_ok=True)
        (out / MARKER).write_text("written by selfsense gap blind\n")
        sc = run_campaign(a.n, a.seed, a.jobs, out, cmd, thresholds=thr)
    print(f"{a.n} cases in {sc['seconds']:.0f} s; family_top1={sc['family_top1']:.3f} "
          f"member_top1={sc['member_top1']:.3f} false_alarm={sc['false_alarm_rate']:.3f} "
          f"open_set={sc['open_set_flagged']:.3f} shrink_error={sc['median_shrink_error']:.3f} -> {out}/scores.md")
    return 0


def _blind_calibrate(a) -> int:
    from selfsense.io import atomic_write_text

    from selfsense.gap.blind import calibrate

    doc = calibrate(a.n, a.seed, a.jobs)
    doc["command"] = f"selfsense gap blind-calibrate --n {a.n} --seed {a.seed} --jobs {a.jobs} --out {a.out}"
    atomic_write_text(a.out, json.dumps(doc, indent=1, sort_keys=True, default=float) + "\n")
    print(f"stage thresholds from {a.n} effect-free cases (T = {doc['T']:.3f}) -> {a.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    import os

    # the diagnostic's linear algebra is many tiny problems: one BLAS thread per process is fastest, and the
    # benchmark scales out by processes (one Snakemake job per case). Only effective before numpy is imported.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    p = argparse.ArgumentParser(prog="selfsense gap", allow_abbrev=False,
                                description="sim-to-real gap diagnostic (docs/gap.md)")
    sub = p.add_subparsers(dest="cmd", required=True, metavar="{diagnose,blind,blind-calibrate}")
    d = sub.add_parser("diagnose", help="diagnose one dataset (any dataset; truth folder optional)",
                       description="diagnose one dataset stage by stage (any dataset; truth folder optional)",
                       allow_abbrev=False)
    d.add_argument("dataset_dir", help="raw dataset folder (rig.yaml, trials.csv, logs)")
    d.add_argument("--out", required=True, help="output folder (verdict.json, stages.csv, effects.csv, candidates.csv, "
                   "shrink.csv / shrink.md, chain.csv, stage_gains.png)")
    d.add_argument("--configfile", default=None, help="config.yaml whose calibration / estimation sections set the "
                   "estimator that is diagnosed (default: the pipeline's defaults)")
    d.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default 0)")
    d.add_argument("--no-figures", action="store_true", help="skip the figure (faster)")
    d.add_argument("--jobs", type=int, default=1, help="recalibrations fitted at a time, in worker processes "
                   "(results do not depend on it)")
    d.add_argument("--force", action="store_true",
                   help="replace --out even if it is a non-empty folder selfsense did not create")
    d.set_defaults(fn=_diagnose)
    bl = sub.add_parser("blind", help="blind check of the stage-wise diagnostic across device families",
                        description="blind check of the stage-wise diagnostic across device families "
                                    "(docs/gap.md, 'Stage-wise diagnostic')", allow_abbrev=False)
    bl.add_argument("--n", type=int, required=True, help="number of blind cases (families in turn)")
    bl.add_argument("--seed", type=int, required=True, help="seed of the case draw")
    bl.add_argument("--out", required=True, help="output folder (scores.md, scores.json, cases.jsonl.gz)")
    bl.add_argument("--jobs", type=int, default=1, help="worker processes (results do not depend on it)")
    bl.add_argument("--thresholds", default=None, help="stage thresholds JSON (default: the packaged ones)")
    bl.add_argument("--force", action="store_true", help="replace --out even if selfsense did not create it")
    bl.add_argument("--tip", action="store_true", help="the tip tier instead: single-effect cases, the default "
                    "estimator, predicted against re-simulated tip shrink (slow: several estimator fits per case)")
    bl.set_defaults(fn=_blind)
    bc = sub.add_parser("blind-calibrate", help="null thresholds of the stage-wise diagnostic",
                        description="null thresholds of the stage-wise diagnostic from effect-free cases over the "
                                    "device families", allow_abbrev=False)
    bc.add_argument("--n", type=int, default=200, help="effect-free cases (default 200; families in turn)")
    bc.add_argument("--seed", type=int, default=1, help="seed of the null cases (default 1; keep it apart from the "
                    "campaign's)")
    bc.add_argument("--jobs", type=int, default=1, help="worker processes (results do not depend on it)")
    bc.add_argument("--out", required=True, help="output thresholds JSON")
    bc.set_defaults(fn=_blind_calibrate)
    a = p.parse_args(argv)
    return int(a.fn(a) or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
