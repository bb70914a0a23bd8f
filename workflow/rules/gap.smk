# Sim-to-real gap diagnostic (code in src/selfsense/gap, docs/gap.md): `gap_diagnose` runs per dataset,
# `gap_reconcile` compares it with Table 3 and writes the folder the report reads. The blind check of the
# diagnostic is `selfsense gap blind` (not a pipeline target).


rule gap_diagnose:
    input:
        # the pipeline's own signals and fitted model (not the raw data again): the diagnostic diagnoses the
        # configured estimator. Not Table 3: its "before" is computed in the job as Table 3 is, and the comparison
        # with Table 3 is gap_reconcile's, so the job starts beside the estimate jobs instead of after the score rule
        signals=per_trial("signals", all_trials),
        model=res("{dataset}", "model", "sensing.json"),
    output:
        # the verdict before its reconciliation with Table 3, and its figure (gap_reconcile writes the folder)
        verdict=temp(res("{dataset}", "gap_draft", "verdict.pkl")),
        figure=temp(res("{dataset}", "gap_draft", "stage_gains.png")),
    log:
        res("{dataset}", "logs", "gap_diagnose.log"),
    benchmark:
        res("{dataset}", "benchmarks", "gap_diagnose.tsv")
    # the longest of the jobs after the model (compare_modes, figures, gap_diagnose): started first, so that the
    # other two share the second core beside it instead of leaving it to run alone at the end. One thread: with
    # threads: 2 (its recalibrations in two forked workers, the same bits) Snakemake on --cores 2 starts figures
    # beside compare_modes and this rule only after both, alone: the rule took 8.9 s instead of 13.3 s, the
    # pipeline no less (27.4 s against 26.6 s wall, and no gain in four more alternated pairs on a loaded machine)
    priority: 1
    conda:
        "../envs/selfsense.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        dataset_dir=dataset_dir,
        config=SENSING_CONFIG,
        seed=config.get("gap", {}).get("seed", 0),
    script:
        "../scripts/gap_diagnose.py"


rule gap_reconcile:
    input:
        verdict=res("{dataset}", "gap_draft", "verdict.pkl"),
        figure=res("{dataset}", "gap_draft", "stage_gains.png"),
        table3=res("{dataset}", "tables", "table3.csv"),
    output:
        # verdict.json, stages.csv, effects.csv, candidates.csv, shrink.csv|md and stage_gains.png
        gap=report(
            directory(res("{dataset}", "gap")),
            patterns=["{name}.png", "{name}.csv"],
            caption="../report/gap.rst",
            category="Sim-to-real gap diagnostic",
            labels={"dataset": "{dataset}", "item": "{name}"},
        ),
    log:
        res("{dataset}", "logs", "gap_reconcile.log"),
    benchmark:
        res("{dataset}", "benchmarks", "gap_reconcile.tsv")
    # a few small files (no fitting, no plotting): inside the Snakemake process
    threads: 1
    resources:
        mem_mb=500,
        runtime=10,
    params:
        dataset_dir=dataset_dir,
    run:
        from selfsense.gap.pipeline import reconcile_job

        reconcile_job(input, output, params, log)
