from selfsense import stages

with stages.logged(snakemake.log[0]):  # noqa: F821
    stages.ingest(snakemake.params.dataset_dir, snakemake.wildcards.trial, snakemake.output[0])  # noqa: F821
