"""SharedWork: units of work shared between worker processes and the calling process."""

import os
import time

import pytest

from capture.pipeline.workers import SharedWork


def _slow_square(x):
    time.sleep(0.05)
    if x < 0:
        raise ValueError(f"negative unit {x}")
    return x * x, os.getpid()


def test_shared_work_returns_every_result_in_order_from_both_processes():
    with SharedWork(_slow_square, 2) as work:
        for i in range(60):
            work.add(i)
        out = work.results()
    assert [r for r, _ in out] == [i * i for i in range(60)]
    pids = {p for _, p in out}
    assert os.getpid() in pids and len(pids) == 2  # the caller and one worker process shared it


def test_shared_work_feeds_the_workers_while_the_caller_is_busy_and_bounds_the_queue():
    with SharedWork(_slow_square, 2) as work:
        for i in range(8):
            work.add(i)
        time.sleep(3.0)  # the caller's own work (tracking): the worker goes on meanwhile
        done_early = sum(f.done() for f in work._results.values() if hasattr(f, "done"))
        out = work.results()
    assert done_early >= 4 and [r for r, _ in out] == [i * i for i in range(8)]
    with SharedWork(_slow_square, 2, max_queued=2) as work:
        for i in range(12):
            work.add(i)
            assert len(work._queue) <= 2  # the caller takes on work rather than queueing it all
        out = work.results()
    assert [r for r, _ in out] == [i * i for i in range(12)]
    assert os.getpid() in {p for _, p in out}


def test_shared_work_in_one_process_and_errors():
    with SharedWork(_slow_square, 1) as work:
        for i in range(3):
            work.add(i)
        assert [r for r, _ in work.results()] == [0, 1, 4]
        assert {p for _, p in work.results()} == {os.getpid()}
    with SharedWork(_slow_square, 2) as work:
        work.add(2)
        work.add(-1)
        with pytest.raises(ValueError, match="negative unit -1"):
            work.results()
    with pytest.raises(ValueError, match="workers must be positive"):
        SharedWork(_slow_square, 0)


def test_shared_work_starts_its_workers_before_the_first_unit():
    """The pool comes up while the caller does its own work first (replay: tracking up to the
    first spin unit), so that the first units go to a worker, not to the caller."""
    with SharedWork(_slow_square, 2, max_queued=1) as work:
        assert work._ready.wait(60) and work._pool is not None  # no unit added yet
        work.add(3)
        out = work.results()
    assert out[0][0] == 9 and out[0][1] != os.getpid()


def test_shared_work_closed_while_its_workers_start_leaves_no_process():
    import multiprocessing

    work = SharedWork(_slow_square, 2)
    work.close()  # at once: the start is under way
    assert not work._starter.is_alive() and work._pool is None
    assert not [p for p in multiprocessing.active_children() if p.name.startswith("SpawnProcess")
                or p.name.startswith("ForkServerProcess")]
