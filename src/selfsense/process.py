"""The end of a pipeline process: a finished ``script:`` job (workflow/scripts) and the Snakemake process of a local
``selfsense run`` exit without the interpreter's teardown.

A normal exit, after the last line of a script, runs the exit handlers, then joins the threads that are still
running and tears down every module and object. That teardown took 0.22-0.34 s for each of the pipeline's script
jobs on ``tweezer_sim`` (from the job's last log line to the end of its process; each has loaded NumPy, pandas,
SciPy and numba kernels), 0.3 s for the Snakemake process, and Snakemake waits for a job's process to end before it
starts the jobs that need its outputs. Multiprocessing's forked workers end the same way (``os._exit`` after their
clean-up)."""
from __future__ import annotations

import atexit
import os
import sys
from typing import NoReturn

__all__ = ["end_now", "exit_code"]


def exit_code(code: object) -> int:
    """The exit status of ``SystemExit(code)`` as the interpreter would give it: 0 for None, the integer itself, 1 for
    anything else (printed to stderr, as the interpreter prints a message given to ``sys.exit``)."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    print(code, file=sys.stderr)
    return 1


def end_now(code: int = 0) -> NoReturn:
    """End this process with status ``code`` once its work is done and its files are closed: the exit handlers run
    (logging flushes and closes its handlers, numba and llvmlite note their shutdown) and the standard streams are
    flushed, as at a normal exit; the teardown of modules and objects is skipped, and so is the wait for threads
    still running (in the Snakemake process, the timer thread its job scheduler leaves behind, which only wakes the
    finished scheduler, up to a second after the last job). Only for the end of a process that has nothing left to
    do: never from a library call or a test."""
    atexit._run_exitfuncs()   # what the interpreter runs at a normal exit (CPython: every handler, in reverse order)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # closed or detached by the program: nothing left to write
            pass
    os._exit(code)
