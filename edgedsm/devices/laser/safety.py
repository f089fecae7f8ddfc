"""Laser safety: the laser is off at start, at stop, on error and (if asked) on signals.

``LaserSafety(relay)`` is a context manager around any ``LaserRelay``:

* entering switches the laser off, so the measurement starts from a known state (if that
  fails, the error is raised and nothing runs with a laser in an unknown state);
* leaving switches it off, whether the block ended normally or by an exception
  (``KeyboardInterrupt`` included); a failed attempt is retried (``attempts``, default 2);
  then the port is released (``close=True``, the default);
* if the switching-off fails while another exception is on its way out, that exception stays
  in charge and carries a note saying the laser could not be switched off (also logged); if
  the block ended normally, the DeviceError is raised.

Signals are optional and explicit, because the daemon owns signal handling:
``LaserSafety(relay, signals=(signal.SIGTERM,))`` installs handlers (main thread only) for
the duration of the block and restores the previous ones after. The handler does no serial
I/O itself: it may have interrupted a half-finished exchange with the board. It raises
``SignalExit`` (a ``SystemExit`` with code 128 + signal number), and the laser is switched
off as that unwinds the stack through ``__exit__``, where the driver first drops any stale
answer. Signals that arrive while switching off are recorded, not raised, so a second
SIGTERM cannot cut the switching-off short. A caller that wants another exit status (the
daemon exits 0 on SIGTERM) catches ``SignalExit``.

Switching off on camera loss is the pipeline's business: it calls ``relay.off()``.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Iterable
from types import FrameType, TracebackType

from edgedsm.devices.laser.base import LaserRelay
from edgedsm.errors import DeviceError

log = logging.getLogger(__name__)


class SignalExit(SystemExit):
    """Raised by LaserSafety's signal handler; exit code 128 + signal number."""

    def __init__(self, signum: int) -> None:
        super().__init__(128 + signum)
        self.signum = signum

    def __str__(self) -> str:
        return f"stopped by {signal.Signals(self.signum).name}"


class LaserSafety:
    """Keep a laser relay off outside the block, whatever happens (see the module docstring)."""

    def __init__(self, relay: LaserRelay, *, signals: Iterable[int] = (), close: bool = True,
                 attempts: int = 2) -> None:
        if attempts < 1:
            raise ValueError("attempts must be at least 1")
        self.relay = relay
        self.signals = tuple(signals)
        self.close = close
        self.attempts = attempts
        #: The last signal received inside the block, or None.
        self.signalled: int | None = None
        #: Why the laser could not be switched off on the way out (None: it was).
        self.off_error: DeviceError | None = None
        self._previous: dict[int, object] = {}
        self._exiting = False

    # -- context manager --------------------------------------------------------------------

    def __enter__(self) -> LaserRelay:
        self._exiting = False
        self.off_error = None
        self._install()
        try:
            self.relay.off()
        except BaseException as exc:
            # Not switched off at start: do not run the block. Clean up as on the way out.
            self._leave(exc)
            raise
        return self.relay

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._leave(exc)

    # -- internals --------------------------------------------------------------------------

    def _leave(self, exc: BaseException | None) -> None:
        self._exiting = True  # from here on a signal is recorded, not raised
        try:
            error = self.off_error = self._switch_off()
            if self.close:
                # detach, not close: after a successful off, switching again is pointless;
                # after failed attempts, one more through close() would only cost a timeout.
                self.relay.detach()
        finally:
            self._restore()
        if error is None:
            return
        if exc is None:
            raise error
        log.error("%s: could not switch the laser off while handling %r: %s",
                  self.relay.description, exc, error)
        exc.add_note(f"the laser could not be switched off: {error}")

    def _switch_off(self) -> DeviceError | None:
        error: DeviceError | None = None
        for attempt in range(1, self.attempts + 1):
            try:
                self.relay.off()
                return None
            except DeviceError as failure:
                error = failure
                log.warning("%s: switching off failed (attempt %d of %d): %s",
                            self.relay.description, attempt, self.attempts, failure)
        return error

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        self.signalled = signum
        if self._exiting:
            log.warning("%s received while switching the laser off; finishing that first",
                        signal.Signals(signum).name)
            return
        raise SignalExit(signum)

    def _install(self) -> None:
        if not self.signals:
            return
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("LaserSafety can install signal handlers only in the main "
                               "thread; pass signals=() and handle signals there")
        for signum in self.signals:
            self._previous[signum] = signal.signal(signum, self._handler)

    def _restore(self) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)  # type: ignore[arg-type]
        self._previous.clear()
