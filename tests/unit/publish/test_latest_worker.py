"""The latest-job-per-key worker behind the map sender and the Home Assistant colour maps."""

from __future__ import annotations

import threading

from edgedsm.publish.latest_worker import LatestWorker


def test_a_newer_job_replaces_one_not_yet_taken_and_errors_do_not_stop_the_worker() -> None:
    gate = threading.Event()
    handled: list[tuple[str, int]] = []
    errors: list[str] = []

    def handle(key: str, job: int) -> None:
        gate.wait(5)
        if job < 0:
            raise ValueError("bad job")
        handled.append((key, job))

    worker: LatestWorker[int] = LatestWorker("test-worker", "job", handle, on_error=errors.append)
    worker.start()
    assert worker.submit("a", 1) is False
    assert not worker.flush(0.1)  # "a" 1 is in hand, held at the gate
    assert worker.submit("b", -1) is False
    assert worker.submit("c", 2) is False
    assert worker.submit("c", 3) is True  # replaces 2, not yet taken
    gate.set()
    assert worker.flush(5)
    assert handled == [("a", 1), ("c", 3)] and errors == ["b"]
    assert worker.submit("a", 4) is False and worker.flush(5) and handled[-1] == ("a", 4)
    worker.stop(timeout_s=2)
    assert not worker.thread.is_alive()


def test_keys_replaced_faster_than_the_worker_takes_them_all_get_their_turn() -> None:
    # maps s1, s2, s3 handed over every round while one takes longer than a round to send: each
    # must still go out in turn (re-queuing a replaced key at the end starved s2 and s3)
    handled: list[str] = []
    started = threading.Event()
    release = threading.Event()

    def handle(key: str, job: int) -> None:
        handled.append(key)
        started.set()
        release.wait(5)
        release.clear()

    worker: LatestWorker[int] = LatestWorker("test-fair", "job", handle)
    worker.start()
    for key in ("s1", "s2", "s3"):
        worker.submit(key, 0)
    for round_ in range(1, 7):
        assert started.wait(5)
        started.clear()
        for key in ("s1", "s2", "s3"):  # a new round arrives while one job is in hand
            worker.submit(key, round_)
        release.set()
    worker.stop(timeout_s=0.1)
    release.set()
    assert handled[:6] == ["s1", "s2", "s3", "s1", "s2", "s3"], handled
