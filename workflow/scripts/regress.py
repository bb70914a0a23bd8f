from selfsense import stages

with stages.logged(snakemake.log[0]):  # noqa: F821
    stages.regress(snakemake.params.dataset_dir, stages.by_trial(snakemake.input.signals),  # noqa: F821
                   snakemake.input.hysteresis, snakemake.output[0])  # noqa: F821
