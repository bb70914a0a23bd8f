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
        raw_inputs,
        # after validation: a dataset that fails the contract or the plausibility checks stops there, not here
        res("{dataset}", "validation.json"),
    output:
        # attribution.csv, budget.csv, shrink.csv|md, verdict.json and the diagnostic's figures
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
        mem_mb=1400,  # peak 1142 MB at the sample budget: block means (benchmarks/MEMORY.md)
        runtime=30,
    params:
        dataset_dir=dataset_dir,
        # the estimator the pipeline uses: the RI + creep model when calibration.h_model is ri (the gap section
        # must diagnose the model of Table 3), else the modified PI; gap.estimator overrides
        estimator=GAP_ESTIMATOR,
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
