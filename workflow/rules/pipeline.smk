# The main DAG (docs/method.md): validate -> ingest -> calibrate H(q) -> regress A -> estimate -> score -> figures
# -> report. Light rules use `run:` and execute inside the Snakemake process (no interpreter, NumPy, numba or
# cvxpy start-up per job, docs/benchmarks.md); on a cluster every job, per trial included, is still a job of its
# own. Heavy rules (plotting, model selection, the gap diagnostic) use `script:` and run in a process of their own.


rule validate_dataset:
    input:
        raw_inputs,
    output:
        res("{dataset}", "validation.json"),
    log:
        res("{dataset}", "logs", "validate.log"),
    benchmark:
        res("{dataset}", "benchmarks", "validate.tsv")
    threads: 1
    resources:
        mem_mb=1300,  # peak 996 MB at the sample budget (benchmarks/MEMORY.md)
        runtime=10,
    params:
        dataset_dir=dataset_dir,
        on_bad_trial=config.get("on_bad_trial", "fail"),
        max_trial_samples=config.get("max_trial_samples", 6000000),
    run:
        stages.run_job("validate_dataset", input, output, params, wildcards, log)


rule ingest:
    input:
        log=trial_log,
        validation=res("{dataset}", "validation.json"),
    output:
        res("{dataset}", "signals", "{trial}.parquet"),
    log:
        res("{dataset}", "logs", "ingest", "{trial}.log"),
    benchmark:
        res("{dataset}", "benchmarks", "ingest", "{trial}.tsv")
    threads: 1
    resources:
        mem_mb=1300,  # peak 1020 MB at the sample budget (benchmarks/MEMORY.md)
        runtime=10,
    params:
        dataset_dir=dataset_dir,
    run:
        stages.run_job("ingest", input, output, params, wildcards, log)


rule calibrate_hysteresis:
    input:
        # every trial: the charge link's reference-free hold evidence reads V, Q and the relay of all of them
        signals=per_trial("signals", all_trials),
    output:
        res("{dataset}", "model", "hysteresis.json"),
        res("{dataset}", "model", "h_selection.csv"),
    log:
        res("{dataset}", "logs", "calibrate_hysteresis.log"),
    benchmark:
        res("{dataset}", "benchmarks", "calibrate_hysteresis.tsv")
    conda:
        "../envs/selfsense.yaml"
    # nothing else of the dataset can run beside it (every later job needs the model): the H(q) selection
    # cross-validates two candidates at a time in forked workers (selfsense.parallel.fork_map; the fits hold the
    # GIL, so threads of the Snakemake process would take turns), the same bits for any number of threads;
    # Snakemake lowers it to --cores. A script: a process of its own, from which the workers can be forked
    threads: 2
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        dataset_dir=dataset_dir,
        config=SENSING_CONFIG,
    script:
        "../scripts/calibrate_hysteresis.py"


rule regress_coefficients:
    input:
        signals=per_trial("signals", all_trials),
        hysteresis=res("{dataset}", "model", "hysteresis.json"),
    output:
        res("{dataset}", "model", "sensing.json"),
    log:
        res("{dataset}", "logs", "regress_coefficients.log"),
    benchmark:
        res("{dataset}", "benchmarks", "regress_coefficients.tsv")
    threads: 1
    # where the creep member is carried beside an offset-drift member, H(q) is calibrated again here without the
    # drift (docs/method.md 6h): the calibration's budget
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        dataset_dir=dataset_dir,
    run:
        stages.run_job("regress_coefficients", input, output, params, wildcards, log)


rule estimate:
    input:
        signals=res("{dataset}", "signals", "{trial}.parquet"),
        model=res("{dataset}", "model", "sensing.json"),
    output:
        estimate=res("{dataset}", "estimates", "{trial}.parquet"),
        internals=res("{dataset}", "internals", "{trial}.parquet"),
    log:
        res("{dataset}", "logs", "estimate", "{trial}.log"),
    benchmark:
        res("{dataset}", "benchmarks", "estimate", "{trial}.tsv")
    threads: 1
    resources:
        mem_mb=1600,  # peak 1272 MB at the sample budget, h_model modified_pi (benchmarks/MEMORY.md)
        runtime=10,
    params:
        dataset_dir=dataset_dir,
    run:
        stages.run_job("estimate", input, output, params, wildcards, log)


rule score:
    input:
        estimates=per_trial("estimates", all_trials),
    output:
        table3=report(
            res("{dataset}", "tables", "table3.csv"),
            caption="../report/table3.rst",
            category="Accuracy",
            labels={"dataset": "{dataset}", "table": "Table 3"},
        ),
        per_trial=report(
            res("{dataset}", "tables", "per_trial.csv"),
            caption="../report/per_trial.rst",
            category="Accuracy",
            labels={"dataset": "{dataset}", "table": "per trial"},
        ),
        table3_md=res("{dataset}", "tables", "table3.md"),
        per_trial_md=res("{dataset}", "tables", "per_trial.md"),
    log:
        res("{dataset}", "logs", "score.log"),
    benchmark:
        res("{dataset}", "benchmarks", "score.tsv")
    threads: 1
    resources:
        mem_mb=800,  # peak 618 MB at the sample budget (benchmarks/MEMORY.md)
        runtime=10,
    params:
        dataset_dir=dataset_dir,
        out_dir=lambda w: res(w.dataset, "tables"),
    run:
        stages.run_job("score", input, output, params, wildcards, log)


rule coverage:
    input:
        # reference-free: V, q and the relay of every trial (the per-trial errors only set side by side in the table,
        # the model read for which holds its hold rows fitted)
        signals=per_trial("signals", all_trials),
        per_trial=res("{dataset}", "tables", "per_trial.csv"),
        model=res("{dataset}", "model", "sensing.json"),
    output:
        csv=report(
            res("{dataset}", "tables", "coverage.csv"),
            caption="../report/coverage.rst",
            category="Accuracy",
            labels={"dataset": "{dataset}", "table": "drive coverage"},
        ),
        md=res("{dataset}", "tables", "coverage.md"),
    log:
        res("{dataset}", "logs", "coverage.log"),
    benchmark:
        res("{dataset}", "benchmarks", "coverage.tsv")
    threads: 1
    resources:
        mem_mb=800,
        runtime=10,
    params:
        dataset_dir=dataset_dir,
        out_dir=lambda w: res(w.dataset, "tables"),
    run:
        stages.run_job("coverage", input, output, params, wildcards, log)


rule compare_modes:
    input:
        # not the estimates: the pipeline model's own row is estimated in the job (~1 s), so that it runs beside
        # the estimate jobs instead of after them (docs/benchmarks.md)
        signals=per_trial("signals", all_trials),
        model=res("{dataset}", "model", "sensing.json"),
    output:
        csv=report(
            res("{dataset}", "tables", "modes.csv"),
            caption="../report/modes.rst",
            category="Accuracy",
            labels={
                "dataset": "{dataset}",
                "table": "H(q) models and calibration modes",
            },
        ),
        md=res("{dataset}", "tables", "modes.md"),
    log:
        res("{dataset}", "logs", "compare_modes.log"),
    benchmark:
        res("{dataset}", "benchmarks", "compare_modes.tsv")
    conda:
        "../envs/selfsense.yaml"
    threads: 1
    resources:
        mem_mb=1700,  # peak 1361 MB with a trial at its 2e6-sample budget (benchmarks/MEMORY.md)
        runtime=30,
    params:
        dataset_dir=dataset_dir,
        config=SENSING_CONFIG,
    script:
        "../scripts/compare_modes.py"


rule figures:
    input:
        signals=per_trial("signals", all_trials),
        internals=per_trial("internals", all_trials),
        model=res("{dataset}", "model", "sensing.json"),
        per_trial=res("{dataset}", "tables", "per_trial.csv"),
    output:
        # every figure of the dataset (PNG and PDF) and captions.json
        figures=report(
            directory(res("{dataset}", "figures")),
            patterns=["{name}.png"],
            caption="../report/figure.rst",
            category="Figures",
            labels={"dataset": "{dataset}", "figure": "{name}"},
        ),
    log:
        res("{dataset}", "logs", "figures.log"),
    benchmark:
        res("{dataset}", "benchmarks", "figures.tsv")
    conda:
        "../envs/selfsense.yaml"
    threads: 1
    resources:
        mem_mb=1100,  # peak 880 MB at the sample budget: every k-th row drawn (benchmarks/MEMORY.md)
        runtime=10,
    params:
        dataset_dir=dataset_dir,
    script:
        "../scripts/figures.py"


rule report:
    input:
        unpack(report_inputs),
    output:
        report(
            res("{dataset}", "report.html"),
            caption="../report/html_report.rst",
            category="Report",
            labels={"dataset": "{dataset}", "file": "report.html"},
        ),
    log:
        res("{dataset}", "logs", "report.log"),
    benchmark:
        res("{dataset}", "benchmarks", "report.tsv")
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        dataset_dir=dataset_dir,
        results_dir=lambda w: res(w.dataset),
        run_config=lambda w: dict(config),  # shown in the report's provenance block
    run:
        stages.run_job("report", input, output, params, wildcards, log)


# MATLAB / spreadsheet users: `selfsense run matlab` (or `snakemake --cores 2 matlab`) writes every trial's results
# as results/<d>/export/<trial>.mat and .csv (t, u_cmd, relay, V, q, V_H, V_p, raw and post-processed estimates,
# references, with units, sample rate, coefficients with units and the estimator config; selfsense.report.export);
# not in the default run. `selfsense export RESULTS_DIR DATASET_DIR --out DIR` does the same outside Snakemake.
rule export_matlab:
    input:
        signals=res("{dataset}", "signals", "{trial}.parquet"),
        internals=res("{dataset}", "internals", "{trial}.parquet"),
        model=res("{dataset}", "model", "sensing.json"),
    output:
        mat=res("{dataset}", "export", "{trial}.mat"),
        csv=res("{dataset}", "export", "{trial}.csv"),
    log:
        res("{dataset}", "logs", "export_matlab", "{trial}.log"),
    benchmark:
        res("{dataset}", "benchmarks", "export_matlab", "{trial}.tsv")
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        dataset_dir=dataset_dir,
    run:
        stages.run_job("export_matlab", input, output, params, wildcards, log)


rule matlab:
    input:
        matlab_files,
