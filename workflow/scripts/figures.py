from selfsense import stages

with stages.logged(snakemake.log[0]):  # noqa: F821
    stages.figures(snakemake.params.dataset_dir, stages.by_trial(snakemake.input.signals),  # noqa: F821
                   snakemake.input.model, stages.by_trial(snakemake.input.internals),  # noqa: F821
                   snakemake.input.per_trial, snakemake.output.figures)  # noqa: F821
