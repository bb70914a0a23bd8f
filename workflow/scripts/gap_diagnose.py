"""Thin wrapper: selfsense.gap.run_diagnose(dataset_dir, out_dir) (all science in src/selfsense/gap); the gap
package's phase lines (logging, INFO) go to the rule's log."""
from selfsense import stages
from selfsense.gap.api import run_diagnose

with stages.logged(snakemake.log[0]):  # noqa: F821
    run_diagnose(snakemake.params.dataset_dir, snakemake.output.gap,  # noqa: F821
                 estimator=snakemake.params.estimator, seed=int(snakemake.params.seed),  # noqa: F821
                 force=True)  # the pipeline owns results/<d>/gap; written all-or-nothing
