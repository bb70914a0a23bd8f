from selfsense import stages

with stages.logged(snakemake.log[0]):  # noqa: F821
    stages.estimate(snakemake.params.dataset_dir, snakemake.input.signals, snakemake.input.model,  # noqa: F821
                    snakemake.output.estimate, full_out=snakemake.output.internals)  # noqa: F821
