from selfsense import stages
from selfsense.process import end_now

with stages.logged(snakemake.log[0]):  # noqa: F821
    stages.compare_modes(snakemake.params.dataset_dir, stages.by_trial(snakemake.input.signals),  # noqa: F821
                         snakemake.params.config, snakemake.output.csv, snakemake.output.md,  # noqa: F821
                         model_json=snakemake.input.model)  # noqa: F821
end_now()  # outputs written and closed: no interpreter teardown for Snakemake to wait for
