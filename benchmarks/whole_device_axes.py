#!/usr/bin/env python
"""Which randomisation axis goes with the error: Spearman rank correlation of each device's Table 3 with each drawn
whole-device quantity, over the records of a ``selfsense devices bench --randomise device`` run.

    python benchmarks/whole_device_axes.py benchmarks/cross_device/whole_device/thesis

Writes ``axes.md`` into that folder (all families, and without the rate-dependent KP family).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import pandas as pd
from scipy.stats import spearmanr

AXES = ["device_sample_rate_hz", "device_adc_bits", "device_laser_noise_m", "device_amplifier_bandwidth_hz",
        "device_amplifier_limits", "device_dielectric_weight", "device_hold_s", "h_fit_rms_v"]


def main(folder: str) -> None:
    d = pd.read_csv(Path(folder) / "records.csv")
    d = d[d["status"] == "ok"]
    L = ["# Whole-device randomisation: which drawn quantity goes with the error", "",
         f"Command: `python benchmarks/whole_device_axes.py {folder}` ({time.strftime('%Y-%m-%d')}); records of "
         f"`{folder}/records.csv` ({len(d)} devices). Spearman rank correlation (p-value) of each device's Table 3 "
         "with the quantity; `h_fit_rms_v` is the selected H model's in-sample error, not a drawn quantity.", ""]
    for name, x in (("all families", d), ("without rate_kp", d[d["family"] != "rate_kp"])):
        L += [f"## {name} ({len(x)} devices)", "", "| quantity | displacement | force |", "|---|---|---|"]
        for c in AXES:
            r1, p1 = spearmanr(x[c], x["displacement_pct"])
            r2, p2 = spearmanr(x[c], x["force_pct"])
            L.append(f"| `{c}` | {r1:+.2f} ({p1:.3f}) | {r2:+.2f} ({p2:.3f}) |")
        L.append("")
    (Path(folder) / "axes.md").write_text("\n".join(L))
    print("\n".join(L))


if __name__ == "__main__":
    main(sys.argv[1])
