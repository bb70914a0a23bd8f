"""Validation errors by drive coverage: how the Table 3 error of the cross-device benchmark's validation trials differs
between trials whose drive the calibration covers and trials that rely on features it lacks (docs/method.md 9).

    python benchmarks/coverage_errors.py benchmarks/cross_device/whole_device/current_fresh100 [MORE ...] --out X.md

Reads the device records (``records/*.json``, written by ``selfsense devices bench`` since the records carry
``per_trial_pct``; a record without it is counted as skipped) and computes each device's coverage again with the
current definitions (:func:`selfsense.report.coverage.coverage_table` on the device simulated again from its record:
family, preset, seed, protocol, randomisation, overrides, effects removed), so that records made before a change of
the definitions are read with today's. Per preset and measurement:
the validation trials the calibration covers, those that lack anything, and those that lack each feature, with the
number of trials and the median of their per-trial error (% of the trial's reference range). A description of the
runs: the coverage is computed from V, q and the relay only, and nothing here is fitted.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _measurement(trial: str) -> str:
    """The benchmark's validation trials are named ``val_disp_*`` and ``val_force_*`` (selfsense.sim.families)."""
    return "displacement" if trial.startswith("val_disp") else "force"


def coverage_of(r: dict) -> dict:
    """trial -> ``lacks`` of the device of record ``r``, simulated again (the same device, drives and noise)."""
    from selfsense.devices import device_scenario, simulate_device
    from selfsense.report.coverage import coverage_table

    overrides = {k[len("override_"):]: v for k, v in r.items() if k.startswith("override_")}
    without = tuple(x for x in str(r.get("without", "")).split(",") if x)
    sc = device_scenario(r["family"], r["preset"], int(r["seed"]), r.get("protocol", "three_trial"),
                         r.get("randomise", "hysteresis"), overrides or None, without)
    sigs, meta, _, _ = simulate_device(sc)
    cov = coverage_table(sigs, meta.reset_index())
    return {row.trial: row.lacks for row in cov.itertuples()}


def collect(folders: list[Path]) -> tuple[dict, int, int]:
    """``{(preset, measurement, group): [errors]}``, devices read, devices skipped (no per-trial errors)."""
    groups: dict = {}
    n = skipped = 0
    for folder in folders:
        for p in sorted((folder / "records").glob("*.json")):
            r = json.loads(p.read_text())
            if r.get("status") != "ok":
                continue
            err = r.get("per_trial_pct")
            if not isinstance(err, dict):
                skipped += 1
                continue
            lacks = coverage_of(r)
            n += 1
            for t, pct in err.items():
                feats = [k for k in str(lacks.get(t, "")).split(";") if k]
                key = (r["preset"], _measurement(t))
                for g in (["covered"] if not feats else ["lacking anything"] + feats):
                    groups.setdefault(key + (g,), []).append(float(pct))
    return groups, n, skipped


def table(groups: dict) -> str:
    from selfsense.report.coverage import FEATURES

    order = ["covered", "lacking anything"] + list(FEATURES)
    words = {"covered": "covered by the calibration", "lacking anything": "lacking any feature",
             **{k: f"with {v}" for k, v in FEATURES.items()}}
    lines = ["| preset | validation trials | displacement: trials, median % | force: trials, median % |",
             "|---|---|---|---|"]
    for preset in sorted({k[0] for k in groups}):
        for g in order:
            cells = []
            for m in ("displacement", "force"):
                v = groups.get((preset, m, g), [])
                cells.append(f"{len(v)}, {np.median(v):.2f}" if v else "0, -")
            if any(not c.startswith("0,") for c in cells):
                lines.append(f"| {preset} | {words[g]} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path, help="benchmark folders with records/*.json")
    ap.add_argument("--out", type=Path, default=None, help="also write the Markdown here")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "src"))
    groups, n, skipped = collect(a.folders)
    if not n:
        print("coverage_errors: no record with coverage_lacks and per_trial_pct in "
              + ", ".join(str(f) for f in a.folders), file=sys.stderr)
        return 2
    text = (f"# Validation errors by drive coverage\n\nCommand: `python benchmarks/coverage_errors.py "
            f"{' '.join(str(f) for f in a.folders)}`\n\n{n} devices ({skipped} records without per-trial errors skipped; coverage computed again). "
            "Per-trial Table 3 error (% of the trial's reference range) of the validation trials, by what their "
            "drive relies on that the calibration trials lack (docs/method.md 9; a trial lacking several features "
            "counts in each of their rows).\n\n" + table(groups))
    print(text)
    if a.out:
        from selfsense.io import write_text_atomic

        write_text_atomic(text, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
