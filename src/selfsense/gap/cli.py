"""``selfsense gap ...``: the sim-to-real gap diagnostic and its blind benchmark.

  selfsense gap diagnose DATASET_DIR --out OUT_DIR [--configfile config.yaml] [--seed S]    (stage-wise)
  selfsense gap diagnose DATASET_DIR --out OUT_DIR --method library [--estimator ...] [--n-boot B]  (earlier design)
  selfsense gap blind --n N --seed S --out DIR [--jobs J]        (stage-wise diagnostic, blind, device families)
  selfsense gap blind-calibrate --n N --seed S --out FILE.json [--jobs J]     (its null thresholds)
  selfsense gap benchmark --n N --seed S --out DIR [--tier fast|full] [--sim device|toy]
                          [--estimator sensing_ri|sensing|fast] [--jobs J]
  selfsense gap scenario --i I --seed S --out FILE.json [--tier fast|full] [--estimator ...]   (one case)
  selfsense gap aggregate SCENARIO_JSON... --out DIR                                          (scores from case files)
  selfsense gap calibrate --n N --seed S --out FILE.json [--tier fast|full] [--sim device|toy]
                          [--estimator ...] [--jobs J]                     (null-calibrated thresholds)
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

__all__ = ["main"]


def _diagnose(a) -> int:
    if a.method == "stages":
        import yaml

        from .pipeline import run_stage_diagnose

        cfg = yaml.safe_load(Path(a.configfile).read_text()) if a.configfile else {}
        v = run_stage_diagnose(a.dataset_dir, a.out, cfg, seed=a.seed, figures=not a.no_figures, force=a.force)
        print(f"gap diagnose {a.dataset_dir}: {v['message']} Wrote {a.out}")
        return 0
    from .api import run_diagnose

    d = run_diagnose(a.dataset_dir, a.out, estimator=a.estimator, seed=a.seed, n_boot=a.n_boot,
                     figures=not a.no_figures, progress=None, force=a.force)
    v = d.verdict
    if v.get("estimator_fallback"):
        print(f"gap diagnose: note: estimator {v['estimator_fallback']}", file=sys.stderr)
    print(f"gap diagnose {a.dataset_dir}: effects={v['effects']} unexplained={v['unexplained']} "
          f"error {v['score_before']:.2f} -> {v['score_after_all']:.2f} % of range; wrote {a.out}")
    return 0


def _benchmark(a) -> int:
    from .benchmark import run_benchmark

    t0 = time.perf_counter()
    cmd = f"selfsense gap benchmark --n {a.n} --seed {a.seed} --tier {a.tier} --out {a.out}"
    if a.sim != "device":
        cmd += f" --sim {a.sim}"
    if a.estimator != "sensing_ri":
        cmd += f" --estimator {a.estimator}"
    if a.jobs > 1:
        cmd += f" --jobs {a.jobs}"
    from selfsense.io.outputs import MARKER, check_output_dir, output_lock

    out = Path(a.out)
    with output_lock(out):  # one campaign per folder at a time; a foreign non-empty folder is never written into
        if not (out / "scenarios").is_dir():  # a new campaign (an existing one is resumed)
            check_output_dir(out, force=a.force)
        out.mkdir(parents=True, exist_ok=True)
        (out / MARKER).write_text("written by selfsense gap benchmark\n")
        sc = run_benchmark(a.n, a.seed, a.tier, out, cmd, sim_kind=a.sim, estimator=a.estimator, jobs=a.jobs)
    dt = time.perf_counter() - t0
    print(f"{a.n} cases in {dt:.1f} s; family_top1={sc['family_top1']:.3f} member_top1={sc['member_top1']:.3f} "
          f"false_alarm={sc['false_alarm_rate_effect_free']:.3f} -> {a.out}/scores.md")
    return 0


def _scenario(a) -> int:

    from .api import run_scenario_to_json

    run_scenario_to_json(a.i, a.seed, a.tier, a.out, estimator=a.estimator)
    return 0


def _aggregate(a) -> int:
    from .api import aggregate_scenarios

    aggregate_scenarios(a.files, a.out)
    return 0


def _calibrate(a) -> int:
    from .benchmark import calibrate_thresholds

    thr = calibrate_thresholds(a.n, a.seed, a.tier, sim_kind=a.sim, estimator=a.estimator, jobs=a.jobs)
    doc = {"thresholds": {k: v for k, v in thr.items() if not k.startswith("_")},
           "null_gains": thr["_null_gains"], "null_generic_gain": thr["_null_generic"],
           "calibration": {"n_null": a.n, "seed": a.seed, "tier": a.tier, "quantile": thr["_q"],
                           "command": f"selfsense gap calibrate --n {a.n} --seed {a.seed} --tier {a.tier} --sim {a.sim} "
                                      f"--estimator {a.estimator} --out {a.out}"}}
    from selfsense.io import atomic_write_text

    atomic_write_text(a.out, json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc, indent=1))
    return 0


def _blind(a) -> int:
    from selfsense.io.outputs import MARKER, check_output_dir, output_lock

    from .blind import load_stage_thresholds, run_campaign

    out = Path(a.out)
    cmd = f"selfsense gap blind --n {a.n} --seed {a.seed} --jobs {a.jobs} --out {a.out}"
    thr = load_stage_thresholds(a.thresholds) if a.thresholds else None
    if a.tip:
        from .blind import run_tip_tier

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

    from .blind import calibrate

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
    sub = p.add_subparsers(dest="cmd", required=True, metavar="{diagnose,blind,blind-calibrate,benchmark,scenario,aggregate,calibrate}")
    d = sub.add_parser("diagnose", help="diagnose one dataset (any dataset; truth folder optional)", description="diagnose one dataset (any dataset; truth folder optional)", allow_abbrev=False)
    d.add_argument("dataset_dir", help="raw dataset folder (rig.yaml, trials.csv, logs); a truth folder beside it is optional")
    d.add_argument("--out", required=True, help="output folder (attribution.csv, budget.csv, verdict.json, figures)")
    d.add_argument("--method", choices=["stages", "library"], default="stages",
                   help="stages: stage-wise diagnostic in the measured signals (default); library: the earlier "
                        "tip-level library diagnostic (docs/gap.md, 'Earlier design')")
    d.add_argument("--configfile", default=None, help="config.yaml whose calibration / estimation sections set the "
                   "estimator that is diagnosed (default: the pipeline's defaults); --method stages")
    d.add_argument("--estimator", choices=["fast", "sensing", "sensing_ri"], default="sensing",
                   help="--method library only: sensing: the project's SelfSensingEstimator (default); fast: the "
                        "NNLS stand-in")
    d.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default 0)")
    d.add_argument("--n-boot", type=int, default=30, help="bootstrap resamples per candidate effect (default 30)")
    d.add_argument("--no-figures", action="store_true", help="skip the figures (faster)")
    d.add_argument("--force", action="store_true",
                   help="replace --out even if it is a non-empty folder selfsense did not create")
    d.set_defaults(fn=_diagnose)
    b = sub.add_parser("benchmark", help="blind benchmark on simulated scenarios", description="blind benchmark on simulated scenarios", allow_abbrev=False)
    b.add_argument("--n", type=int, required=True, help="number of blind scenarios")
    b.add_argument("--seed", type=int, required=True, help="seed of the scenario draw")
    b.add_argument("--out", required=True, help="output folder (scores.md, case records)")
    b.add_argument("--tier", choices=["fast", "full"], default="fast", help="scenario length and detail (default fast)")
    b.add_argument("--sim", choices=["device", "toy"], default="device",
                   help="device: selfsense.sim (default); toy: selfsense.gap.toysim")
    b.add_argument("--estimator", choices=["fast", "sensing", "sensing_ri"], default="sensing_ri",
                   help="nominal model whose gap is diagnosed (default sensing_ri: RI + creep, the best nominal)")
    b.add_argument("--force", action="store_true", help="write into --out even if it is a non-empty folder "
                   "selfsense did not create")
    b.add_argument("--jobs", type=int, default=1, help="worker processes (results do not depend on it)")
    b.set_defaults(fn=_benchmark)
    s = sub.add_parser("scenario", help="one benchmark case -> JSON", description="one benchmark case -> JSON", allow_abbrev=False)
    s.add_argument("--i", type=int, required=True, help="index of the scenario in the draw")
    s.add_argument("--seed", type=int, required=True, help="seed of the scenario draw")
    s.add_argument("--out", required=True, help="output JSON file of the case record")
    s.add_argument("--tier", choices=["fast", "full"], default="fast", help="scenario length and detail (default fast)")
    s.add_argument("--estimator", choices=["fast", "sensing", "sensing_ri"], default="sensing_ri",
                   help="nominal model whose gap is diagnosed (default sensing_ri)")
    s.set_defaults(fn=_scenario)
    g = sub.add_parser("aggregate", help="scores from scenario JSON files", description="scores from scenario JSON files", allow_abbrev=False)
    g.add_argument("files", nargs="+", help="case record JSON files written by 'gap scenario'")
    g.add_argument("--out", required=True, help="output folder for the scores")
    g.set_defaults(fn=_aggregate)
    c = sub.add_parser("calibrate", help="null-calibrated thresholds", description="null-calibrated thresholds", allow_abbrev=False)
    c.add_argument("--n", type=int, default=20, help="number of effect-free (null) cases (default 20)")
    c.add_argument("--seed", type=int, default=1, help="seed of the null cases (default 1)")
    c.add_argument("--tier", choices=["fast", "full"], default="fast", help="scenario length and detail (default fast)")
    c.add_argument("--out", required=True, help="output thresholds JSON file")
    c.add_argument("--sim", choices=["device", "toy"], default="device", help="simulator of the null cases (default device)")
    c.add_argument("--estimator", choices=["fast", "sensing", "sensing_ri"], default="sensing_ri",
                   help="nominal model whose thresholds are calibrated (default sensing_ri)")
    c.add_argument("--jobs", type=int, default=1, help="worker processes (results do not depend on it)")
    c.set_defaults(fn=_calibrate)
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
