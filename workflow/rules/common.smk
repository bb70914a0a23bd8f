# Shared settings and functions of the workflow (functions live here only, as snakemake --lint asks).
# Dataset and trial lists are read through selfsense.io, so a bad trials.csv fails with a clear message.
import os


from selfsense import io as sio
from selfsense import stages

# Arrow buffers from the system allocator in every job: a trial read and freed returns its memory to the OS instead
# of staying in mimalloc's cache (peak RSS per job, benchmarks/MEMORY.md)
os.environ.setdefault("ARROW_DEFAULT_MEMORY_POOL", "system")

RAW = config.get("raw_dir", "data/raw")
RESULTS = config.get("results_dir", "results")
DATASETS = list(config["datasets"])
GAP_ENABLED = bool(config.get("gap", {}).get("enabled", True))
#: settings the H(q) calibration and the estimator read (params of the rules that fit a model)
SENSING_CONFIG = {k: config.get(k, {}) for k in ("calibration", "estimation")}
# cross-device benchmark target (workflow/rules/devices.smk): settings from config["devices"]
DEVICES = {
    "n": 10,
    "first_seed": 0,
    "families": ["preisach", "bouc_wen", "gpi", "jiles_atherton", "rate_kp"],
    "presets": ["clean", "drift"],
    **config.get("devices", {}),
}
DEVICE_IDS = [
    f"{fam}_{pre}_{seed}"
    for fam in DEVICES["families"]
    for pre in DEVICES["presets"]
    for seed in range(
        int(DEVICES["first_seed"]), int(DEVICES["first_seed"]) + int(DEVICES["n"])
    )
]

_TRIALS = {}


wildcard_constraints:
    dataset="[A-Za-z0-9_.-]+",
    trial="[A-Za-z0-9_-]+",


def res(*parts):
    """A path under the results folder (config results_dir): res("{dataset}", "signals", "{trial}.parquet")."""
    return os.path.join(RESULTS, *parts)


def raw(*parts):
    """A path under the raw-data folder (config raw_dir); never written to."""
    return os.path.join(RAW, *parts)


def dataset_dir(wildcards):
    return raw(wildcards.dataset)


def trials_table(dataset):
    if dataset not in _TRIALS:
        _TRIALS[dataset] = sio.load_trials(raw(dataset)).set_index("trial")
    return _TRIALS[dataset]


def all_trials(dataset):
    """Every trial of trials.csv. The DAG is fixed before any job runs (no checkpoint, so cluster profiles may group
    jobs): a trial that fails validation with on_bad_trial=skip still has its per-trial files, each a skip
    placeholder (selfsense.stages.write_skipped) that every dataset-level stage leaves out (stages.by_trial); the
    report lists it under "Failed trials"."""
    return list(trials_table(dataset).index)


def calibration_trials(dataset):
    t = trials_table(dataset)
    return sorted(t.index[t["role"] == "calibration"])


def raw_inputs(wildcards):
    """rig.yaml, trials.csv and every trial log of a dataset."""
    files = [raw(wildcards.dataset, "rig.yaml"), raw(wildcards.dataset, "trials.csv")]
    return files + [
        raw(wildcards.dataset, str(f)) for f in trials_table(wildcards.dataset)["file"]
    ]


def trial_log(wildcards):
    return raw(
        wildcards.dataset,
        str(trials_table(wildcards.dataset).loc[wildcards.trial, "file"]),
    )


def per_trial(kind, trials_fn):
    """Input function: ``res(<dataset>, kind, <trial>.parquet)`` for the trials ``trials_fn(dataset)``."""

    def _f(wildcards):
        return [
            res(wildcards.dataset, kind, f"{t}.parquet")
            for t in trials_fn(wildcards.dataset)
        ]

    return _f


def report_inputs(wildcards):
    d = wildcards.dataset
    inputs = {
        "table3": res(d, "tables", "table3.md"),
        "coverage": res(d, "tables", "coverage.md"),
        "figures": res(d, "figures"),
    }
    if config.get("report", {}).get("compare_modes", True):
        inputs["modes"] = res(d, "tables", "modes.md")
    if GAP_ENABLED:
        inputs["gap"] = res(d, "gap")
    return inputs


def matlab_files(wildcards):
    return [
        res(d, "export", f"{t}.{ext}")
        for d in DATASETS
        for t in all_trials(d)
        for ext in ("mat", "csv")
    ]


def slac_data_dir(wildcards):
    """The SLAC one-sided magnet data for the optional target ri_compare_slac (not bundled: config slac_data_dir)."""
    d = config.get("slac_data_dir")
    if not d:
        raise ValueError(
            "config: slac_data_dir is not set; ri_compare_slac needs the folder with strdat.ru3/strdat.ru4 "
            "(e.g. --config slac_data_dir=PATH)"
        )
    return d


def ri_main(args, log):
    """The RI command line (selfsense.cli.ri) inside the Snakemake process, output to the rule's log."""
    from selfsense.cli.ri import main

    with stages.logged(log):
        rc = main(list(args))
    if rc:
        raise RuntimeError(
            f"selfsense ri {' '.join(args)} exited with {rc} (see {log})"
        )
