# The main DAG (ARCHITECTURE.md): validate -> ingest -> calibrate H(q) -> regress A -> estimate -> score -> figures -> report


checkpoint validate_dataset:
    input:
        rig=RAW + "/{dataset}/rig.yaml",
        trials=RAW + "/{dataset}/trials.csv",
        logs=lambda w: [os.path.join(RAW, w.dataset, str(f)) for f in trials_table(w.dataset)["file"]],
    output:
        RESULTS + "/{dataset}/validation.json",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
        on_bad_trial=config.get("on_bad_trial", "fail"),
    log:
        RESULTS + "/{dataset}/logs/validate.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/validate.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    script:
        "../scripts/validate.py"


rule ingest:
    input:
        log=trial_log,
        validation=RESULTS + "/{dataset}/validation.json",
    output:
        RESULTS + "/{dataset}/signals/{trial}.parquet",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
    log:
        RESULTS + "/{dataset}/logs/ingest/{trial}.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/ingest/{trial}.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/ingest.py"


rule calibrate_hysteresis:
    input:
        signals=lambda w: expand(RESULTS + "/{{dataset}}/signals/{trial}.parquet", trial=calibration_trials(w.dataset)),
    output:
        RESULTS + "/{dataset}/model/hysteresis.json",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
        config=lambda w: {k: config.get(k, {}) for k in ("calibration", "estimation")},
    log:
        RESULTS + "/{dataset}/logs/calibrate_hysteresis.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/calibrate_hysteresis.tsv"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    script:
        "../scripts/calibrate.py"


rule regress_coefficients:
    input:
        signals=lambda w: expand(RESULTS + "/{{dataset}}/signals/{trial}.parquet", trial=calibration_trials(w.dataset)),
        hysteresis=RESULTS + "/{dataset}/model/hysteresis.json",
    output:
        RESULTS + "/{dataset}/model/sensing.json",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
    log:
        RESULTS + "/{dataset}/logs/regress_coefficients.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/regress_coefficients.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/regress.py"


rule estimate:
    input:
        signals=RESULTS + "/{dataset}/signals/{trial}.parquet",
        model=RESULTS + "/{dataset}/model/sensing.json",
    output:
        estimate=RESULTS + "/{dataset}/estimates/{trial}.parquet",
        internals=RESULTS + "/{dataset}/internals/{trial}.parquet",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
    log:
        RESULTS + "/{dataset}/logs/estimate/{trial}.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/estimate/{trial}.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/estimate.py"


rule score:
    input:
        estimates=lambda w: expand(RESULTS + "/{{dataset}}/estimates/{trial}.parquet", trial=all_trials(w.dataset)),
    output:
        table3=RESULTS + "/{dataset}/tables/table3.csv",
        per_trial=RESULTS + "/{dataset}/tables/per_trial.csv",
        table3_md=RESULTS + "/{dataset}/tables/table3.md",
        per_trial_md=RESULTS + "/{dataset}/tables/per_trial.md",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
    log:
        RESULTS + "/{dataset}/logs/score.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/score.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/score.py"


rule compare_modes:
    input:
        signals=lambda w: expand(RESULTS + "/{{dataset}}/signals/{trial}.parquet", trial=all_trials(w.dataset)),
    output:
        csv=RESULTS + "/{dataset}/tables/modes.csv",
        md=RESULTS + "/{dataset}/tables/modes.md",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
        config=lambda w: {k: config.get(k, {}) for k in ("calibration", "estimation")},
    log:
        RESULTS + "/{dataset}/logs/compare_modes.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/compare_modes.tsv"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    script:
        "../scripts/compare_modes.py"


rule figures:
    input:
        signals=lambda w: expand(RESULTS + "/{{dataset}}/signals/{trial}.parquet", trial=all_trials(w.dataset)),
        internals=lambda w: expand(RESULTS + "/{{dataset}}/internals/{trial}.parquet", trial=all_trials(w.dataset)),
        model=RESULTS + "/{dataset}/model/sensing.json",
        per_trial=RESULTS + "/{dataset}/tables/per_trial.csv",
    output:
        captions=RESULTS + "/{dataset}/figures/captions.json",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
        out_dir=lambda w: f"{RESULTS}/{w.dataset}/figures",
    log:
        RESULTS + "/{dataset}/logs/figures.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/figures.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/figures.py"


def report_inputs(wildcards):
    d = wildcards.dataset
    inputs = {
        "table3": f"{RESULTS}/{d}/tables/table3.md",
        "captions": f"{RESULTS}/{d}/figures/captions.json",
    }
    if config.get("report", {}).get("compare_modes", True):
        inputs["modes"] = f"{RESULTS}/{d}/tables/modes.md"
    if GAP_ENABLED and HAVE_GAP_RULES:
        inputs["gap"] = f"{RESULTS}/{d}/gap/verdict.json"
    return inputs


rule report:
    input:
        unpack(report_inputs),
    output:
        RESULTS + "/{dataset}/report.html",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
        results_dir=lambda w: f"{RESULTS}/{w.dataset}",
        run_config=lambda w: dict(config),  # shown in the report's provenance block
    log:
        RESULTS + "/{dataset}/logs/report.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/report.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    script:
        "../scripts/report.py"


# MATLAB / spreadsheet users: `selfsense run matlab` (or `snakemake --cores 2 matlab`) writes every trial's results
# as results/<d>/export/<trial>.mat and .csv (t, u_cmd, relay, V, q, V_H, V_p, raw and post-processed estimates,
# references, with units, sample rate, coefficients with units and the estimator config; selfsense.report.export);
# not in the default run. `selfsense export RESULTS_DIR DATASET_DIR --out DIR` does the same outside Snakemake.
rule export_matlab:
    input:
        signals=RESULTS + "/{dataset}/signals/{trial}.parquet",
        internals=RESULTS + "/{dataset}/internals/{trial}.parquet",
        model=RESULTS + "/{dataset}/model/sensing.json",
    output:
        mat=RESULTS + "/{dataset}/export/{trial}.mat",
        csv=RESULTS + "/{dataset}/export/{trial}.csv",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
    log:
        RESULTS + "/{dataset}/logs/export_matlab/{trial}.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/export_matlab/{trial}.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    script:
        "../scripts/export_matlab.py"


rule matlab:
    input:
        lambda w: [f"{RESULTS}/{d}/export/{t}.{ext}" for d in DATASETS for t in all_trials(d) for ext in ("mat", "csv")],
