"""Interruptible worker pools: results in order, errors propagate, an interruption stops every worker."""

import signal
import threading
import time

import pytest

from dualcal.files.io import write_text_atomic
from dualcal.parallel import Cancelled, interruptible_map, raise_if_cancelled


@pytest.mark.parametrize("jobs", [1, 3])
def test_results_come_in_item_order(jobs):
    def slow_square(x):
        time.sleep(0.01 * (5 - x % 5))
        return x * x

    assert list(interruptible_map(slow_square, range(12), jobs)) == [x * x for x in range(12)]


def test_an_error_in_a_worker_propagates_and_later_items_are_not_started():
    started = []

    def work(x):
        started.append(x)
        if x == 0:
            raise ZeroDivisionError("a bug")
        time.sleep(0.05)
        return x

    with pytest.raises(ZeroDivisionError):
        list(interruptible_map(work, range(40), 2))
    assert len(started) < 10


def test_ctrl_c_cancels_pending_items_and_stops_running_ones():
    """SIGINT while the caller waits: running workers stop at their next check, none is left."""
    started, finished = [], []

    def work(x):
        started.append(x)
        for _ in range(200):                 # 1 s of work, checking between its steps
            raise_if_cancelled()
            time.sleep(0.005)
        finished.append(x)
        return x

    before = threading.active_count()
    main = threading.main_thread().ident
    timer = threading.Timer(0.2, lambda: signal.pthread_kill(main, signal.SIGINT))
    t0 = time.monotonic()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        for _ in interruptible_map(work, range(20), 2):
            pass
    assert time.monotonic() - t0 < 0.9        # not the 1 s each running item would take
    assert finished == [] and sorted(started) == [0, 1]
    assert threading.active_count() == before


def test_an_interrupted_pool_commits_no_file(tmp_path):
    """A worker still writing when the pool is interrupted leaves the earlier file as it was."""
    out = tmp_path / "out.txt"
    out.write_text("earlier")
    writing = threading.Event()

    def work(x):
        if x == 0:
            return x
        writing.set()
        time.sleep(0.3)                       # the pool is interrupted meanwhile
        write_text_atomic(out, "new")
        return x

    results = interruptible_map(work, [0, 1], 2)
    with pytest.raises(KeyboardInterrupt):
        for _ in results:
            writing.wait(5)
            raise KeyboardInterrupt
    assert out.read_text() == "earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_outside_a_pool_nothing_is_cancelled():
    raise_if_cancelled()
    assert issubclass(Cancelled, Exception)
