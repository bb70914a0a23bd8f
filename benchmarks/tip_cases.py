"""Chosen cases of the gap diagnostic's tip tier, scored again with the current code: the named effect's predicted tip
shrink against the true one (the case's Table 3 minus that of its effect-free twin: same device, drive and noise; for
the amplifier's limits, since 2026-12-04, the true shrink is from the excitation-matched twin, the twin driven with the
voltage the case's amplifier applied, ``selfsense.gap.blind.matched_twin_error``; the "effect-free twin" and "cost"
columns stay the effect-free twin's).

    python benchmarks/tip_cases.py --seed 4711 --cases 60,44,12,38,66,43,13,5,70 --jobs 2 \\
        --out benchmarks/gap_tip/amplifier_member.md

Each finished case is appended to ``<out>.partial.jsonl`` at once; a run stopped part-way (or with a failed case)
and started again with the same ``--out`` and the same code runs only the cases missing there. A completed run
deletes the file, so a later run (after a code change, say) computes every case again.

Used to rescore one effect family after a change made for it (here: the amplifier member of the voltage link) without
rerunning the whole campaign (``selfsense gap blind --tip``); the cases are those the campaign drew for that family, so
the numbers sit beside the campaign's own records (``benchmarks/gap_tip/tip_cases.jsonl.gz``).
"""
from __future__ import annotations

import argparse
import gzip
import json
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _one(args):
    from selfsense.gap.blind import run_tip_case

    i, seed = args
    return run_tip_case(i, seed)


def _run_cases(cases: list[int], seed: int, jobs: int, partial: Path) -> list[dict]:
    """The records of ``cases``, in their order. Each record is appended to ``partial`` (one JSON line) as soon as
    its case is done, so that a run stopped part-way keeps the cases it finished; a later run with the same ``--out``
    takes the records of this seed found there instead of running those cases again (every case is a deterministic
    function of (case, seed), so a record kept is the one a new run would make)."""
    done: dict[int, dict] = {}
    if partial.exists():
        for line in partial.read_text().splitlines():
            try:
                r = json.loads(line)
            except json.JSONDecodeError:   # a line cut off where the run was stopped: that case runs again
                continue
            if r["seed"] == seed and r["case"] in cases:
                done[r["case"]] = r
        if done:
            print(f"tip_cases: {len(done)} cases taken from {partial}", file=sys.stderr)
    todo = list(dict.fromkeys(i for i in cases if i not in done))   # a case given twice runs once
    if todo:
        partial.parent.mkdir(parents=True, exist_ok=True)
        cut = partial.exists() and partial.stat().st_size and not partial.read_bytes().endswith(b"\n")
        failed = []
        with ProcessPoolExecutor(max_workers=max(1, jobs)) as ex, open(partial, "a") as fh:
            if cut:   # the line cut off stays a line of its own
                fh.write("\n")
            futs = {ex.submit(_one, (i, seed)): i for i in todo}
            for f in as_completed(futs):
                try:
                    r = f.result()
                except Exception as exc:   # noqa: BLE001 -- the other cases are still kept; raised below
                    failed.append((futs[f], exc))
                    continue
                done[r["case"]] = r
                fh.write(json.dumps(r, default=float, sort_keys=True) + "\n")
                fh.flush()
        if failed:
            case, exc = min(failed, key=lambda x: x[0])
            raise RuntimeError(f"tip_cases: {len(failed)} case(s) failed ({', '.join(str(c) for c, _ in failed)}); "
                               f"the others are kept in {partial}") from exc
    return [done[i] for i in cases]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=4711)
    ap.add_argument("--cases", required=True, help="comma-separated case indices of the tip campaign")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--campaign", default=str(ROOT / "benchmarks" / "gap_tip" / "tip_cases.jsonl.gz"),
                    help="the campaign's records, for the 'before this change' columns")
    ap.add_argument("--out", required=True)
    ap.add_argument("--records", help="write the tables from these records (a previous run's .jsonl.gz) instead of "
                                      "running the cases again")
    a = ap.parse_args(argv)
    from selfsense.determinism import single_thread_blas

    single_thread_blas()   # one BLAS thread per process and its workers, as the selfsense command runs
    cases = [int(x) for x in a.cases.split(",")]
    old = {}
    if Path(a.campaign).exists():
        with gzip.open(a.campaign, "rt") as fh:
            old = {r["case"]: r for r in map(json.loads, fh) if r["seed"] == a.seed}
    if a.records:
        with gzip.open(a.records, "rt") as fh:
            recs = [r for r in map(json.loads, fh) if r["case"] in cases]
    else:
        recs = _run_cases(cases, a.seed, a.jobs, Path(a.out).with_suffix(".partial.jsonl"))
    from selfsense.gap.blind import _truth

    rows = ["| case | family | effect | named top-1 | Table 3 mean, case [points] | effect-free twin | cost (case - "
            "twin) | true shrink from the prediction's base | predicted shrink (90 % interval) | relative error | "
            "campaign record: predicted / true |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    errs = []
    for r in recs:
        e = next(iter(r["manifest"]["effects"]))
        p = r["predicted_shrink"].get(e)
        lo, hi = r["interval"].get(e, [float("nan")] * 2)
        t = _truth(r, e)
        rel = abs(p - t) / abs(t) if p is not None and t else float("nan")
        if p is not None and r["top"] == e:
            errs.append(rel)
        o = old.get(r["case"], {})
        op = (o.get("predicted_shrink") or {}).get(e)
        rows.append(f"| {r['case']} | {r['family']} | {e} | {r['top'] == e} | {r['before']:.2f} | "
                    f"{r['error_without']:.2f} | {r['true_shrink']:.2f} | {t:.2f} | "
                    + ("-" if p is None else f"{p:.2f} ({lo:.2f} to {hi:.2f})") + " | "
                    + ("-" if p is None else f"{rel:.2f}") + " | "
                    + (f"{op:.2f} / {o['true_shrink']:.2f}" if op is not None else "-") + " |")
    args = [x for x in (sys.argv[1:] if argv is None else argv)]
    if "--records" in args:   # the command that made the records, not the rewrite
        k = args.index("--records")
        del args[k:k + 2]
    cmd = "python benchmarks/tip_cases.py " + " ".join(args)
    cost_now = sorted(r["true_shrink"] for r in recs)
    cost_old = sorted(old[r["case"]]["true_shrink"] for r in recs if r["case"] in old)
    median = lambda v: float(statistics.median(v)) if v else float("nan")  # noqa: E731
    med = median(errs)
    text = (f"# Tip tier, chosen cases rescored\n\nCommand: `{cmd}` "
            f"({datetime.now(timezone.utc).strftime('%Y-%m-%d')})\n\n" + "\n".join(rows)
            + f"\n\nMedian relative error of the predicted shrink over the {len(errs)} cases named right: {med:.2f}. "
            "Where the default estimator already carries the member that models the named effect (adopted for "
            "Table 3), the prediction is the member's own contribution (Table 3 of the chain recalibrated without "
            "it, minus Table 3) and the truth is measured from the same base (the chain without it minus the twin); "
            "records written before 2026-11-26 predicted 0 there and are scored against the cost.\n\n"
            f"Cost of the effect (Table 3 mean of the case minus its effect-free twin, points): median "
            f"{median(cost_now):.2f}, mean {sum(cost_now) / max(len(cost_now), 1):.2f} over these {len(recs)} cases"
            + (f"; the campaign's own records of the same cases (made with the estimator of their date): median "
               f"{median(cost_old):.2f}, mean {sum(cost_old) / len(cost_old):.2f}" if cost_old else "") + ".\n")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(text)
    body = "".join(json.dumps(r, default=float, sort_keys=True) + "\n" for r in recs).encode()
    with open(Path(a.out).with_suffix(".jsonl.gz"), "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0) as fh:
        fh.write(body)
    # the run is complete: its records are in the outputs, and a later run (after a code change, say) starts afresh
    Path(a.out).with_suffix(".partial.jsonl").unlink(missing_ok=True)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
