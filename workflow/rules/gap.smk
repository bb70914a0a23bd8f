# Sim-to-real gap diagnostic (GAP_DIAGNOSIS.md; code in src/selfsense/gap, docs/gap.md).
# Included by the Snakefile. `gap_diagnose` runs per dataset (the report uses its verdict);
# `gap_benchmark` is a campaign target, NOT part of the default run:
#     snakemake --cores 2 gap_benchmark   (n, seed, tier, estimator from config["gap"]["benchmark"], defaults below)
#     e.g. snakemake --cores 2 gap_benchmark --configfile config.yaml bench.yaml
#          with bench.yaml:  gap: {enabled: true, benchmark: {n: 1000, seed: 2026, tier: fast}}
#     (tier full needs its own null calibration first: `selfsense gap calibrate --tier full ...`, merged into
#      src/selfsense/gap/thresholds.json; without it every case stops with a KeyError naming that command)
import os

GAP_BENCH = {"n": 40, "seed": 1, "tier": "fast", "estimator": "sensing_ri", **config.get("gap", {}).get("benchmark", {})}


def gap_raw_inputs(wildcards):
    d = os.path.join(RAW, wildcards.dataset)
    files = [os.path.join(d, "rig.yaml"), os.path.join(d, "trials.csv")]
    files += [os.path.join(d, str(f)) for f in trials_table(wildcards.dataset)["file"]]
    # after validation: a dataset that fails the contract or the plausibility checks stops there, not here
    files.append(f"{RESULTS}/{wildcards.dataset}/validation.json")
    return files


rule gap_diagnose:
    input:
        gap_raw_inputs,
    output:
        attribution=RESULTS + "/{dataset}/gap/attribution.csv",
        budget=RESULTS + "/{dataset}/gap/budget.csv",
        verdict=RESULTS + "/{dataset}/gap/verdict.json",
        shrink=RESULTS + "/{dataset}/gap/shrink.csv",
    params:
        dataset_dir=lambda w: os.path.join(RAW, w.dataset),
        out_dir=lambda w: f"{RESULTS}/{w.dataset}/gap",
        # the estimator the pipeline uses: the RI + creep model when calibration.h_model is ri (issue: the gap
        # section must diagnose the model of Table 3), else the modified PI; gap.estimator overrides
        estimator=config.get("gap", {}).get("estimator")
        or ("sensing_ri" if config.get("calibration", {}).get("h_model") == "ri" else "sensing"),
        seed=config.get("gap", {}).get("seed", 0),
    log:
        RESULTS + "/{dataset}/logs/gap_diagnose.log",
    benchmark:
        RESULTS + "/{dataset}/benchmarks/gap_diagnose.tsv"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    script:
        "../scripts/gap_diagnose.py"


rule gap_scenario:
    output:
        RESULTS + "/gap_benchmark/scenarios/{i}.json",
    params:
        seed=GAP_BENCH["seed"],
        tier=GAP_BENCH["tier"],
        estimator=GAP_BENCH["estimator"],
    log:
        RESULTS + "/gap_benchmark/logs/scenario_{i}.log",
    benchmark:
        RESULTS + "/gap_benchmark/benchmarks/scenario_{i}.tsv"
    wildcard_constraints:
        i="[0-9]+",
    threads: 1
    resources:
        mem_mb=1500,
        runtime=10,
    script:
        "../scripts/gap_scenario.py"


rule gap_benchmark:
    input:
        expand(RESULTS + "/gap_benchmark/scenarios/{i}.json", i=range(int(GAP_BENCH["n"]))),
    output:
        scores=RESULTS + "/gap_benchmark/scores.md",
        csv=RESULTS + "/gap_benchmark/scores.csv",
    log:
        RESULTS + "/gap_benchmark/logs/aggregate.log",
    benchmark:
        RESULTS + "/gap_benchmark/benchmarks/aggregate.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/gap_aggregate.py"
