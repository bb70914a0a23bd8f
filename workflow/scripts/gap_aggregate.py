"""Thin wrapper: benchmark scores from the scenario JSON files (selfsense.gap.api.aggregate_scenarios)."""
import contextlib
import os

from selfsense.determinism import single_thread_blas
from selfsense.gap.api import aggregate_scenarios

single_thread_blas()  # as every pipeline job (selfsense.stages.logged)
with open(snakemake.log[0], "w") as log, contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):  # noqa: F821
    aggregate_scenarios(list(snakemake.input), os.path.dirname(snakemake.output.scores))  # noqa: F821
