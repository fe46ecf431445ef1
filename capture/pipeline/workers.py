"""Independent units of work shared between worker processes and the calling process.

The calling process usually has work of its own first (replay: tracking the ball),
so :class:`SharedWork` starts ``workers - 1`` processes in the background, hands them
units as they are added, and makes the caller join in once it asks for the results:
the caller then runs queued units itself while the workers run others, so that
``workers`` processes are busy in all, never more.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
import warnings
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait

from tqdm import tqdm


def _worker_start(initializer: Callable | None) -> None:
    """Worker processes leave Ctrl-C to the caller, which stops them."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if initializer is not None:
        initializer()


class SharedWork:
    """Run ``fn(unit)`` for every unit added, in ``workers`` processes including the caller.

    Parameters
    ----------
    fn : callable
        A module-level function (it is pickled by name for the worker processes).
    workers : int
        Processes in all; 1 runs everything in the calling process.
    preload : sequence of str
        Modules the worker processes import once before they start (forkserver preload).
    initializer : callable, optional
        Run in each worker process at its start.
    max_queued : int, optional
        Most units waiting for a worker (default ``2 * workers``): beyond that, :meth:`add`
        runs the oldest waiting unit in the caller, which bounds the memory held by queued
        units when the workers cannot keep up.

    Worker processes come from a forkserver (forking a process that has threads, as
    Zarr's or OpenCV's, can deadlock the child); they are started in a background
    thread at once, so that they are up when the first unit comes (a forkserver with
    replay's modules takes 0.6 s to start on an idle core, 1.7 s beside tracking: replay's
    first spin units were run by the caller, while it should have been tracking) and adding
    units never waits for them. :meth:`close` waits for a start under way. Use as a context
    manager.
    """

    def __init__(self, fn: Callable, workers: int, *, preload: Sequence[str] = (),
                 initializer: Callable | None = None, max_queued: int | None = None):
        if workers < 1:
            raise ValueError(f"workers must be positive, got {workers}")
        self._fn = fn
        self._n_pool = workers - 1
        self._max_queued = 2 * workers if max_queued is None else max_queued
        self._queue: deque = deque()
        self._futures: dict[Future, int] = {}
        self._results: dict[int, object] = {}
        self._n_units = 0
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.RLock()  # guards the queue, the futures and the pool
        self._closed = False
        self._ready = threading.Event()
        self._starter = threading.Thread(target=self._start, args=(list(preload), initializer),
                                         name="SharedWork-start") if self._n_pool else None
        if self._starter is None:
            self._ready.set()
        else:
            self._starter.start()

    def _start(self, preload, initializer) -> None:
        pool = None
        try:
            with self._lock:
                if self._closed:
                    return
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload(preload)
            pool = ProcessPoolExecutor(self._n_pool, mp_context=ctx, initializer=_worker_start,
                                       initargs=(initializer,))
            for f in [pool.submit(int) for _ in range(self._n_pool)]:  # the workers are up
                f.result()
        except (OSError, RuntimeError) as exc:  # no worker processes here: the caller does it all
            if pool is not None:
                pool.shutdown(cancel_futures=True)
            pool = None
            if not self._closed:
                warnings.warn(f"worker processes unavailable ({exc}); running in one process", RuntimeWarning)
        finally:
            with self._lock:
                closed = self._closed
                if not closed:
                    self._pool = pool
            if closed and pool is not None:  # closed while starting (close() waits for this)
                pool.shutdown(cancel_futures=True)
            self._ready.set()
            self._feed()

    def _feed(self, _done: Future | None = None) -> None:
        """Collect finished units; keep each worker busy with one unit and one queued.

        Also called from the pool's thread when a unit finishes.
        """
        with self._lock:
            for f in [f for f in self._futures if f.done()]:
                i = self._futures.pop(f)
                if not f.cancelled():
                    self._results[i] = f
            if self._pool is None or self._closed:
                return
            while self._queue and len(self._futures) < self._n_pool + 1:
                i, unit = self._queue.popleft()
                f = self._pool.submit(self._fn, unit)
                self._futures[f] = i
                f.add_done_callback(self._feed)

    def _run_one(self, newest: bool) -> bool:
        """Run one queued unit in the caller (the newest or the oldest); False if none is queued."""
        with self._lock:
            if not self._queue:
                return False
            i, unit = self._queue.pop() if newest else self._queue.popleft()
        self._results[i] = self._fn(unit)
        return True

    def add(self, unit) -> None:
        """Queue one unit; a free worker process takes it up at once. When more than ``max_queued``
        units wait (or there are no worker processes), the caller runs one itself."""
        with self._lock:
            self._queue.append((self._n_units, unit))
            self._n_units += 1
        self._feed()
        while len(self._queue) > (self._max_queued if self._n_pool else 0):
            self._run_one(newest=False)

    def results(self, progress: bool = False, desc: str = "work") -> list:
        """Run what is left (the caller takes part) and return every unit's result, in order added."""
        bar = tqdm(total=self._n_units, initial=len(self._results), unit="unit", desc=desc,
                   disable=not progress, leave=False)
        while True:
            before = len(self._results)
            self._feed()
            # the workers take units from the front, the caller from the back
            if not self._run_one(newest=True):
                with self._lock:
                    pending = list(self._futures)
                if not pending:
                    break
                wait(pending, return_when=FIRST_COMPLETED)
            bar.update(len(self._results) - before)
        bar.close()
        return [r.result() if isinstance(r, Future) else r for r in (self._results[i] for i in range(self._n_units))]

    def close(self) -> None:
        """Stop the worker processes (cancelling queued units), after a start under way."""
        with self._lock:
            self._closed = True
        if self._starter is not None:
            self._starter.join()  # a start under way shuts its pool down itself
        pool = self._pool
        if pool is not None:
            pool.shutdown(cancel_futures=True)

    def __enter__(self) -> SharedWork:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
