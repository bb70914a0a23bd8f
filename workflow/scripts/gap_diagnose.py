"""Thin wrapper: selfsense.gap.pipeline.run_pipeline_diagnosis (all science in src/selfsense/gap): the stage-wise
diagnostic on the pipeline's signals and fitted model; its phase lines go to the rule's log."""
from selfsense import stages
from selfsense.gap.pipeline import run_pipeline_diagnosis

with stages.logged(snakemake.log[0]):  # noqa: F821
    signals = stages.by_trial(snakemake.input.signals)  # noqa: F821
    run_pipeline_diagnosis(snakemake.params.dataset_dir, signals, snakemake.input.model,  # noqa: F821
                           snakemake.params.config, snakemake.output.gap,  # noqa: F821
                           table3_csv=snakemake.input.table3, seed=int(snakemake.params.seed),  # noqa: F821
                           workers=snakemake.threads)  # noqa: F821
