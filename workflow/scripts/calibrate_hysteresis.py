"""Thin wrapper: selfsense.stages.calibrate (H(q) selection and identification, src/selfsense/sensing/estimator.py).
A process of its own, so that its H(q) selection cross-validates the candidates in forked workers, one per thread
of the rule (selfsense.parallel.fork_map: the same bits for any count)."""
from selfsense import stages
from selfsense.hysteresis.models.select import cv_workers
from selfsense.process import end_now

with stages.logged(snakemake.log[0]), cv_workers(snakemake.threads):  # noqa: F821
    stages.calibrate(snakemake.params.dataset_dir, stages.by_trial(snakemake.input.signals),  # noqa: F821
                     snakemake.params.config, snakemake.output[0])  # noqa: F821
end_now()  # outputs written and closed: no interpreter teardown for Snakemake to wait for
