"""Waiting on the main thread in slices: a signal that another thread takes still runs its handler."""

from __future__ import annotations

import signal
import threading
import time

from edgedsm.signals import SIGNAL_SLICE_S, handling, wait_for


def _signal_from_another_thread(delay_s: float) -> threading.Thread:
    # sent to the sender's own thread: there Python only flags the handler for the main thread
    sender = threading.Thread(target=lambda: (time.sleep(delay_s), signal.pthread_kill(threading.get_ident(),
                                                                                        signal.SIGUSR1)), daemon=True)
    sender.start()
    return sender


def test_wait_for_returns_soon_after_a_signal_taken_by_another_thread() -> None:
    stop = threading.Event()
    with handling({signal.SIGUSR1: lambda *_: stop.set()}):
        sender = _signal_from_another_thread(0.2)
        started = time.monotonic()
        wait_for(stop)
        waited = time.monotonic() - started
        sender.join(5)
    assert stop.is_set() and waited < 0.2 + 4 * SIGNAL_SLICE_S, waited


def test_a_plain_wait_does_not_see_it_until_its_timeout() -> None:
    # what wait_for is for: the same signal leaves a plain wait blocked for its whole timeout
    stop = threading.Event()
    with handling({signal.SIGUSR1: lambda *_: stop.set()}):
        sender = _signal_from_another_thread(0.2)
        started = time.monotonic()
        stop.wait(3.0)
        waited = time.monotonic() - started
        sender.join(5)
    assert waited >= 2.9 and stop.is_set()  # the handler ran once the main thread woke
