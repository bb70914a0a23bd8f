# Sim-to-real gap diagnostic (code in src/selfsense/gap, docs/gap.md).
# `gap_diagnose` runs per dataset (the report uses its verdict); `gap_benchmark` is a campaign target, NOT part of
# the default run:
#     snakemake --cores 2 gap_benchmark   (n, seed, tier, estimator from config["gap"]["benchmark"], defaults in
#                                          workflow/rules/common.smk)
#     e.g. snakemake --cores 2 gap_benchmark --configfile config.yaml bench.yaml
#          with bench.yaml:  gap: {enabled: true, benchmark: {n: 1000, seed: 2026, tier: fast}}
#     (tier full needs its own null calibration first: `selfsense gap calibrate --tier full ...`, merged into
#      src/selfsense/gap/thresholds.json; without it every case stops with a KeyError naming that command)


rule gap_diagnose:
    input:
        # the pipeline's own signals and fitted model (not the raw data again): the diagnostic diagnoses the
        # configured estimator, and its "before" is Table 3
        signals=per_trial("signals", all_trials),
        model=res("{dataset}", "model", "sensing.json"),
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
        res("{dataset}", "logs", "gap_diagnose.log"),
    benchmark:
        res("{dataset}", "benchmarks", "gap_diagnose.tsv")
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


rule gap_scenario:
    output:
        res("gap_benchmark", "scenarios", "{i}.json"),
    log:
        res("gap_benchmark", "logs", "scenario_{i}.log"),
    benchmark:
        res("gap_benchmark", "benchmarks", "scenario_{i}.tsv")
    wildcard_constraints:
        i="[0-9]+",
    conda:
        "../envs/selfsense.yaml"
    threads: 1
    resources:
        mem_mb=1500,
        runtime=10,
    params:
        seed=GAP_BENCH["seed"],
        tier=GAP_BENCH["tier"],
        estimator=GAP_BENCH["estimator"],
    script:
        "../scripts/gap_scenario.py"


rule gap_benchmark:
    input:
        expand(
            res("gap_benchmark", "scenarios", "{i}.json"), i=range(int(GAP_BENCH["n"]))
        ),
    output:
        scores=report(
            res("gap_benchmark", "scores.md"),
            caption="../report/gap_benchmark.rst",
            category="Sim-to-real gap benchmark",
        ),
        csv=res("gap_benchmark", "scores.csv"),
    log:
        res("gap_benchmark", "logs", "aggregate.log"),
    benchmark:
        res("gap_benchmark", "benchmarks", "aggregate.tsv")
    conda:
        "../envs/selfsense.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/gap_aggregate.py"
