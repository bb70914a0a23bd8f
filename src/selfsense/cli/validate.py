"""``selfsense validate DATASET_DIR``: check a raw dataset against the contract (docs/data_format.md).

Exit 0 and one OK line for a valid dataset; otherwise exit 1 and one line per problem (on stdout).
Physical plausibility warnings (``selfsense.io.plausibility``) are printed as ``warning: ...`` lines and do not
change the exit code. Exit 2 for a usage error.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from selfsense.io.dataset import _dataset_problems


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="selfsense validate", description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("dataset_dir", nargs="+", help="dataset folder(s), e.g. data/raw/tweezer_sim")
    ap.add_argument("--metrics", action="store_true",
                    help="also print each trial's plausibility metrics (to set rig.yaml plausibility: limits)")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    rc = 0
    for dd in args.dataset_dir:
        d = Path(dd)
        if args.metrics:
            _print_metrics(d)
        warns: list = []
        rig, trials, probs, n_samples = _dataset_problems(d, warns, pipeline=True)
        for w in warns:
            print(f"warning: {d}/{w}")
        if probs:
            rc = 1
            for p in probs:
                print(f"{d}/{p}" if not str(p).startswith(str(d)) else str(p))
            print(f"FAILED {d}: {len(probs)} problem{'s' if len(probs) != 1 else ''}", file=sys.stderr)
        else:
            ncal = int((trials["role"] == "calibration").sum())
            print(f"OK {d}: dataset {rig.dataset!r}, {len(trials)} trials ({ncal} calibration, "
                  f"{len(trials) - ncal} validation), {n_samples} samples at {rig.sample_rate_hz:g} Hz")
    return rc


def _print_metrics(d: Path) -> None:
    """One line per trial: the quantities the plausibility checks compare with their limits."""
    from selfsense.io.logs import check_log
    from selfsense.io.plausibility import check_plausibility
    from selfsense.io.rig import check_rig
    from selfsense.io.trials import check_trials

    rig, _ = check_rig(d)
    trials, _ = check_trials(d)
    if rig is None or trials is None:
        return
    for rec in trials.to_dict("records"):
        df, probs = check_log(d / rec["file"], rig, rec["reference"], name=rec["file"])
        if df is None or probs:
            continue
        m: dict = {}
        check_plausibility(df, rig, rec, rec["file"], metrics=m)
        print(f"metrics {rec['trial']}: " + " ".join(f"{k}={v:.4g}" for k, v in sorted(m.items())))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
