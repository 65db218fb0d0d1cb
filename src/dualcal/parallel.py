"""Worker pools that stop at once on Ctrl-C.

:func:`interruptible_map` runs a function over items in worker threads and yields the results
in order. When the caller is interrupted (``KeyboardInterrupt``) or fails, the items not yet
started are cancelled, the running ones are told to stop (:func:`raise_if_cancelled`, which
:func:`dualcal.files.io.write_bytes_atomic` calls before it commits a file, so an interrupted run never
writes an output after the interruption), and the call returns only once no worker runs any
more: no thread or process is left behind.

Threads, not processes: the work (decoding, OpenCV, numpy's array loops) releases the GIL, threads
start at once, a Ctrl-C reaches only the main thread (a process pool's workers would each get it
too and print their own tracebacks), and nothing outlives the call.
"""

from __future__ import annotations

import contextvars
import threading
from collections.abc import Callable, Iterable, Iterator

__all__ = ["Cancelled", "interruptible_map", "raise_if_cancelled"]

# The stop event of the pool the current thread works for (unset outside a pool). Each call of
# interruptible_map has its own, so an interrupted call never affects a later one.
_STOP: contextvars.ContextVar[threading.Event | None] = contextvars.ContextVar("dualcal_stop", default=None)


class Cancelled(Exception):
    """Raised inside a worker whose pool was interrupted; the pool swallows it."""


def raise_if_cancelled() -> None:
    """Raise :class:`Cancelled` if the pool this thread works for was interrupted.

    Long work calls it between steps (e.g. between the bands of an image) to stop early; outside
    a pool it does nothing.
    """
    stop = _STOP.get()
    if stop is not None and stop.is_set():
        raise Cancelled("interrupted")


def interruptible_map(func: Callable, items: Iterable, jobs: int = 1) -> Iterator:
    """``func(item)`` for every item, in ``jobs`` threads, yielding the results in item order.

    With ``jobs == 1`` the items are processed in the calling thread, one after the other.
    If the consumer stops early, is interrupted or ``func`` raises, pending items are cancelled,
    running ones are asked to stop, and the exception propagates once every worker has ended.
    """
    items = list(items)
    if jobs <= 1 or len(items) <= 1:
        yield from map(func, items)
        return
    stop = threading.Event()

    def work(item):
        if stop.is_set():
            raise Cancelled("interrupted")
        token = _STOP.set(stop)
        try:
            return func(item)
        finally:
            _STOP.reset(token)

    from concurrent.futures import ThreadPoolExecutor

    pool = ThreadPoolExecutor(max_workers=min(jobs, len(items)))
    try:
        futures = [pool.submit(work, item) for item in items]
        for future in futures:
            yield future.result()
    finally:
        stop.set()
        pool.shutdown(wait=True, cancel_futures=True)
