"""Signal handlers installed for a while and the previous ones put back after, so in-process
callers (tests, embedding code) keep theirs; and waiting on the main thread in slices, so that
they run.

Why slices: the kernel may hand a process-directed signal (Ctrl-C, SIGTERM) to any thread of the
process. Taken by another thread, it only flags Python's handler, which runs on the main thread at
its next bytecode: a main thread blocked in a plain ``Event.wait()`` or a long sleep would not see
it until that ends, or never."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator, Mapping
from types import FrameType

Handler = Callable[[int, FrameType | None], object]


@contextlib.contextmanager
def handling(handlers: Mapping[signal.Signals, Handler]) -> Iterator[None]:
    """Install ``handlers`` (main thread only); the previous ones are restored on the way out."""
    previous = {signum: signal.signal(signum, handler) for signum, handler in handlers.items()}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


#: Seconds the main thread blocks at most before the signal handlers flagged meanwhile run.
SIGNAL_SLICE_S = 0.25


def wait_for(event: threading.Event) -> None:
    """``event.wait()`` in slices of SIGNAL_SLICE_S, so that signal handlers run meanwhile (module
    docstring): returns once the event is set."""
    while not event.wait(SIGNAL_SLICE_S):
        pass
