"""selfsense.parallel.fork_map: the items' results in their order, computed in forked processes where that is safe,
in threads or in turn where it is not; an exception reaches the caller."""
import os
import threading

import pytest

from selfsense.parallel import can_fork, fork_map


def _pid_and_square(x):
    return os.getpid(), x * x


def test_results_in_order_from_forked_workers():
    if not can_fork():
        pytest.skip("no fork here (platform, or another thread is running)")
    out = fork_map(_pid_and_square, range(7), 2)
    assert [r for _, r in out] == [x * x for x in range(7)]
    assert {p for p, _ in out} - {os.getpid()}   # the work ran in child processes


def test_inherited_state_is_used_not_pickled():
    big = {"data": list(range(1000))}
    local = lambda i: sum(big["data"][:i])  # noqa: E731 - a closure: unpicklable, inherited by the fork
    assert fork_map(local, [0, 10, 1000], 2) == [0, 45, sum(range(1000))]


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
    finally:
        stop.set()
        t.join()


def _fail(x):
    if x == 2:
        raise ValueError(f"item {x} is bad")
    return x


def test_an_exception_in_a_worker_reaches_the_caller():
    with pytest.raises(ValueError, match="item 2 is bad"):
        fork_map(_fail, range(4), 2)


def _nested(x):
    return fork_map(_pid_and_square, [x, x + 1], 2)


def test_a_worker_that_maps_again_runs_its_items_itself():
    if not can_fork():
        pytest.skip("no fork here")
    out = fork_map(_nested, [1, 5], 2)
    assert [[r for _, r in o] for o in out] == [[1, 4], [25, 36]]
    assert all(len({p for p, _ in o}) == 1 for o in out)   # in the worker itself: a pool's worker has no children
