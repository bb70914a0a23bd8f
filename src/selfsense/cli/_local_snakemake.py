"""Snakemake for a run on this machine, without the SLURM executor plugins' start-up probe.

Snakemake imports every installed executor plugin at start (``snakemake_interface_common.plugin_registry``: every
top-level module named ``snakemake_executor_plugin_*``). The SLURM plugin (the ``slurm`` extra, for ``selfsense run
--profile workflow/profiles/slurm``) then runs ``scontrol show config`` while building its option help; where SLURM's
client is installed and its controller cannot be reached, that call waits up to 10 s at every start (9 s measured on
the development machine). ``selfsense run`` starts Snakemake through this module when neither an executor nor a
profile is given (:func:`selfsense.cli.run.runs_locally`), so such a run never loads those plugins; any other run
starts ``python -m snakemake`` unchanged.

It also ends the process when the workflow has ended (:func:`cancel_timers`): Snakemake's job scheduler leaves a
timer thread behind that the interpreter otherwise waits for, up to a second after the last job.

    python -m selfsense.cli._local_snakemake [snakemake options]
"""
from __future__ import annotations

import pkgutil
import sys
import threading

#: executor plugins a local run does not load (module-name prefix)
SKIPPED_PLUGINS = ("snakemake_executor_plugin_slurm",)


def without_skipped(modules):
    """The module infos of ``pkgutil.iter_modules`` without the :data:`SKIPPED_PLUGINS`."""
    return (m for m in modules if not m.name.startswith(SKIPPED_PLUGINS))


def hide_skipped_plugins() -> None:
    """Leave the :data:`SKIPPED_PLUGINS` out of ``pkgutil.iter_modules``, where Snakemake's plugin registry looks for
    executor plugins (call before Snakemake collects them)."""
    orig = pkgutil.iter_modules

    def iter_modules(path=None, prefix=""):
        return without_skipped(orig(path, prefix))

    pkgutil.iter_modules = iter_modules


def cancel_timers() -> None:
    """Cancel the ``threading.Timer`` threads still waiting once Snakemake has returned. Its job scheduler starts one
    at every pass of its loop that waits for running jobs (``--max-jobs-per-timespan``, default 100/1s: look again
    after the timespan); the last one outlives the workflow, and the interpreter joins it before it exits: 1.0-1.35 s
    after Snakemake's closing ``Elapsed time`` line on ``tweezer_sim``, on the critical path of every run. Its action
    only wakes the scheduler that has already finished, so cancelling it changes nothing else."""
    for t in threading.enumerate():
        if isinstance(t, threading.Timer):
            t.cancel()


def main(argv: list[str] | None = None) -> int:
    hide_skipped_plugins()
    from snakemake.cli import main as snakemake_main

    try:
        return snakemake_main(sys.argv[1:] if argv is None else argv)
    finally:   # also when Snakemake ends with sys.exit, as its command line does
        cancel_timers()


if __name__ == "__main__":
    sys.exit(main())
