"""Pool tip-tier records of one seed made in parts (``selfsense gap blind --tip`` for cases 0..n-1, then
``benchmarks/tip_cases.py`` for the cases after them) into one tier: the records sorted by case, scored as
``selfsense gap blind --tip --n N`` scores its own (``selfsense.gap.blind.score_tip``, ``write_tip_scores``).

    python benchmarks/tip_pool.py --records benchmarks/gap_tip/seed_20261217/tip_cases.jsonl.gz \\
        part2.jsonl.gz --out benchmarks/gap_tip/seed_20261217_160 --command "..."

Every case of the seed is a deterministic function of (case, seed) (:func:`selfsense.gap.blind.run_tip_case`), so the
pooled records are those one campaign of N cases would write. Refuses records of different seeds, a case twice, or
cases that do not run 0..N-1 without a gap.
"""
from __future__ import annotations

import argparse
import gzip
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", nargs="+", required=True, help="tip records (.jsonl.gz), one file per part")
    ap.add_argument("--out", required=True, help="folder for tip_cases.jsonl.gz, tip_scores.json, tip_scores.md")
    ap.add_argument("--command", required=True, help="the commands that made the parts (written into tip_scores.md)")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "src"))
    from selfsense.gap.blind import _write_records, score_tip, write_tip_scores

    recs = [json.loads(line) for f in a.records for line in gzip.open(f, "rt") if line.strip()]
    seeds = {r["seed"] for r in recs}
    if len(seeds) != 1:
        raise SystemExit(f"tip_pool: records of several seeds {sorted(seeds)}")
    cases = sorted(r["case"] for r in recs)
    if cases != list(range(len(cases))):
        raise SystemExit(f"tip_pool: the cases must run 0..{len(cases) - 1} once each (found {len(cases)} records, "
                         f"{len(set(cases))} distinct, largest {cases[-1]})")
    recs.sort(key=lambda r: r["case"])
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    _write_records(out / "tip_cases.jsonl.gz", recs)   # the bytes a campaign writes (gzip mtime 0, sorted keys)
    sc = score_tip(recs)
    sc["seconds"] = float(sum(r.get("seconds", 0.0) for r in recs))
    write_tip_scores(recs, sc, out, a.command)
    print(f"{len(recs)} tip cases of seed {seeds.pop()}: median tip shrink error {sc['median_tip_shrink_error']:.3f} "
          f"over {sc['n_scored']}, coverage {sc['interval_coverage']:.2f} -> {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
