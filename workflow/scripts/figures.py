from selfsense import stages
from selfsense.process import end_now

with stages.logged(snakemake.log[0]):  # noqa: F821
    stages.figures(snakemake.params.dataset_dir, stages.by_trial(snakemake.input.signals),  # noqa: F821
                   snakemake.input.model, stages.by_trial(snakemake.input.internals),  # noqa: F821
                   snakemake.input.per_trial, snakemake.output.figures)  # noqa: F821
end_now()  # outputs written and closed: no interpreter teardown for Snakemake to wait for
