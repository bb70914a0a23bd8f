# Cross-device accuracy benchmark (selfsense.devices; docs/cross_device.md), a target, NOT part of the default run:
#     snakemake --cores 2 cross_device
# One job per virtual device (family x preset x seed), so a cluster profile scales it out; the aggregate writes
# RESULTS/cross_device/cross_device.md (Table 3 per family and preset, median and 90th percentile over devices).
# Settings from config["devices"] (defaults below); the estimator uses the config's calibration/estimation blocks.
DEVICES = {
    "n": 10,
    "first_seed": 0,
    "families": ["preisach", "bouc_wen", "gpi", "jiles_atherton"],
    "presets": ["clean", "drift"],
    **config.get("devices", {}),
}
DEVICE_IDS = [
    f"{fam}_{pre}_{seed}"
    for fam in DEVICES["families"]
    for pre in DEVICES["presets"]
    for seed in range(int(DEVICES["first_seed"]), int(DEVICES["first_seed"]) + int(DEVICES["n"]))
]


rule device_job:
    output:
        RESULTS + "/cross_device/records/{family}_{preset}_{seed}.json",
    wildcard_constraints:
        family="preisach|bouc_wen|gpi|jiles_atherton",
        preset="clean|drift",
        seed=r"\d+",
    params:
        config=lambda w: {k: config.get(k, {}) for k in ("calibration", "estimation")},
    log:
        RESULTS + "/cross_device/logs/{family}_{preset}_{seed}.log",
    benchmark:
        RESULTS + "/cross_device/benchmarks/{family}_{preset}_{seed}.tsv"
    threads: 1
    resources:
        mem_mb=1500,
        runtime=10,
    script:
        "../scripts/device_job.py"


rule cross_device:
    input:
        expand(RESULTS + "/cross_device/records/{id}.json", id=DEVICE_IDS),
    output:
        md=RESULTS + "/cross_device/cross_device.md",
        csv=RESULTS + "/cross_device/cross_device.csv",
        records=RESULTS + "/cross_device/records.csv",
    log:
        RESULTS + "/cross_device/logs/cross_device.log",
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    shell:
        "{PYTHON} -m selfsense devices table {input} --out $(dirname {output.md}) > {log} 2>&1"
