# Shared helpers: dataset and trial lists (read through selfsense.io so a bad trials.csv fails with a clear message).
import os
import sys

from selfsense import io as sio

PYTHON = sys.executable  # the interpreter running Snakemake (has selfsense installed)
RAW = config.get("raw_dir", "data/raw")
RESULTS = config.get("results_dir", "results")
DATASETS = list(config["datasets"])
GAP_ENABLED = bool(config.get("gap", {}).get("enabled", True))

_TRIALS = {}


def trials_table(dataset):
    if dataset not in _TRIALS:
        _TRIALS[dataset] = sio.load_trials(os.path.join(RAW, dataset)).set_index("trial")
    return _TRIALS[dataset]


def all_trials(dataset):
    """Trials that passed validation (checkpoint validate_dataset; with on_bad_trial=skip a bad validation
    trial is left out and listed as failed in the report)."""
    import json

    path = checkpoints.validate_dataset.get(dataset=dataset).output[0]
    with open(path) as fh:
        return list(json.load(fh)["trials"])


def calibration_trials(dataset):
    t = trials_table(dataset)
    return sorted(t.index[t["role"] == "calibration"])


def trial_log(wildcards):
    return os.path.join(RAW, wildcards.dataset, str(trials_table(wildcards.dataset).loc[wildcards.trial, "file"]))


def signals_of(trials_fn):
    def _f(wildcards):
        return {t: f"{RESULTS}/{wildcards.dataset}/signals/{t}.parquet" for t in trials_fn(wildcards.dataset)}

    return _f


def estimates_of(wildcards):
    return {t: f"{RESULTS}/{wildcards.dataset}/estimates/{t}.parquet" for t in all_trials(wildcards.dataset)}


wildcard_constraints:
    dataset="[A-Za-z0-9_.-]+",
    trial="[A-Za-z0-9_-]+",


def slac_data_dir():
    """The SLAC one-sided magnet data for the optional target ri_compare_slac (not bundled: config slac_data_dir)."""
    d = config.get("slac_data_dir")
    if not d:
        raise ValueError(
            "config: slac_data_dir is not set; ri_compare_slac needs the folder with strdat.ru3/strdat.ru4 "
            "(e.g. --config slac_data_dir=PATH)"
        )
    return d
