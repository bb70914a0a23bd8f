from selfsense import stages
from selfsense.report.export import export_trial

with stages.logged(snakemake.log[0]):  # noqa: F821
    export_trial(snakemake.params.dataset_dir, snakemake.wildcards.trial, snakemake.input.signals,  # noqa: F821
                 snakemake.input.internals, snakemake.input.model,  # noqa: F821
                 out_mat=snakemake.output.mat, out_csv=snakemake.output.csv)  # noqa: F821
