"""Independent pieces of one job in processes of their own, with the same result as running them in turn.

The model fits of the calibration and of the gap diagnostic's recalibrations are Python-heavy (a trust-region loop,
many small NumPy calls): they hold the GIL most of the time, so threads take turns instead of sharing the cores.
:func:`fork_map` runs them in child processes forked from the job (the inputs are inherited, not pickled; only the
results travel back). Each piece is a deterministic function of inherited state, so the result has the same bits
for any number of workers, and in the same order as the items."""
from __future__ import annotations

import multiprocessing as mp
import threading
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")
R = TypeVar("R")

_FN: Callable | None = None   # the function of the running fork_map, inherited by the forked workers


def _call(item):
    return _FN(item)


def can_fork() -> bool:
    """Whether forking workers is safe here: the platform has ``fork``, this process runs one thread (a fork
    copies only the calling thread, so a lock held by another thread would stay locked in the child) and is not
    itself a pool's worker (those may not have children)."""
    return ("fork" in mp.get_all_start_methods() and threading.active_count() == 1
            and not mp.current_process().daemon)


def one_blas_thread():
    """A context in which the BLAS / OpenMP libraries loaded in this process run one thread each (threadpoolctl),
    the previous counts put back at its end. Results depend on the BLAS thread count in their last bits
    (:func:`selfsense.determinism.single_thread_blas`, which pins the process for good: the pipeline's jobs and the
    ``selfsense`` command); this scoped limit gives a library caller that has not pinned the process the same bits
    as they do. The limit is the process's: two threads that each enter and leave it at different times can still
    leave one of them unpinned for a while, so concurrent callers pin the process instead."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1)


def with_one_blas_thread(fn: Callable[..., R]) -> Callable[..., R]:
    """``fn`` run under :func:`one_blas_thread` at every call (its signature and docstring kept)."""
    import functools

    @functools.wraps(fn)
    def pinned(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)

    return pinned


def fork_map(fn: Callable[[T], R], items: Iterable[T], workers: int, threads_fallback: bool = False) -> list[R]:
    """``[fn(x) for x in items]``, with up to ``workers`` items at a time in forked child processes (taken in the
    order given as workers come free). Where forking is not possible (:func:`can_fork`: a job running in a thread of
    the Snakemake process), in threads with ``threads_fallback`` (each in a copy of the calling thread's context),
    else one item after another here; also with one worker or one item. An exception in ``fn`` is raised here."""
    global _FN
    items = list(items)
    workers = max(1, min(int(workers), len(items)))
    if workers == 1:
        return [fn(x) for x in items]
    if not can_fork():
        if not threads_fallback:
            return [fn(x) for x in items]
        import contextvars
        from concurrent.futures import ThreadPoolExecutor

        # one BLAS thread for the whole map, set here in the calling thread: a BLAS thread limit is the process's, not
        # a thread's, so a worker that leaves its own ``threadpool_limits(1)`` block (the Duhem fit's) would put the
        # count it found back while another worker is still inside its block -- that one's arithmetic would then run
        # on several BLAS threads and give other bits, depending on timing. Under this limit every nested block
        # finds one thread and puts one back
        with one_blas_thread(), ThreadPoolExecutor(workers, thread_name_prefix="selfsense") as pool:
            futs = [pool.submit(contextvars.copy_context().run, fn, x) for x in items]
            return [f.result() for f in futs]
    prev, _FN = _FN, fn
    try:
        with mp.get_context("fork").Pool(workers) as pool:
            return pool.map(_call, items, chunksize=1)
    finally:
        _FN = prev
