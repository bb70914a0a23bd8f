"""``selfsense export``: every trial's results as MATLAB ``.mat`` and CSV with units (:mod:`selfsense.report.export`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from selfsense.report.export import export_trial

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="selfsense export", allow_abbrev=False,
                                 description="write each trial's results as .mat and .csv with units, sample rate, "
                                             "V, q, raw and post-processed estimates, coefficients and config")
    ap.add_argument("results", help="results folder of one dataset, e.g. results/tweezer_sim (after selfsense run)")
    ap.add_argument("dataset", help="its raw dataset folder, e.g. data/raw/tweezer_sim (rig.yaml, trials.csv)")
    ap.add_argument("--out", required=True, help="output folder (created): <trial>.mat and <trial>.csv")
    ap.add_argument("--trial", action="append", default=None,
                    help="trial to export (repeatable; default: every trial with results)")
    ap.add_argument("--format", choices=["mat", "csv", "both"], default="both", help="what to write (default both)")
    a = ap.parse_args(argv)
    res = Path(a.results)
    model = res / "model" / "sensing.json"
    if not model.is_file():
        raise FileNotFoundError(2, "No such file or directory (run 'selfsense run' first)", str(model))
    trials = a.trial or sorted(p.stem for p in (res / "internals").glob("*.parquet"))
    if not trials:
        raise ValueError(f"{res / 'internals'}: no trial results to export (run 'selfsense run' first)")
    out = Path(a.out)
    for t in trials:
        sig, internals = res / "signals" / f"{t}.parquet", res / "internals" / f"{t}.parquet"
        for p in (sig, internals):
            if not p.is_file():
                raise FileNotFoundError(2, f"No such file or directory (no results for trial {t!r})", str(p))
        paths = export_trial(a.dataset, t, sig, internals, model,
                             out / f"{t}.mat" if a.format in ("mat", "both") else None,
                             out / f"{t}.csv" if a.format in ("csv", "both") else None)
        for p in paths:
            print(f"wrote {p}")
    return 0
