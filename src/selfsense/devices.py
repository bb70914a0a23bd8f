"""Cross-device accuracy benchmark: thesis Table 3 on many virtual devices of several truth families.

One *device job* (:func:`run_device`) draws a device (:func:`selfsense.sim.families.draw_device`), simulates its
trials into a temporary dataset folder (the data contract of docs/data_format.md, exactly what a user would record), runs the
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
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

__all__ = ["device_scenario", "simulate_device", "run_device", "aggregate", "aggregate_markdown", "bench",
           "write_tables", "PROTOCOLS"]


def _default_pipeline_config() -> dict:
    """Empty ``calibration`` / ``estimation`` blocks: the estimator's defaults, which are config.yaml's."""
    return {"calibration": {}, "estimation": {}}


#: calibration protocols: ``thesis`` calibrates on the free-tip sine and the blocked sine only, as the thesis does
#: (``000_18d138f03f1777c3.txt`` sec. 5.2: H(q) is calibrated on the sinusoidal input); ``three_trial`` adds a
#: free-tip mixed-drive calibration trial (minor loops and holds)
PROTOCOLS = ("thesis", "three_trial")


def device_scenario(family: str, preset: str, seed: int, protocol: str = "three_trial",
                    randomise: str = "hysteresis", device_overrides: Mapping[str, Any] | None = None,
                    without: Sequence[str] = ()) -> dict:
    """The scenario of one virtual device of the benchmark (:func:`selfsense.sim.families.draw_device`), with the
    ``device_overrides`` set after the draw and, on the ``thesis`` protocol, without the free-tip mixed calibration
    trial. ``without``: effects of the draw set to zero after it (the effect-free twin: the same device, drives and
    noise, the effect removed; a name that is no effect of the simulator is refused)."""
    from selfsense.sim.families import draw_device

    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol: expected one of {', '.join(PROTOCOLS)}, found {protocol!r}")
    check_without(without)   # before the draw, which simulates the free stroke
    sc = draw_device(family, seed, preset, randomise=randomise)
    unknown = sorted(set(device_overrides or {}) - set(sc["device"]))
    if unknown:
        raise ValueError(f"device_overrides: unknown device quantities {unknown}; expected some of "
                         f"{sorted(sc['device'])}")
    sc["device"].update(dict(device_overrides or {}))
    for k in without:   # an effect the draw does not have (e.g. leakage on the clean preset) is already zero
        if k in sc["effects"]:
            sc["effects"][k] = 0.0
    if protocol == "thesis":
        sc["trials"] = [t for t in sc["trials"] if not (t["role"] == "calibration" and t.get("signal") == "mixed")]
    return sc


def check_without(without: Sequence[str]) -> None:
    """Refuse a name of ``without`` that is no effect of the simulator (:data:`selfsense.sim.effects.EFFECTS`)."""
    from selfsense.sim.effects import EFFECTS

    unknown = sorted(set(without) - set(EFFECTS))
    if unknown:
        raise ValueError(f"without: unknown effects {unknown}; expected some of {', '.join(EFFECTS)}")


def simulate_device(sc: Mapping[str, Any], with_truth: bool = False) -> tuple[dict, pd.DataFrame, Any, dict | None]:
    """Simulate a device scenario (:func:`device_scenario`) into a temporary dataset and load it as the pipeline
    does: (prepared trials by id, trials.csv indexed by trial, rig, the simulator's truth per trial or None).
    Raises :class:`selfsense.io.ContractError` where the generated dataset breaks the data contract."""
    from selfsense import io as sio
    from selfsense.signals import prepare_trial
    from selfsense.sim.simulate import simulate_dataset

    with tempfile.TemporaryDirectory(prefix="selfsense-device-") as tmp:
        ds = Path(tmp) / sc["name"]
        truth_dir = Path(tmp) / (sc["name"] + ".truth")
        simulate_dataset(sc, out_dir=ds, truth_dir=truth_dir, contributions=False)
        rig = sio.load_rig(ds)
        meta = sio.load_trials(ds).set_index("trial")
        trials = {t: prepare_trial(sio.trial_signals(ds, t, rig=rig), rig) for t in meta.index}
        truth = ({t: pd.read_parquet(truth_dir / f"{t}.parquet") for t in meta.index} if with_truth else None)
    return trials, meta, rig, truth


def run_device(family: str, preset: str, seed: int, config: Mapping[str, Any] | None = None,
               protocol: str = "three_trial", randomise: str = "hysteresis",
               device_overrides: Mapping[str, Any] | None = None, members: Mapping[str, str] | None = None,
               without: Sequence[str] = ()) -> dict:
    """Simulate one virtual device and score the pipeline's estimator on it (Table 3, validation trials; the
    mixed-drive validation trials also on their own). ``device_overrides``: device quantities set after the draw
    (e.g. ``{"adc_bits": 18}``: the same device, drive and noise with a finer ADC), recorded as ``override_<name>``.
    ``members``: chain members forced on or off (``SelfSensingEstimator(members=...)``, e.g.
    ``{"offset_drift": "on"}``: what a member would give where the calibration's gate does not adopt it), recorded
    as ``member_<name>``. ``without``: effects of the draw removed (:func:`device_scenario`; the effect-free twin that
    measures an effect's cost), recorded as ``without``. The record also says which charge-link members the fit carries (``offset_drift``,
    ``leakage_ns``)."""
    from selfsense import io as sio
    from selfsense.report import tables
    from selfsense.sensing import SelfSensingEstimator
    from selfsense.stages import sensing_config

    from selfsense.sensing.estimator import member_modes

    member_modes(members)   # an unknown member or mode is refused here, not recorded as a failed calibration
    cfg = dict(config or _default_pipeline_config())
    sc = device_scenario(family, preset, seed, protocol, randomise, device_overrides, tuple(without))
    rec: dict[str, Any] = {"family": family, "preset": preset, "seed": int(seed), "protocol": protocol,
                           "randomise": randomise, **{f"device_{k}": v for k, v in sc.get("randomise", {}).items()},
                           "n_actuators": sc["device"]["n_actuators"], "h_sign": sc["device"]["h_sign"],
                           "preload": sc["effects"].get("preload", 0.0),
                           **{f"override_{k}": v for k, v in (device_overrides or {}).items()},
                           **{f"member_{k}": str(v) for k, v in (members or {}).items()},
                           **({"without": ",".join(sorted(without))} if without else {})}
    try:
        sigs, meta, rig, _ = simulate_device(sc)
    except sio.ContractError as exc:  # the generator made a dataset the contract rejects: a benchmark failure
        # the problems themselves (file, field, what was expected, what was found), not the message's first line:
        # that names only the temporary folder the dataset was simulated into
        rec.update({"status": "invalid_dataset", "error": "; ".join(str(p) for p in exc.problems)[:600],
                    "displacement_pct": float("nan"), "force_pct": float("nan")})
        return rec
    try:
        est = SelfSensingEstimator(config=sensing_config(cfg), rig=rig, members=dict(members or {})).fit(sigs, meta)
    except Exception as exc:  # a failed calibration is a result of the benchmark, recorded as such
        rec.update({"status": "calibration_failed", "error": f"{type(exc).__name__}: {exc}",
                    "displacement_pct": float("nan"), "force_pct": float("nan")})
        return rec
    ests = {}
    for t, s in sigs.items():
        e = est.estimate(s, trial=t)
        e["dx_ref"], e["f_ref"] = s["dx_ref"].to_numpy(), s["f_ref"].to_numpy()
        ests[t] = e
    pt = tables.per_trial_table(ests, meta.reset_index())
    t3 = tables.table3(pt).set_index("measurement")
    # the mixed-drive validation trials (minor loops and holds the sine calibration never shows) on their own
    mixed = pt[(pt["role"] == "validation") & (pt["signal"] == "mixed")]
    mixed_pct = {m: float(g["percent_of_range"].mean()) for m, g in mixed.groupby("measurement")}
    # which validation trials rely on drive features the calibration lacks (selfsense.report.coverage: V, q and the
    # relay only; read by no fit)
    from selfsense.report.coverage import coverage_table

    try:
        cov = coverage_table(sigs, meta.reset_index())
        lacks = {r.trial: r.lacks for r in cov.itertuples() if r.role == "validation"}
    except ValueError as exc:   # recorded, not a failed device: the scores above do not depend on it
        lacks = {"error": str(exc)}
    hrep = est.fit_report_.get("hysteresis", {})
    hcost = est.fit_report_.get("h_error_cost", {})
    rec.update({
        "status": "ok",
        "displacement_pct": float(t3.loc["displacement", "percent_of_range"]),
        "force_pct": float(t3.loc["force", "percent_of_range"]),
        "mixed_displacement_pct": mixed_pct.get("displacement", float("nan")),
        "mixed_force_pct": mixed_pct.get("force", float("nan")),
        "coverage_lacks": lacks,
        "per_trial_pct": {r.trial: float(r.percent_of_range) for r in pt.itertuples() if r.role == "validation"},
        "h_model": str(hrep.get("h_model", "")),
        "h_selected": str(hrep.get("selected", hrep.get("h_model", ""))),
        "h_fit_rms_v": float(hrep.get("rms_v", float("nan"))),
        "rest_offset": bool(est.fit_report_.get("rest_offset", {}).get("applied", False)),
        "charge_resolution_dx_pct": float(est.fit_report_.get("charge_resolution", {}).get("validation_dx_pct", 0.0)),
        "charge_resolution_f_pct": float(est.fit_report_.get("charge_resolution", {}).get("validation_f_pct", 0.0)),
        "charge_resolution_h_v": float(est.fit_report_.get("charge_resolution", {}).get("calibration_h_target_v", 0.0)),
        "h_error_v": _number(hcost.get("h_error_v")),
        "h_error_dx_pct": _number(hcost.get("dx_pct")),
        "h_error_f_pct": _number(hcost.get("f_pct")),
        "offset_drift": bool(est.offset_drift_),
        "leakage_ns": float(est.leakage_s_) * 1e9,
        "quantiser": bool((est.quantiser_ or {}).get("applied", False)),
        "quantiser_i_q_na": float((est.quantiser_ or {}).get("i_q_a", 0.0)) * 1e9,
        "stress": bool((est.stress_ or {}).get("applied", False)),
        "amplifier_lag_ms": (float((est.amplifier_lag_ or {}).get("tau_s", 0.0)) * 1e3
                             if (est.amplifier_lag_ or {}).get("applied") else 0.0),
        "regression": str(est.fit_report_.get("regression_form", "")),
        "warnings": list(est.fit_report_.get("warnings", [])),
    })
    return rec


def _number(v) -> float:
    """A fit-report number for a record: None (not assessed) as NaN, 0.0 kept."""
    return float("nan") if v is None else float(v)


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
        for m in ("displacement", "force"):
            col = f"mixed_{m}_pct"
            v = ok[col].to_numpy(dtype=float) if col in ok else np.array([])
            v = v[np.isfinite(v)]
            row[f"mixed_{m}_median_pct"] = float(np.median(v)) if v.size else float("nan")
        rows.append(row)
    return pd.DataFrame(rows)


def aggregate_markdown(agg: pd.DataFrame, targets: Mapping[str, tuple[float, float]] | None = None) -> str:
    """The cross-device Table 3 as Markdown, with the targets (median 5 / 8 % clean, 8 / 12 % drift) marked met / missed."""
    targets = targets or {"clean": (5.0, 8.0), "drift": (8.0, 12.0)}
    lines = ["| family | preset | devices (failed) | displacement median % | displacement p90 % | force median % | "
             "force p90 % | mixed-drive validation trials: displacement / force median % | target median (disp / force) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for _, r in agg.iterrows():
        td, tf = targets.get(r["preset"], (float("nan"), float("nan")))
        md = "met" if r["displacement_median_pct"] <= td else "missed"
        mf = "met" if r["force_median_pct"] <= tf else "missed"
        lines.append(f"| {r['family']} | {r['preset']} | {r['n_devices']} ({r['n_failed']}) | "
                     f"{r['displacement_median_pct']:.2f} | {r['displacement_p90_pct']:.2f} | "
                     f"{r['force_median_pct']:.2f} | {r['force_p90_pct']:.2f} | "
                     f"{r.get('mixed_displacement_median_pct', float('nan')):.2f} / "
                     f"{r.get('mixed_force_median_pct', float('nan')):.2f} | "
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


def _config_from(path: str | None) -> dict:
    if not path:
        return _default_pipeline_config()
    import yaml

    with open(path) as fh:
        cfg = yaml.safe_load(fh) or {}
    return {"calibration": dict(cfg.get("calibration", {}) or {}), "estimation": dict(cfg.get("estimation", {}) or {})}


def _job(args):
    family, preset, seed, cfg, out, protocol, randomise, overrides, members, without = args
    rec = run_device(family, preset, seed, cfg, protocol, randomise, overrides, members, without)
    write_record(rec, out)
    return rec


def bench(n: int, families, presets, jobs: int, out_dir: str | Path, config: Mapping[str, Any] | None = None,
          first_seed: int = 0, progress: bool = True, protocol: str = "three_trial",
          randomise: str = "hysteresis", device_overrides: Mapping[str, Any] | None = None,
          members: Mapping[str, str] | None = None, without: Sequence[str] = ()) -> pd.DataFrame:
    """Run ``n`` devices per family and preset (seeds first_seed..first_seed+n-1), ``jobs`` in parallel, one record
    file per device under ``out_dir/records`` (existing records are reused: resumable), then write
    ``cross_device.csv`` / ``cross_device.md`` / ``records.csv``. ``device_overrides``, ``members`` and ``without``:
    as :func:`run_device`, the same for every device (``without``: every effect named must be in every device's
    draw, e.g. the drift preset's leakage, offset_drift and creep)."""
    import os
    from concurrent.futures import ProcessPoolExecutor

    from selfsense.sensing.estimator import member_modes

    member_modes(members)   # before any device starts
    check_without(without)
    out_dir = Path(out_dir)
    rec_dir = out_dir / "records"
    rec_dir.mkdir(parents=True, exist_ok=True)
    todo, recs = [], []
    for fam in families:
        for pre in presets:
            for seed in range(first_seed, first_seed + n):
                p = rec_dir / f"{fam}_{pre}_{seed}.json"
                if p.exists():
                    rec = json.loads(p.read_text())
                    over = {k[len("override_"):]: v for k, v in rec.items() if k.startswith("override_")}
                    if over != dict(device_overrides or {}):
                        raise ValueError(f"{p}: a record with device overrides {over}; this run asks for "
                                         f"{dict(device_overrides or {})}: use another --out folder")
                    forced = {k[len("member_"):]: v for k, v in rec.items() if k.startswith("member_")}
                    if forced != {k: str(v) for k, v in (members or {}).items()}:
                        raise ValueError(f"{p}: a record with members forced {forced}; this run asks for "
                                         f"{dict(members or {})}: use another --out folder")
                    if rec.get("without", "") != ",".join(sorted(without)):
                        raise ValueError(f"{p}: a record without the effects {rec.get('without', '') or 'none'!r}; "
                                         f"this run asks without {','.join(sorted(without)) or 'none'!r}: use "
                                         "another --out folder")
                    if (rec.get("protocol", "three_trial"), rec.get("randomise", "hysteresis")) != (protocol, randomise):
                        raise ValueError(f"{p}: a record of protocol {rec.get('protocol', 'three_trial')!r}, "
                                         f"randomisation {rec.get('randomise', 'hysteresis')!r}; this run asks for "
                                         f"{protocol!r}, {randomise!r}: use another --out folder")
                    recs.append(rec)
                else:
                    todo.append((fam, pre, seed, config, str(p), protocol, randomise, dict(device_overrides or {}),
                                 dict(members or {}), tuple(without)))
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from tqdm import tqdm

    with ProcessPoolExecutor(max(1, int(jobs))) as ex:
        for rec in tqdm(ex.map(_job, todo), total=len(todo), desc="devices", unit="device",
                        disable=None if progress else True):
            recs.append(rec)
    write_tables(recs, out_dir)
    return aggregate(recs)


def write_tables(recs, out_dir: str | Path) -> None:
    from selfsense.io import write_text_atomic

    out_dir = Path(out_dir)
    df = pd.DataFrame(recs).sort_values(["family", "preset", "seed"])
    agg = aggregate(recs)
    write_text_atomic(df.drop(columns=[c for c in ("warnings",) if c in df]).to_csv(index=False, float_format="%.6g"),
                      out_dir / "records.csv")
    write_text_atomic(agg.to_csv(index=False, float_format="%.6g"), out_dir / "cross_device.csv")
    protocols = sorted({r.get("protocol", "three_trial") for r in recs})
    write_text_atomic(
        "# Cross-device accuracy (thesis Table 3 per device family and preset)\n\n"
        f"Calibration protocol: {', '.join(protocols)} (thesis: free-tip and blocked sines only; three_trial: with a "
        "free-tip mixed-drive calibration trial besides). "
        "Validation trials, mean |estimate - reference| / reference range per trial, then the mean over trials of "
        "each measurement (Table 3), per device; median and 90th percentile over devices.\n\n"
        + aggregate_markdown(agg), out_dir / "cross_device.md")
