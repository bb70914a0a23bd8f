#!/usr/bin/env python
"""What the calibration alone says about a device's Table 3: the error of H(q) through A2 and B22
(``fit_report_["h_error_cost"]``, docs/method.md 6g) and the charge resolution of the shunt channel
(``fit_report_["charge_resolution"]``, docs/method.md 1b), against the Table 3 each device scored.

    python benchmarks/error_causes.py benchmarks/cross_device/whole_device/fold_starts_fresh42 \
        --out benchmarks/cross_device/whole_device/fold_starts_fresh42/error_causes.md

Reads ``records.csv`` of a ``selfsense devices bench`` folder (records made by a version that writes
``h_error_dx_pct``). Writes the devices sorted by their displacement error, the Spearman rank correlation of each
measure with Table 3 (both measures are made before any validation reference is read), and the ratio of each
device's Table 3 to the larger measure: an RMS error through a linear map on drives like the calibration's, against
the mean absolute error on drives the calibration may not have shown, so a floor, not a forecast.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import spearmanr


def table(df: pd.DataFrame) -> str:
    head = ("| family | preset | seed | displacement / force % | H(q) error through A2 / B22 % | charge resolution "
            "dx / f % | Table 3 / the larger measure (dx, f) |")
    lines = [head, "|---|---|---|---|---|---|---|"]
    for _, r in df.sort_values("displacement_pct", ascending=False).iterrows():
        lines.append(f"| {r['family']} | {r['preset']} | {int(r['seed'])} | {r['displacement_pct']:.2f} / "
                     f"{r['force_pct']:.2f} | {r['h_error_dx_pct']:.2f} / {r['h_error_f_pct']:.2f} | "
                     f"{r['charge_resolution_dx_pct']:.2f} / {r['charge_resolution_f_pct']:.2f} | {ratio(r, 'dx')}, "
                     f"{ratio(r, 'f')} |")
    return "\n".join(lines) + "\n"


def ratio(r, k: str) -> str:
    m = max(r[f"h_error_{k}_pct"], r[f"charge_resolution_{k}_pct"])
    return f"{r['displacement_pct' if k == 'dx' else 'force_pct'] / m:.1f}" if m > 0 else "-"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", help="selfsense devices bench output folders (records.csv)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    df = pd.concat([pd.read_csv(Path(f) / "records.csv") for f in a.folders], ignore_index=True)
    need = {"h_error_dx_pct", "h_error_f_pct", "charge_resolution_dx_pct", "charge_resolution_f_pct"}
    missing = sorted(need - set(df.columns))
    if missing:
        raise SystemExit(f"{', '.join(a.folders)}: records.csv lacks {missing}; rescore with the current version")
    df = df[df["status"] == "ok"].copy()
    for c in need:
        df[c] = df[c].fillna(0.0)
    rows = []
    for meas, col in (("displacement", "displacement_pct"), ("force", "force_pct")):
        k = "dx" if meas == "displacement" else "f"
        both = np.maximum(df[f"h_error_{k}_pct"], df[f"charge_resolution_{k}_pct"])
        for name, x in (("H(q) error through A2 / B22", df[f"h_error_{k}_pct"]),
                        ("charge resolution", df[f"charge_resolution_{k}_pct"]), ("the larger of the two", both)):
            rho, p = spearmanr(df[col], x)
            rows.append(f"| {meas} | {name} | {rho:.2f} | {p:.1e} |")
    rat = [max(r["h_error_dx_pct"], r["charge_resolution_dx_pct"]) for _, r in df.iterrows()]
    med = float(np.median(df["displacement_pct"] / np.maximum(rat, 1e-12)))
    text = (f"# What the calibration alone says about Table 3\n\n"
            f"Command: `python benchmarks/error_causes.py {' '.join(a.folders)} --out {a.out}`\n\n"
            f"{len(df)} devices. Spearman rank correlation of each calibration-time measure with the device's Table 3 "
            f"(validation trials):\n\n| Table 3 | measure | rho | p |\n|---|---|---|---|\n" + "\n".join(rows) + "\n\n"
            f"Median of displacement / the larger measure: {med:.2f}.\n\n" + table(df))
    Path(a.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
