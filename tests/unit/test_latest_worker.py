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
