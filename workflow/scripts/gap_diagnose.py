"""Thin wrapper: selfsense.gap.pipeline.diagnose_pipeline (all science in src/selfsense/gap): the stage-wise
diagnostic on the pipeline's signals and fitted model, drafted for the rule gap_reconcile (which compares it with
Table 3 and writes the gap folder); its phase lines go to the rule's log."""
from selfsense import stages
from selfsense.gap.pipeline import diagnose_pipeline, write_draft
from selfsense.process import end_now

with stages.logged(snakemake.log[0]):  # noqa: F821
    signals = stages.by_trial(snakemake.input.signals)  # noqa: F821
    v = diagnose_pipeline(snakemake.params.dataset_dir, signals, snakemake.input.model,  # noqa: F821
                          snakemake.params.config, seed=int(snakemake.params.seed),  # noqa: F821
                          workers=snakemake.threads)  # noqa: F821
    write_draft(v, snakemake.output.verdict, snakemake.output.figure)  # noqa: F821
end_now()  # outputs written and closed: no interpreter teardown for Snakemake to wait for
