# Cross-device accuracy benchmark (selfsense.devices; docs/cross_device.md), a target, NOT part of the default run:
#     snakemake --cores 2 cross_device
# One job per virtual device (family x preset x seed), so a cluster profile scales it out; the aggregate writes
# RESULTS/cross_device/cross_device.md (Table 3 per family and preset, median and 90th percentile over devices).
# Settings from config["devices"] (DEVICES in common.smk); the estimator uses the config's calibration/estimation.


rule device_job:
    output:
        res("cross_device", "records", "{family}_{preset}_{seed}.json"),
    log:
        res("cross_device", "logs", "{family}_{preset}_{seed}.log"),
    benchmark:
        res("cross_device", "benchmarks", "{family}_{preset}_{seed}.tsv")
    wildcard_constraints:
        family="preisach|bouc_wen|gpi|jiles_atherton|rate_kp",
        preset="clean|drift",
        seed=r"\d+",
    conda:
        "../envs/selfsense.yaml"
    threads: 1
    resources:
        mem_mb=1500,
        runtime=10,
    params:
        config=SENSING_CONFIG,
    script:
        "../scripts/device_job.py"


rule cross_device:
    input:
        expand(res("cross_device", "records", "{id}.json"), id=DEVICE_IDS),
    output:
        md=report(
            res("cross_device", "cross_device.md"),
            caption="../report/cross_device.rst",
            category="Cross-device accuracy",
        ),
        csv=res("cross_device", "cross_device.csv"),
        records=res("cross_device", "records.csv"),
    log:
        res("cross_device", "logs", "cross_device.log"),
    conda:
        "../envs/selfsense.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    script:
        "../scripts/device_table.py"
