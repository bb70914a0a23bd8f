"""Thin wrapper: one blind benchmark case -> JSON (selfsense.gap.api.run_scenario_to_json)."""
import contextlib

from selfsense.determinism import single_thread_blas
from selfsense.gap.api import run_scenario_to_json

single_thread_blas()  # as every pipeline job (selfsense.stages.logged)
with open(snakemake.log[0], "w") as log, contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):  # noqa: F821
    run_scenario_to_json(int(snakemake.wildcards.i), int(snakemake.params.seed), snakemake.params.tier,  # noqa: F821
                         snakemake.output[0], estimator=snakemake.params.estimator)  # noqa: F821
