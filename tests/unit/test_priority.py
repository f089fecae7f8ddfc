"""Threads whose work can wait run nicer than the engine's (edgedsm.priority)."""

from __future__ import annotations

import os
import sys
import threading

import pytest

from edgedsm.priority import lower_priority
from edgedsm.publish.latest_worker import WORKER_NICE, LatestWorker

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice values are Linux's")


def thread_nice() -> int:
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


def test_only_the_calling_thread_gets_nicer() -> None:
    process = os.getpriority(os.PRIO_PROCESS, os.getpid())
    seen: list[int] = []

    def body() -> None:
        lower_priority(3)
        seen.append(thread_nice())

    thread = threading.Thread(target=body)
    thread.start()
    thread.join(5)
    assert seen == [min(19, process + 3)]
    assert thread_nice() == process and os.getpriority(os.PRIO_PROCESS, os.getpid()) == process


def test_map_workers_and_the_evaluator_run_nicer_than_the_pipeline() -> None:
    from edgedsm.daemon.evaluator import EVALUATOR_NICE, yield_cores

    process = os.getpriority(os.PRIO_PROCESS, os.getpid())
    seen: dict[str, int] = {}
    worker: LatestWorker[int] = LatestWorker("test-nice", "job", lambda key, job: seen.update({key: thread_nice()}))
    worker.start()
    worker.submit("map", 1)
    assert worker.flush(5)
    worker.stop(timeout_s=2)
    evaluator = threading.Thread(target=lambda: (yield_cores(), seen.update(evaluator=thread_nice())))
    evaluator.start()
    evaluator.join(5)
    assert seen == {"map": min(19, process + WORKER_NICE), "evaluator": min(19, process + EVALUATOR_NICE)}
    assert WORKER_NICE > EVALUATOR_NICE > 0  # maps wait longest; the states every 0.5 s less
