from selfsense import stages

with stages.logged(snakemake.log[0]):  # noqa: F821
    stages.validate(snakemake.params.dataset_dir, snakemake.output[0], snakemake.params.on_bad_trial)  # noqa: F821
