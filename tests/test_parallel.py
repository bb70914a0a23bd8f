"""selfsense.parallel.fork_map: the items' results in their order, computed in forked processes where that is safe,
in threads or in turn where it is not; an exception reaches the caller.

The forking cases run in a fresh interpreter (:func:`_fresh`): a pytest-xdist worker runs an I/O thread beside the
tests, where :func:`~selfsense.parallel.can_fork` rightly refuses to fork."""
import os
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest

from selfsense.parallel import can_fork, fork_map

ROOT = Path(__file__).resolve().parents[1]


def _fresh(code: str, drop=()) -> str:
    """Run ``code`` in a new single-threaded interpreter (selfsense from this checkout), without the environment
    variables ``drop``; its stdout."""
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    return out.stdout


def test_results_in_order_from_forked_workers_that_inherit_unpicklable_state():
    out = _fresh("""
        import os
        from selfsense.parallel import can_fork, fork_map
        assert can_fork()
        big = {"data": list(range(1000))}
        pid_sq = lambda x: (os.getpid(), x * x, sum(big["data"][:x]))   # a closure: inherited, never pickled
        res = fork_map(pid_sq, range(7), 2)
        assert [r[1] for r in res] == [x * x for x in range(7)]
        assert [r[2] for r in res] == [sum(range(x)) for x in range(7)]
        assert {r[0] for r in res} - {os.getpid()}, "the work did not run in child processes"
        print("ok")
    """)
    assert out.strip() == "ok"


def test_a_worker_that_maps_again_runs_its_items_itself():
    out = _fresh("""
        import os
        from selfsense.parallel import fork_map
        inner = lambda x: (os.getpid(), x * x)
        outer = lambda x: fork_map(inner, [x, x + 1], 2)
        res = fork_map(outer, [1, 5], 2)
        assert [[r for _, r in o] for o in res] == [[1, 4], [25, 36]]
        # in the worker itself: a pool's worker may not have children
        assert all(len({p for p, _ in o}) == 1 and o[0][0] != os.getpid() for o in res)
        print("ok")
    """)
    assert out.strip() == "ok"


def test_an_exception_in_a_forked_worker_reaches_the_caller():
    out = _fresh("""
        from selfsense.parallel import fork_map
        def fail(x):
            if x == 2:
                raise ValueError(f"item {x} is bad")
            return x
        try:
            fork_map(fail, range(4), 2)
        except ValueError as e:
            print(e)
    """)
    assert out.strip() == "item 2 is bad"


def _pid_and_square(x):
    return os.getpid(), x * x


def test_one_worker_or_one_item_runs_here():
    assert fork_map(_pid_and_square, [3], 4) == [(os.getpid(), 9)]
    assert fork_map(_pid_and_square, [1, 2], 1) == [(os.getpid(), 1), (os.getpid(), 4)]


def test_with_another_thread_running_it_does_not_fork():
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert not can_fork()
        assert {p for p, _ in fork_map(_pid_and_square, range(4), 2)} == {os.getpid()}
        names = fork_map(lambda _: threading.current_thread().name, range(4), 2, threads_fallback=True)
        assert all(n.startswith("selfsense") for n in names)
        with pytest.raises(ValueError, match="item 2"):
            fork_map(lambda x: (_ for _ in ()).throw(ValueError("item 2")) if x == 2 else x, range(4), 2,
                     threads_fallback=True)
    finally:
        stop.set()
        t.join()


def test_threaded_workers_keep_one_blas_thread_while_another_leaves_its_own_limit():
    """In threads, a worker that leaves its own ``threadpool_limits(1)`` block (the Duhem fit's) while another is still
    inside one must not put the process's BLAS back on several threads under that one (its bits would then depend
    on timing: the cause of a rare mismatch of the threaded H(q) selection against the serial one). Forced order:
    worker 0 enters, worker 1 enters, worker 0 leaves, worker 1 reads its BLAS thread count. After the map the
    count is the one before it. In a fresh interpreter without the thread-count variables (an earlier test of this
    worker may have pinned this process, and its variables would pin the child too)."""
    from selfsense.determinism import THREAD_ENV_VARS

    code = """
        import threading, time
        from threadpoolctl import threadpool_info, threadpool_limits
        from selfsense.parallel import can_fork, fork_map

        def counts():
            return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})

        import numpy  # noqa: F401  (its BLAS loaded before the first count)
        if counts() != [2]:
            threadpool_limits(limits=2, user_api="blas")
        if counts() != [2]:
            print("skip", counts())
            raise SystemExit(0)
        e0_in, e1_in, left = threading.Event(), threading.Event(), threading.Event()

        def work(i):
            if i == 0:
                with threadpool_limits(limits=1):
                    e0_in.set()
                    assert e1_in.wait(30)
                left.set()
                return None
            assert e0_in.wait(30)
            with threadpool_limits(limits=1):
                e1_in.set()
                assert left.wait(30)
                time.sleep(0.01)
                return counts()

        stop = threading.Event()
        t = threading.Thread(target=stop.wait)
        t.start()
        try:
            assert not can_fork()
            got = fork_map(work, [0, 1], 2, threads_fallback=True)
        finally:
            stop.set()
            t.join()
        print("worker1", got[1], "after", counts())
    """
    out = _fresh(code, drop=THREAD_ENV_VARS)
    if out.startswith("skip"):
        pytest.skip(f"this machine's BLAS runs {out.split(' ', 1)[1].strip()} thread(s) at most: no second thread to "
                    "race for")
    assert out.strip() == "worker1 [1] after [2]", out
