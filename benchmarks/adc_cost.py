"""What the ADC costs the whole-device benchmark, and whether the charge-resolution check names it.

Compares two record folders of ``selfsense devices bench`` on the same devices (family, preset, seed): one with
the drawn ADC resolution (12-18 bits) and one with ``--set adc_bits=N``. For every device it also simulates the
drawn dataset again (no fit) and runs the reference-free charge-resolution check
(:func:`selfsense.chain.charge.charge_resolution`) on its calibration trials: whether the shunt channel is dithered,
and the charge error in volts of the H(q) target ``V - Q / (n_A C_p)`` (catalog ``C_p``).

    python benchmarks/adc_cost.py --native benchmarks/cross_device/whole_device/thesis_relay_fix \
        --fine benchmarks/cross_device/whole_device/thesis_adc18 --jobs 2 \
        --out benchmarks/cross_device/whole_device/thesis_adc18/adc_cost.md

``--native`` takes several folders where the drawn-ADC records of the devices are spread over them (a device held by
several is taken from a folder where it was scored, the later one if in several).
"""
from __future__ import annotations

import argparse
import glob
import json
import shlex
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
from _records import DEVICE_KEYS, one_per_device  # noqa: E402  (benchmarks/ is on sys.path when run as a script)


def _records(folder: str) -> pd.DataFrame:
    recs = [json.loads(Path(p).read_text()) for p in sorted(glob.glob(str(Path(folder) / "records" / "*.json")))]
    if not recs:
        raise SystemExit(f"{folder}: no records/*.json")
    return pd.DataFrame(recs)


def _resolution(args) -> dict:
    """Charge resolution of one drawn device's calibration trials (thesis protocol), reference-free, no fit."""
    family, preset, seed = args
    from selfsense import io as sio
    from selfsense.chain.charge import charge_resolution
    from selfsense.signals import prepare_trial
    from selfsense.sim.families import draw_device
    from selfsense.sim.simulate import simulate_dataset

    sc = draw_device(family, seed, preset, randomise="device")
    sc["trials"] = [t for t in sc["trials"] if not (t["role"] == "calibration" and t.get("signal") == "mixed")]
    with tempfile.TemporaryDirectory(prefix="selfsense-adc-") as tmp:
        ds = Path(tmp) / sc["name"]
        simulate_dataset(sc, out_dir=ds, truth_dir=Path(tmp) / (sc["name"] + ".truth"), contributions=False)
        rig = sio.load_rig(ds)
        meta = sio.load_trials(ds)
        n_a = float(rig.n_actuators)
        cp = float(rig.actuator_catalog["capacitance_f"]) if isinstance(rig.actuator_catalog, dict) else float(
            rig.actuator_catalog.capacitance_f)
        slope = 1.0 / (n_a * cp)
        sig, dith = [], []
        for t in meta.loc[meta["role"] == "calibration", "trial"]:
            res, _ = charge_resolution(prepare_trial(sio.trial_signals(ds, t, rig=rig), rig), rig.shunt_resistance_ohm)
            sig.append(res.sigma_q_rms_c)
            dith.append(res.dithered)
    return {"family": family, "preset": preset, "seed": seed, "dithered": bool(all(dith)),
            "h_target_v": float(slope * np.sqrt(np.mean(np.square(sig))))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--native", required=True, nargs="+", action="extend",
                    help="records with the drawn ADC resolution (one folder or several: a device several hold is "
                         "taken from one where it was scored, e.g. again after a fix, the later one if in several)")
    ap.add_argument("--fine", required=True, help="records of the same devices with --set adc_bits=N")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", required=True, help="markdown file to write")
    a = ap.parse_args(argv)
    from selfsense.determinism import single_thread_blas

    single_thread_blas()   # one BLAS thread per process and its workers, as the selfsense command runs
    key = list(DEVICE_KEYS)
    # a device held by several folders: its scored record (status ok) first, then the later folder's
    nat = one_per_device(_records(f) for f in a.native)
    fine = _records(a.fine)
    bits = sorted({int(b) for b in fine.get("override_adc_bits", pd.Series(dtype=float)).dropna()})
    m = nat.merge(fine, on=key, suffixes=("", "_fine"))
    if m.empty:
        raise SystemExit("no device in both folders")
    with ProcessPoolExecutor(max(1, a.jobs)) as ex:
        res = pd.DataFrame(list(ex.map(_resolution, [tuple(r) for r in m[key].itertuples(index=False)])))
    m = m.merge(res, on=key)
    lines = [f"# What the ADC costs (whole-device randomisation, thesis protocol)\n",
             f"Command: `python benchmarks/adc_cost.py --native {shlex.join(a.native)} --fine {a.fine} --jobs {a.jobs} "
             f"--out {a.out}`\n",
             f"Table 3 of the same devices, drives and noise with their drawn ADC "
             f"({', '.join(f'`{f}`' for f in a.native)}) and with "
             f"{'/'.join(map(str, bits)) or '?'} bits (`{a.fine}`); the charge-resolution check "
             "(`selfsense.chain.charge.charge_resolution`, reference-free, on the calibration trials of the drawn "
             "dataset): dithered or not, and the charge error in volts of the H(q) target (1 SD, RMS).\n",
             "| family | preset | devices | drawn ADC: displacement / force median % | finer ADC: median % | "
             "devices not dithered |", "|---|---|---|---|---|---|"]
    for (fam, pre), g in m.groupby(["family", "preset"]):
        lines.append(f"| {fam} | {pre} | {len(g)} | {g['displacement_pct'].median():.2f} / {g['force_pct'].median():.2f} "
                     f"| {g['displacement_pct_fine'].median():.2f} / {g['force_pct_fine'].median():.2f} "
                     f"| {int((~g['dithered']).sum())} |")
    lines += ["", "By what the check says (all families and presets):", "",
              "| charge-resolution check | devices | drawn ADC: displacement / force median % | finer ADC: median % | "
              "median ratio drawn / finer (displacement) |", "|---|---|---|---|---|"]
    for lab, g in (("dithered (resolved)", m[m["dithered"]]), ("not dithered", m[~m["dithered"]])):
        if g.empty:
            continue
        ratio = np.median(g["displacement_pct"] / g["displacement_pct_fine"])
        lines.append(f"| {lab} | {len(g)} | {g['displacement_pct'].median():.2f} / {g['force_pct'].median():.2f} | "
                     f"{g['displacement_pct_fine'].median():.2f} / {g['force_pct_fine'].median():.2f} | {ratio:.2f} |")
    nd = m[~m["dithered"]]
    if len(nd) >= 3:
        from scipy.stats import spearmanr

        cost = nd["displacement_pct"] - nd["displacement_pct_fine"]
        rho, p = spearmanr(nd["h_target_v"], cost)
        lines += ["", f"Among the {len(nd)} devices whose channel is not dithered, the charge error in volts of the H "
                      f"target against the displacement points the finer ADC gives back: Spearman rho = {rho:.2f} "
                      f"(p = {p:.2g})."]
    lines += ["", "Per device:", "",
              "| family | preset | seed | ADC bits | dithered | H-target error V | displacement % drawn / finer | "
              "force % drawn / finer |", "|---|---|---|---|---|---|---|---|"]
    for r in m.sort_values(key).itertuples():
        lines.append(f"| {r.family} | {r.preset} | {r.seed} | {int(r.device_adc_bits)} | {'yes' if r.dithered else 'no'} "
                     f"| {r.h_target_v:.3g} | {r.displacement_pct:.2f} / {r.displacement_pct_fine:.2f} "
                     f"| {r.force_pct:.2f} / {r.force_pct_fine:.2f} |")
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines[:20]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
