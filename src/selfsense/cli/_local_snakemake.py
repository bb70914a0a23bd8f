"""Snakemake for a run on this machine, without the SLURM executor plugins' start-up probe.

Snakemake imports every installed executor plugin at start (``snakemake_interface_common.plugin_registry``: every
top-level module named ``snakemake_executor_plugin_*``). The SLURM plugin (the ``slurm`` extra, for ``selfsense run
--profile workflow/profiles/slurm``) then runs ``scontrol show config`` while building its option help; where SLURM's
client is installed and its controller cannot be reached, that call waits up to 10 s at every start (9 s measured on
the development machine). ``selfsense run`` starts Snakemake through this module when neither an executor nor a
profile is given (:func:`selfsense.cli.run.runs_locally`), so such a run never loads those plugins; any other run
starts ``python -m snakemake`` unchanged.

Started as a program, it ends its process as soon as Snakemake returns (:func:`selfsense.process.end_now`): no wait
for the timer thread Snakemake's job scheduler leaves behind (up to a second after the last job) and no teardown.

    python -m selfsense.cli._local_snakemake [snakemake options]
"""
from __future__ import annotations

import pkgutil
import sys

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


def main(argv: list[str] | None = None) -> int:
    """Snakemake's command line with ``argv``; its exit status (Snakemake ends with ``sys.exit``)."""
    from selfsense.process import exit_code

    hide_skipped_plugins()
    from snakemake.cli import main as snakemake_main

    try:
        snakemake_main(sys.argv[1:] if argv is None else argv)
    except SystemExit as stop:
        return exit_code(stop.code)
    return 0


if __name__ == "__main__":
    from selfsense.process import end_now

    end_now(main())
