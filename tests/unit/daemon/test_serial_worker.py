"""The evaluator's worker thread: calls in order, results and exceptions in futures, and a call
still running at exit does not keep the process alive."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
import time

import pytest

from edgedsm.daemon.worker import SerialWorker


def test_calls_run_in_order_on_one_thread_after_the_initializer() -> None:
    seen: list[tuple[str, int]] = []
    worker = SerialWorker("test-worker", initializer=lambda: seen.append((threading.current_thread().name, -1)))
    futures = [worker.submit(lambda i=i: seen.append((threading.current_thread().name, i)) or i * i) for i in range(20)]
    assert [future.result(timeout=5) for future in futures] == [i * i for i in range(20)]
    assert seen == [("test-worker", i) for i in range(-1, 20)]
    worker.shutdown()


def test_an_exception_reaches_the_future_and_the_next_call_still_runs() -> None:
    worker = SerialWorker("test-worker")
    failing = worker.submit(lambda: 1 / 0)
    after = worker.submit(lambda x: x + 1, 41)
    with pytest.raises(ZeroDivisionError):
        failing.result(timeout=5)
    assert after.result(timeout=5) == 42
    worker.shutdown()


def test_after_shutdown_queued_calls_run_then_the_thread_ends_and_new_calls_are_refused() -> None:
    worker = SerialWorker("test-worker")
    gate = threading.Event()
    first = worker.submit(gate.wait, 5)
    queued = worker.submit(lambda: "queued")
    worker.shutdown()
    with pytest.raises(RuntimeError, match="after shutdown"):
        worker.submit(lambda: None)
    gate.set()
    assert first.result(timeout=5) is True and queued.result(timeout=5) == "queued"
    deadline = time.monotonic() + 5
    while worker.alive and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not worker.alive


def test_a_call_still_running_does_not_hold_the_process_at_exit() -> None:
    # a ThreadPoolExecutor's worker is joined at interpreter exit: this call would hold it 60 s
    script = textwrap.dedent("""
        import time
        from edgedsm.daemon.worker import SerialWorker
        worker = SerialWorker("slow")
        worker.submit(time.sleep, 60)
        time.sleep(0.2)
        worker.shutdown()
    """)
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30, check=False)
    elapsed = time.monotonic() - started
    assert done.returncode == 0, done.stderr
    assert elapsed < 10, f"the process took {elapsed:.1f} s to exit"
