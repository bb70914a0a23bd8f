"""Thin wrapper: selfsense.gap.run_diagnose(dataset_dir, out_dir) (all science in src/selfsense/gap)."""
import contextlib
import logging

from selfsense.gap.api import run_diagnose

with open(snakemake.log[0], "w") as log, contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):  # noqa: F821
    logging.basicConfig(stream=log, level=logging.INFO, format="%(message)s", force=True)  # phase lines in the log
    run_diagnose(snakemake.params.dataset_dir, snakemake.params.out_dir,  # noqa: F821
                 estimator=snakemake.params.estimator, seed=int(snakemake.params.seed),  # noqa: F821
                 force=True)  # the pipeline owns results/<d>/gap; written all-or-nothing
