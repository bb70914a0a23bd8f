"""Cross-device accuracy benchmark: thesis Table 3 on many virtual devices of several truth families.

One *device job* (:func:`run_device`) draws a device (:func:`selfsense.sim.families.draw_device`), simulates its
trials into a temporary dataset folder (the DATA_FORMAT contract, exactly what a user would record), runs the
pipeline's own stages in process (ingest -> H(q) calibration -> coefficient regression -> estimation -> scoring,
same configuration as ``config.yaml``) and returns one record: Table 3 on the validation trials, the selected
H(q) model and its fit diagnostics. :func:`aggregate` turns records into the per-family / per-preset table
(median and 90th percentile over devices). The command is ``selfsense devices``; the Snakemake target is
``cross_device`` (one job per device, ``workflow/rules/devices.smk``).

Nothing here is tuned to one family: every device family runs through the same configuration.
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np
import pandas as pd

__all__ = ["run_device", "aggregate", "aggregate_markdown", "DEFAULT_CONFIG"]

#: estimator configuration of the benchmark: the pipeline defaults (config.yaml ``calibration``/``estimation``)
DEFAULT_CONFIG: dict = {"calibration": {}, "estimation": {}}


def _default_pipeline_config() -> dict:
    """The ``calibration`` and ``estimation`` blocks of the packaged default configuration (config.yaml)."""
    return {"calibration": {}, "estimation": {}}


def run_device(family: str, preset: str, seed: int, config: Mapping[str, Any] | None = None) -> dict:
    """Simulate one virtual device and score the pipeline's estimator on it (Table 3, validation trials)."""
    from selfsense import io as sio
    from selfsense.report import tables
    from selfsense.sensing import SelfSensingEstimator
    from selfsense.signals import prepare_trial
    from selfsense.sim.families import draw_device
    from selfsense.sim.simulate import simulate_dataset
    from selfsense.stages import sensing_config

    cfg = dict(config or _default_pipeline_config())
    sc = draw_device(family, seed, preset)
    rec: dict[str, Any] = {"family": family, "preset": preset, "seed": int(seed),
                           "n_actuators": sc["device"]["n_actuators"], "h_sign": sc["device"]["h_sign"],
                           "preload": sc["effects"].get("preload", 0.0)}
    with tempfile.TemporaryDirectory(prefix="selfsense-device-") as tmp:
        ds = Path(tmp) / sc["name"]
        simulate_dataset(sc, out_dir=ds, truth_dir=Path(tmp) / (sc["name"] + ".truth"), contributions=False)
        rig = sio.load_rig(ds)
        meta = sio.load_trials(ds).set_index("trial")
        try:
            sigs = {t: prepare_trial(sio.trial_signals(ds, t, rig=rig), rig) for t in meta.index}
        except sio.ContractError as exc:  # the generator made a dataset the contract rejects: a benchmark failure
            rec.update({"status": "invalid_dataset", "error": str(exc).splitlines()[0][-300:],
                        "displacement_pct": float("nan"), "force_pct": float("nan")})
            return rec
        try:
            est = SelfSensingEstimator(config=sensing_config(cfg), rig=rig).fit(sigs, meta)
        except Exception as exc:  # a failed calibration is a result of the benchmark, recorded as such
            rec.update({"status": "calibration_failed", "error": f"{type(exc).__name__}: {exc}",
                        "displacement_pct": float("nan"), "force_pct": float("nan")})
            return rec
        ests = {}
        for t, s in sigs.items():
            e = est.estimate(s)
            e["dx_ref"], e["f_ref"] = s["dx_ref"].to_numpy(), s["f_ref"].to_numpy()
            ests[t] = e
        pt = tables.per_trial_table(ests, meta.reset_index())
        t3 = tables.table3(pt).set_index("measurement")
    hrep = est.fit_report_.get("hysteresis", {})
    rec.update({
        "status": "ok",
        "displacement_pct": float(t3.loc["displacement", "percent_of_range"]),
        "force_pct": float(t3.loc["force", "percent_of_range"]),
        "h_model": str(hrep.get("h_model", "")),
        "h_selected": str(hrep.get("selected", hrep.get("h_model", ""))),
        "h_fit_rms_v": float(hrep.get("rms_v", float("nan"))),
        "warnings": list(est.fit_report_.get("warnings", [])),
    })
    return rec


def aggregate(records: Iterable[Mapping[str, Any]]) -> pd.DataFrame:
    """Median and 90th percentile over devices of Table 3 (% of range) per family and preset."""
    df = pd.DataFrame(list(records))
    rows = []
    for (fam, pre), g in df.groupby(["family", "preset"], sort=True):
        ok = g[g["status"] == "ok"]
        row = {"family": fam, "preset": pre, "n_devices": int(len(g)), "n_failed": int((g["status"] != "ok").sum())}
        for m in ("displacement", "force"):
            v = ok[f"{m}_pct"].to_numpy(dtype=float)
            row[f"{m}_median_pct"] = float(np.median(v)) if v.size else float("nan")
            row[f"{m}_p90_pct"] = float(np.percentile(v, 90)) if v.size else float("nan")
        rows.append(row)
    return pd.DataFrame(rows)


def aggregate_markdown(agg: pd.DataFrame, targets: Mapping[str, tuple[float, float]] | None = None) -> str:
    """The cross-device Table 3 as Markdown, with the issue's targets marked met / missed."""
    targets = targets or {"clean": (5.0, 8.0), "drift": (8.0, 12.0)}
    lines = ["| family | preset | devices (failed) | displacement median % | displacement p90 % | force median % | "
             "force p90 % | target median (disp / force) |", "|---|---|---|---|---|---|---|---|"]
    for _, r in agg.iterrows():
        td, tf = targets.get(r["preset"], (float("nan"), float("nan")))
        md = "met" if r["displacement_median_pct"] <= td else "missed"
        mf = "met" if r["force_median_pct"] <= tf else "missed"
        lines.append(f"| {r['family']} | {r['preset']} | {r['n_devices']} ({r['n_failed']}) | "
                     f"{r['displacement_median_pct']:.2f} | {r['displacement_p90_pct']:.2f} | "
                     f"{r['force_median_pct']:.2f} | {r['force_p90_pct']:.2f} | "
                     f"{td:g} / {tf:g}: {md} / {mf} |")
    for pre, g in agg.groupby("preset"):
        for m in ("displacement", "force"):
            v = g[f"{m}_median_pct"].to_numpy(dtype=float)
            if v.size and np.all(np.isfinite(v)):
                ratio = float(v.max() / max(v.min(), 1e-12))
                lines.append("")
                lines.append(f"{pre}, {m}: worst family / best family = {ratio:.2f} "
                             f"({'met' if ratio <= 2.0 else 'missed'}: target <= 2)")
    return "\n".join(lines) + "\n"


def write_record(rec: Mapping[str, Any], path: str | Path) -> None:
    from selfsense.io import write_text_atomic

    write_text_atomic(json.dumps(rec, indent=1, sort_keys=True, default=float) + "\n", path)
