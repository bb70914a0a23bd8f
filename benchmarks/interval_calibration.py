"""Calibration of the 90 % interval of "how far it shrinks" (``selfsense.gap.counterfactual.INTERVAL_UPPER_WIDEN``)
on the blind tip campaigns, and its coverage on records it was not calibrated on.

    python benchmarks/interval_calibration.py --out benchmarks/gap_tip/interval_calibration.md

The gap diagnostic's interval of a predicted tip shrink was a paired block bootstrap over the validation blocks: the
sampling spread of the recalibrated chain's change. It holds nothing of what the chain with the effect's model still
leaves of the effect, and the truths of the blind tip tier (the case's Table 3 minus its effect-free twin's) fell
outside it in a third of the cases, mostly above it. The interval is now ``[min(lo, p), p + c (hi - p)]`` for a
prediction ``p`` with bootstrap interval ``[lo, hi]`` (:func:`selfsense.gap.counterfactual.widened_interval`). ``c``
is set by split-conformal calibration on the scored cases (named top-1, a true shrink beyond 3 tip noise floors:
``selfsense.gap.blind._tip_scored``) of the calibration campaigns: the smallest factor that puts ``ceil(0.9 (n + 1))``
of the ``n`` truths inside, rounded up to 0.01. The lower side is the bootstrap's (never narrowed).

Reported: the factor, the coverage of the bootstrap and of the widened interval per calibration campaign, each
campaign scored with the factor calibrated on the others (leave-one-campaign-out), per effect family, the median
width relative to the truth, and the coverage on held-out records (``--held-out``: single-effect tip records of other
campaigns, e.g. a fresh seed; ``--joint``: joint records of ``benchmarks/tip_joint.py``, the "all together" interval).
Records written before the widening hold the bootstrap interval as ``interval`` (``shrink_all_interval_90``); later
ones hold it as ``interval_blocks`` (``shrink_all_interval_90_blocks``) beside the widened one.

    python benchmarks/interval_calibration.py --apply RECORDS_DIR --command "..." --out DIR

writes a campaign made before the widening as the current code writes it (widened intervals, scored again).
"""
from __future__ import annotations

import argparse
import gzip
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: the calibration campaigns: every blind tip campaign made with the stage chain's members (2026-12-03 on)
CALIBRATION = ("seed_20261213", "seed_20261214", "seed_20261216", "seed_20261217_160", "seed_20261218",
               "seed_20261219")
COVERAGE = 0.90


def _records(path: Path) -> list[dict]:
    f = path / "tip_cases.jsonl.gz" if path.is_dir() else path
    name = "joint_cases.jsonl.gz"
    if path.is_dir() and not f.exists() and (path / name).exists():
        f = path / name
    if not f.exists():
        raise SystemExit(f"interval_calibration: no records at {f}")
    return [json.loads(line) for line in gzip.open(f, "rt") if line.strip()]


def tip_cases(recs: list[dict], campaign: str, scored: bool = True) -> list[dict]:
    """Prediction, truth, bootstrap interval and effect of single-effect tip records: the cases the tip tier scores
    (named top-1, a true shrink beyond 3 tip noise floors), or with ``scored=False`` the cases named right whose truth
    is within 3 floors of 0 (not used to calibrate; their coverage says what the interval holds where the effect's
    tip consequence is noise)."""
    from selfsense.gap.blind import _tip_scored, _truth

    _, rows = _tip_scored(recs)
    out = []
    for r, x in zip(recs, rows):
        e = x["effect"]
        if not (x["scored"] if scored else (x["named"] and not x["scored"] and
                                            r["predicted_shrink"].get(e) is not None)):
            continue
        lo, hi = (r.get("interval_blocks") or r["interval"])[e]
        out.append({"campaign": campaign, "case": int(r["case"]), "effect": e, "pred": float(r["predicted_shrink"][e]),
                    "true": float(_truth(r, e)), "lo": float(lo), "hi": float(hi)})
    return out


def joint_cases(recs: list[dict], campaign: str) -> list[dict]:
    """The scored cases of joint records (benchmarks/tip_joint.py's rule: a true joint shrink beyond 3 floors)."""
    from selfsense.gap.blind import tip_noise_floor

    floor = tip_noise_floor(recs)
    out = []
    for r in recs:
        t = float(r["true_all_from_base"])
        if not abs(t) > 3.0 * floor:
            continue
        lo, hi = r.get("shrink_all_interval_90_blocks") or r["shrink_all_interval_90"]
        out.append({"campaign": campaign, "case": int(r["case"]), "effect": "all together",
                    "pred": float(r["shrink_all"]), "true": t, "lo": float(lo), "hi": float(hi)})
    return out


def inside(c: dict, upper: float) -> bool:
    from selfsense.gap.counterfactual import widened_interval

    lo, hi = widened_interval(c["pred"], [c["lo"], c["hi"]], upper)
    return bool(lo <= c["true"] <= hi)


def calibrate(cases: list[dict], coverage: float = COVERAGE) -> float:
    """The smallest upper factor (>= 1, rounded up to 0.01) that puts ceil(coverage (n + 1)) of the cases' truths
    inside the widened interval (split conformal); inf where the lower sides alone leave too many out."""
    n = len(cases)
    need = math.ceil(coverage * (n + 1))
    if need > n:
        return math.inf
    ok_low = [c["true"] >= min(c["lo"], c["pred"]) for c in cases]
    ups = sorted(0.0 if c["true"] <= c["pred"] else (c["true"] - c["pred"]) / max(c["hi"] - c["pred"], 1e-300)
                 for c, ok in zip(cases, ok_low) if ok)
    if len(ups) < need:
        return math.inf
    c = max(1.0, math.ceil(ups[need - 1] * 100.0) / 100.0)
    while sum(inside(x, c) for x in cases) < need:   # a product rounded below the score: the next hundredth
        c = round(c + 0.01, 2)
    return c


def width(c: dict, upper: float) -> float:
    from selfsense.gap.counterfactual import widened_interval

    lo, hi = widened_interval(c["pred"], [c["lo"], c["hi"]], upper)
    return (hi - lo) / abs(c["true"])


def report(calib: list[dict], held: dict[str, list[dict]], factor: float, commands: list[str]) -> str:
    from selfsense.gap.counterfactual import INTERVAL_UPPER_WIDEN

    f2 = lambda x: "-" if not np.isfinite(x) else f"{x:.2f}"  # noqa: E731
    cov = lambda cs, u: float(np.mean([inside(c, u) for c in cs])) if cs else float("nan")  # noqa: E731
    L = ["# The 90 % interval of \"how far it shrinks\": calibration on the blind tip campaigns", "",
         "Commands: " + "; ".join(f"`{c}`" for c in commands), "",
         f"Interval: `[min(lo, p), p + c (hi - p)]` around the prediction `p` with block-bootstrap interval `[lo, hi]`. "
         f"Calibrated factor `c` = **{factor:.2f}** over {len(calib)} scored cases of {len(CALIBRATION)} campaigns "
         f"(split conformal, {COVERAGE:.0%} of the truths inside); the code's `INTERVAL_UPPER_WIDEN` = "
         f"{INTERVAL_UPPER_WIDEN:.2f}. Pooled coverage: bootstrap {f2(cov(calib, 1.0))}, widened "
         f"{f2(cov(calib, factor))}; median width / |truth|: bootstrap "
         f"{f2(float(np.median([width(c, 1.0) for c in calib])))}, widened "
         f"{f2(float(np.median([width(c, factor) for c in calib])))}.", "",
         "## Per calibration campaign, and leave-one-campaign-out", "",
         "| campaign | scored cases | bootstrap coverage | widened coverage (pooled factor) | factor from the other "
         "campaigns | coverage with it |", "|---|---|---|---|---|---|"]
    for name in CALIBRATION:
        cs = [c for c in calib if c["campaign"] == name]
        rest = [c for c in calib if c["campaign"] != name]
        u = calibrate(rest)
        L.append(f"| {name} | {len(cs)} | {f2(cov(cs, 1.0))} | {f2(cov(cs, factor))} | {u:.2f} | {f2(cov(cs, u))} |")
    L += ["", "## Per effect family (calibration campaigns pooled)", "",
          "| effect family | scored cases | bootstrap coverage | widened coverage | factor from the other families | "
          "coverage with it |", "|---|---|---|---|---|---|"]
    for e in sorted({c["effect"] for c in calib}):
        cs = [c for c in calib if c["effect"] == e]
        u = calibrate([c for c in calib if c["effect"] != e])
        L.append(f"| {e} | {len(cs)} | {f2(cov(cs, 1.0))} | {f2(cov(cs, factor))} | {u:.2f} | {f2(cov(cs, u))} |")
    small = [c for name in CALIBRATION
             for c in tip_cases(_records(ROOT / "benchmarks" / "gap_tip" / name), name, scored=False)]
    if small:
        below = sum(c["true"] < min(c["lo"], c["pred"]) for c in small)
        L += ["", "## Where the truth is within noise (not calibrated on)", "",
              f"The same campaigns' {len(small)} cases named right whose true shrink lies within 3 tip noise floors of 0 "
              f"(not scored by the tip tier): bootstrap coverage {f2(cov(small, 1.0))}, widened {f2(cov(small, factor))}; "
              f"{below} truths below the lower side (the bootstrap's, not widened)."]
    if held:
        L += ["", "## Held-out records (not used to calibrate)", "",
              "| records | scored cases | bootstrap coverage | widened coverage | median width / \\|truth\\|, "
              "bootstrap / widened |", "|---|---|---|---|---|"]
        for name, cs in held.items():
            L.append(f"| {name} | {len(cs)} | {f2(cov(cs, 1.0))} | {f2(cov(cs, INTERVAL_UPPER_WIDEN))} | "
                     f"{f2(float(np.median([width(c, 1.0) for c in cs])) if cs else float('nan'))} / "
                     f"{f2(float(np.median([width(c, INTERVAL_UPPER_WIDEN) for c in cs])) if cs else float('nan'))} |")
    return "\n".join(L) + "\n"


def widen_records(recs: list[dict]) -> list[dict]:
    """Tip records written before the widening, as the current code writes them: the bootstrap intervals moved to
    ``interval_blocks`` / ``shrink_all_interval_90_blocks`` and the widened ones in their place (the widening reads
    only the prediction and the bootstrap interval, and the bootstrap draws the same numbers in the same order, so
    every other field is what the current code gives)."""
    from selfsense.gap.counterfactual import widened_interval

    out = []
    for r in recs:
        if "interval_blocks" in r:
            raise SystemExit(f"interval_calibration: case {r.get('case')} already holds widened intervals")
        r = dict(r)
        r["interval_blocks"] = r["interval"]
        r["interval"] = {e: widened_interval(r["predicted_shrink"][e], iv) for e, iv in r["interval_blocks"].items()}
        r["shrink_all_interval_90_blocks"] = r["shrink_all_interval_90"]
        r["shrink_all_interval_90"] = widened_interval(r["shrink_all"], r["shrink_all_interval_90_blocks"])
        out.append(r)
    return out


def apply(records: Path, out: Path, command: str) -> None:
    """Write ``records`` (a single-effect tip campaign made before the widening) with widened intervals, scored
    again, to ``out`` (tip_cases.jsonl.gz, tip_scores.json, tip_scores.md)."""
    from selfsense.gap.blind import _write_records, score_tip, write_tip_scores

    recs = widen_records(_records(records))
    out.mkdir(parents=True, exist_ok=True)
    _write_records(out / "tip_cases.jsonl.gz", recs)
    src = records / "tip_scores.json" if records.is_dir() else None
    sc = score_tip(recs)
    if src is not None and src.exists():
        sc["seconds"] = json.loads(src.read_text()).get("seconds")
    write_tip_scores(recs, sc, out, command)


def calibration_cases(root: Path = ROOT / "benchmarks" / "gap_tip") -> list[dict]:
    return [c for name in CALIBRATION for c in tip_cases(_records(root / name), name)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="markdown report")
    ap.add_argument("--held-out", nargs="*", default=[], help="single-effect tip records (folders or .jsonl.gz)")
    ap.add_argument("--joint", nargs="*", default=[], help="joint tip records (folders or .jsonl.gz)")
    ap.add_argument("--apply", default=None, help="instead: a single-effect tip campaign made before the widening "
                    "(folder), written with widened intervals to --out (a folder) and scored again")
    ap.add_argument("--command", default="", help="with --apply: the command that made the campaign (for its table)")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "src"))
    if a.apply:
        cmd = (f"{a.command}, intervals widened by python benchmarks/interval_calibration.py --apply {a.apply} "
               f"--out {a.out}")
        apply(Path(a.apply), Path(a.out), cmd.lstrip(", "))
        print(f"widened records and scores -> {a.out}")
        return 0
    calib = calibration_cases()
    factor = calibrate(calib)
    held = {}
    for p in a.held_out:
        held[f"{Path(p).name} (single effect)"] = tip_cases(_records(Path(p)), Path(p).name)
    for p in a.joint:
        held[f"{Path(p).name} (all together)"] = joint_cases(_records(Path(p)), Path(p).name)
    cmd = "python benchmarks/interval_calibration.py " + " ".join(
        ([f"--held-out {' '.join(a.held_out)}"] if a.held_out else []) + ([f"--joint {' '.join(a.joint)}"]
                                                                          if a.joint else []) + [f"--out {a.out}"])
    text = report(calib, held, factor, [cmd])
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
