"""What limits the accuracy on a simulated dataset: the measurements of the README's "Accuracy" section.

    python benchmarks/accuracy_limits.py [--dataset data/raw/tweezer_sim] [--out benchmarks/ACCURACY_LIMITS.md]

Needs the dataset's truth folder (``<dataset>.truth``, written by ``selfsense simulate``). For each H(q) model
(the pipeline's default, modified PI, RI + creep) it prints Table 3 (validation mean, % of range) for:
  * the estimator as in the pipeline;
  * the same with the true charge and/or the true actuator voltage substituted for the measured ones;
  * the same dataset re-simulated with every default unmodelled effect switched off (same scenario and seed);
and the H(q) error [V RMS] on every free-tip trial (in sample for the calibration trials, out of sample otherwise).
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from selfsense import io as sio
from selfsense.report import tables
from selfsense.sensing import SelfSensingEstimator, SensingConfig
from selfsense.sensing.estimator import h_target
from selfsense.signals import prepare_trial


def _load(dataset: Path):
    rig = sio.load_rig(dataset)
    meta = sio.load_trials(dataset).set_index("trial")
    sigs = {t: prepare_trial(sio.trial_signals(dataset, t, rig=rig), rig) for t in meta.index}
    return rig, meta, sigs


def _table3(est, sigs, meta):
    ests = {}
    for t, s in sigs.items():
        e = est.estimate(s, trial=t)
        e["dx_ref"], e["f_ref"] = s["dx_ref"].to_numpy(), s["f_ref"].to_numpy()
        ests[t] = e
    t3 = tables.table3(tables.per_trial_table(ests, meta.reset_index())).set_index("measurement")
    return float(t3.loc["displacement", "percent_of_range"]), float(t3.loc["force", "percent_of_range"])


def _h_errors(est, sigs, meta):
    out = {}
    for t in meta.index[meta["tip"] == "free"]:
        s = sigs[t][sigs[t]["relay"] < 0.5]
        y = h_target(s["V"].to_numpy(), s["q"].to_numpy(), est.h_slope_)
        out[t] = float(np.sqrt(np.mean((est.hysteresis_(s["q"].to_numpy()) - y) ** 2)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="data/raw/tweezer_sim")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    dataset = Path(args.dataset)
    truth_dir = dataset.parent / f"{dataset.name}.truth"
    rig, meta, sigs = _load(dataset)
    truth = {t: pd.read_parquet(truth_dir / f"{t}.parquet") for t in meta.index}
    import datetime

    lines = [f"# Accuracy limits on `{dataset}` (validation mean, % of range)", "",
             f"Command: `python benchmarks/accuracy_limits.py --dataset {args.dataset} --out {args.out}`; "
             f"measured {datetime.date.today().isoformat()}. `default` is the pipeline's default estimator "
             "(config.yaml), `modified_pi` and `ri` are `SensingConfig(h_model=...)` with every other setting at its default (joint identification on all calibration trials, drift compensation where supported), so they differ from the thesis-method rows of the modes table.", "",
             "| H(q) model | variant | displacement | force |", "|---|---|---|---|"]
    herr_lines = ["", "| H(q) model | free-tip trial | role | H error, V RMS |", "|---|---|---|---|"]
    # the same scenario re-simulated with the default effects off
    import json

    from selfsense.sim.simulate import simulate_dataset

    manifest = json.loads((truth_dir / "manifest.json").read_text())
    scenario = dict(manifest["scenario"])
    scenario["effects_defaults"] = False
    scenario["effects"] = {}
    with tempfile.TemporaryDirectory() as tmp:
        clean = Path(tmp) / dataset.name
        simulate_dataset(scenario, seed=manifest["seed"], out_dir=clean, contributions=False)
        _, _, clean_sigs = _load(clean)
    import yaml

    from selfsense.stages import sensing_config

    default_cfg = sensing_config(yaml.safe_load((Path(__file__).resolve().parents[1] / "config.yaml").read_text()))
    for h_model in ("default", "modified_pi", "ri"):
        cfg = default_cfg if h_model == "default" else SensingConfig(h_model=h_model)
        variants = {"as in the pipeline": sigs}
        for name, cols in (("true charge", ("q",)), ("true voltage", ("V",)), ("true charge and voltage", ("q", "V"))):
            v = {}
            for t, s in sigs.items():
                s = s.copy()
                for c in cols:
                    s[c] = truth[t][c].to_numpy(dtype=float)
                v[t] = s
            variants[name] = v
        variants["default effects off (re-simulated)"] = clean_sigs
        for name, S in variants.items():
            est = SelfSensingEstimator(config=cfg, rig=rig).fit(S, meta)
            dx, f = _table3(est, S, meta)
            lines.append(f"| {h_model} | {name} | {dx:.2f} | {f:.2f} |")
            print(lines[-1], flush=True)
            if name == "as in the pipeline":
                for t, e in _h_errors(est, S, meta).items():
                    herr_lines.append(f"| {h_model} | {t} | {meta.loc[t, 'role']} | {e:.3f} |")
    text = "\n".join(lines + herr_lines) + "\n"
    print("\n".join(herr_lines))
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
