"""One background thread that runs submitted calls in order and returns futures: the evaluator
thread. Unlike a ``ThreadPoolExecutor``, whose workers the interpreter joins at exit, its thread
is a daemon thread, so a call still running when the daemon stops (bounded by the evaluator's
``finish``) cannot keep the process alive past SIGTERM: stopping promises an exit within 2 s."""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

T = TypeVar("T")

_STOP = object()


class SerialWorker:
    """Runs ``submit``-ted calls one after the other on one daemon thread."""

    def __init__(self, name: str, initializer: Callable[[], None] | None = None) -> None:
        self._calls: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._initializer = initializer
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, fn: Callable[..., T], *args: Any) -> Future[T]:
        """``fn(*args)`` after every call submitted before it; its result or exception in the future."""
        if self._closed:
            raise RuntimeError(f"{self._thread.name}: no call is taken after shutdown")
        future: Future[T] = Future()
        self._calls.put((future, fn, args))
        return future

    def shutdown(self) -> None:
        """Take no more calls; those queued still run, and the thread then ends (not waited for)."""
        if not self._closed:
            self._closed = True
            self._calls.put(_STOP)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _run(self) -> None:
        if self._initializer is not None:
            self._initializer()
        while (item := self._calls.get()) is not _STOP:
            future, fn, args = item
            if not future.set_running_or_notify_cancel():
                continue
            try:
                result = fn(*args)
            except BaseException as exc:  # handed to whoever waits on the future, as an executor does
                future.set_exception(exc)
            else:
                future.set_result(result)
