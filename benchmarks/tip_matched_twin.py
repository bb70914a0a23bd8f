"""A tip-tier campaign's records scored again against the excitation-matched twin, predictions unchanged.

    python benchmarks/tip_matched_twin.py --records benchmarks/gap_tip/seed_20261213 \\
        --out benchmarks/gap_tip/seed_20261213_matched

For a case whose effect changes the voltage the actuators receive (``selfsense.gap.blind.EXCITATION_EFFECTS``: the
amplifier's current and slew limits), the truth of "how far it shrinks once modelled" is the Table 3 of the same
device and noise without the effect, driven with the voltage the case's amplifier applied
(``selfsense.gap.blind.matched_twin_error``); the effect-free twin the campaign recorded stays the effect's cost. This
script adds that twin to records written before it existed (``selfsense gap blind --tip`` records it since), and
writes the records and the tip scores to ``--out``. Only meaningful with the code the records were made with: the
predictions and the base are read from the records, the twin's Table 3 is computed now.
"""
from __future__ import annotations

import argparse
import gzip
import json
import sys
from pathlib import Path


def _matched(rec: dict) -> float:
    from selfsense.gap.blind import matched_twin_error
    from selfsense.sensing.estimator import SelfSensingEstimator, SensingConfig

    return matched_twin_error(rec["manifest"], lambda r: SelfSensingEstimator(config=SensingConfig(), rig=r))


def rescore(recs: list[dict], jobs: int = 1) -> list[dict]:
    """``recs`` with the matched twin added to every excitation-effect case that lacks it (a new list)."""
    from selfsense.gap.blind import EXCITATION_EFFECTS, set_model_truths
    from selfsense.parallel import fork_map

    todo = [i for i, r in enumerate(recs)
            if set(r["manifest"]["effects"]) & EXCITATION_EFFECTS and "error_without_matched" not in r]
    got = fork_map(_matched, [recs[i] for i in todo], jobs) if todo else []
    out = [dict(r) for r in recs]
    for i, e in zip(todo, got):
        out[i] = set_model_truths(out[i], e)
    return out


def main(argv=None) -> int:
    from selfsense.gap.blind import _write_records, score_tip, write_tip_scores

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", required=True, help="folder of a tip-tier campaign (tip_cases.jsonl.gz)")
    ap.add_argument("--out", required=True, help="folder for the rescored records and tip_scores.md / .json")
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args(argv)
    from selfsense.determinism import single_thread_blas

    single_thread_blas()   # one BLAS thread per process and its workers, as the selfsense command runs
    src, out = Path(a.records), Path(a.out)
    if src.resolve() == out.resolve():
        sys.exit(f"tip_matched_twin.py: --out must differ from --records ({src}): the campaign's records are kept")
    with gzip.open(src / "tip_cases.jsonl.gz", "rt") as fh:
        recs = [json.loads(line) for line in fh]
    recs = rescore(recs, a.jobs)
    out.mkdir(parents=True, exist_ok=True)
    _write_records(out / "tip_cases.jsonl.gz", recs)
    sc = score_tip(recs)
    cmd = "python benchmarks/tip_matched_twin.py " + " ".join(argv if argv is not None else sys.argv[1:])
    write_tip_scores(recs, sc, out, cmd)
    print(f"{out / 'tip_scores.md'}: median shrink error {sc['median_tip_shrink_error']:.3f}, "
          f"coverage {sc['interval_coverage']:.2f} over {sc['n_scored']} scored cases")
    return 0


if __name__ == "__main__":
    sys.exit(main())
