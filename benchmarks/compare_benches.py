#!/usr/bin/env python
"""Two runs of the cross-device benchmark on the same devices, device by device: Table 3 medians per preset, the
devices better and worse, split by whether the shunt channel's noise dithers its ADC step, and the rule "the second
run where the channel is dithered, the first elsewhere".

    python benchmarks/compare_benches.py benchmarks/cross_device/whole_device/thesis_quantiser_bound \\
        benchmarks/cross_device/whole_device/offset_drift_on --out benchmarks/cross_device/whole_device/offset_drift_on/compare.md

Each argument is a folder written by ``selfsense devices bench`` (its ``records.csv``; the first run may be kept in
several, ``--first-also``); devices are matched on family,
preset and seed, and only the devices both runs scored are compared. "Dithered" is the record's
``charge_resolution_dx_pct == 0``: the estimator found the shunt channel dithered in every validation trial
(``selfsense.chain.charge.charge_resolution``, reference-free). "Better" / "worse": the displacement error moved by more
than 0.01 points.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

if str(Path(__file__).resolve().parent) not in sys.path:   # loaded by path (the tests), not run as a script
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import DEVICE_KEYS, one_per_device  # noqa: E402

KEYS = list(DEVICE_KEYS)


def _records(dirs) -> pd.DataFrame:
    """The records of one run kept in several folders (:func:`_records.one_per_device`: a device several hold is taken
    from one where it was scored, the later folder where more than one did)."""
    return one_per_device(pd.read_csv(Path(d) / "records.csv") for d in dirs)


def compare(base_dir, other_dir: str | Path) -> pd.DataFrame:
    """One row per device both runs scored: the two Table 3 errors and the dithered flag. ``base_dir``: a folder or
    a list of folders holding the first run (:func:`_records`)."""
    cols = KEYS + ["displacement_pct", "force_pct", "charge_resolution_dx_pct"]
    a = _records([base_dir] if isinstance(base_dir, (str, Path)) else list(base_dir))[cols]
    b = pd.read_csv(Path(other_dir) / "records.csv")[cols]
    m = a.merge(b, on=KEYS, suffixes=("_base", "_other"))
    m["dithered"] = m["charge_resolution_dx_pct_other"] == 0
    return m.sort_values(KEYS).reset_index(drop=True)


def _line(label: str, d: pd.DataFrame) -> str:
    if d.empty:
        return f"| {label} | 0 | | | | |"
    dd = d["displacement_pct_other"] - d["displacement_pct_base"]
    return (f"| {label} | {len(d)} | {d['displacement_pct_base'].median():.2f} / {d['force_pct_base'].median():.2f} | "
            f"{d['displacement_pct_other'].median():.2f} / {d['force_pct_other'].median():.2f} | "
            f"{int((dd < -0.01).sum())} / {int((dd > 0.01).sum())} |")


def markdown(m: pd.DataFrame, base_dir, other_dir) -> str:
    out = [f"Devices scored by both `{base_dir}` (first) and `{other_dir}` (second); displacement / force median %.",
           "", "| devices | n | first | second | displacement better / worse with the second |", "|---|---|---|---|---|"]
    for preset, g in m.groupby("preset"):
        out.append(_line(f"{preset}", g))
        out.append(_line(f"{preset}, dithered channel", g[g["dithered"]]))
        out.append(_line(f"{preset}, undithered channel", g[~g["dithered"]]))
    out += ["", "The second run where the channel is dithered, the first elsewhere:", "",
            "| preset | n | displacement / force median % |", "|---|---|---|"]
    for preset, g in m.groupby("preset"):
        d = g["displacement_pct_other"].where(g["dithered"], g["displacement_pct_base"])
        f = g["force_pct_other"].where(g["dithered"], g["force_pct_base"])
        out.append(f"| {preset} | {len(g)} | {d.median():.2f} / {f.median():.2f} |")
    out += ["", "| family | preset | seed | dithered | first: displacement / force % | second |", "|---|---|---|---|---|---|"]
    for _, r in m.iterrows():
        out.append(f"| {r['family']} | {r['preset']} | {r['seed']} | {'yes' if r['dithered'] else 'no'} | "
                   f"{r['displacement_pct_base']:.2f} / {r['force_pct_base']:.2f} | "
                   f"{r['displacement_pct_other']:.2f} / {r['force_pct_other']:.2f} |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("first", help="a `selfsense devices bench` folder (its records.csv)")
    ap.add_argument("second", help="another one, on (some of) the same devices")
    ap.add_argument("--first-also", action="append", default=[], metavar="DIR",
                    help="another folder of the first run (repeatable): a device several folders hold is taken from "
                         "one where it was scored, the later folder where more than one did")
    ap.add_argument("--out", default=None, help="also write the Markdown here")
    a = ap.parse_args(argv)
    first = [a.first] + list(a.first_also)
    m = compare(first, a.second)
    if m.empty:
        print(f"compare_benches: no device is scored in both {a.first} and {a.second}", file=sys.stderr)
        return 2
    text = markdown(m, "`, `".join(first), a.second)
    print(text, end="")
    if a.out:
        Path(a.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
