"""The laser relay contract: what every relay driver, real or simulated, promises.

Public methods (``on``, ``off``, ``state``, ``close``, ``detach``) hold the rules: locking,
the closed check, the readback check, and the promise that closing switches the laser off.
Drivers implement only the private hooks, in the python-microscope style:

``_do_switch(on)``
    Send one switching command; return when the board has taken it (or at once for boards
    that never answer). Must be bounded in time: raise ``DeviceTimeout`` when an answer the
    board owes does not come within the driver's timeout.
``_do_read_state()``
    Ask the board whether the relay is closed (``True``) or open (``False``). Only drivers
    with ``supports_readback = True`` implement it.
``_do_close()``
    Release the port. Called once; never switches anything.

Errors are ``DeviceError`` (the board answered nonsense), ``DeviceTimeout`` (it did not answer
in time) and ``DeviceLost`` (the port went away), all from ``edgedsm.errors``.
"""

from __future__ import annotations

import abc
import logging
import threading
from dataclasses import dataclass
from types import TracebackType
from typing import ClassVar, Self

from edgedsm.errors import DeviceError

log = logging.getLogger(__name__)


def _word(on: bool | None) -> str:
    return "unknown" if on is None else ("on" if on else "off")


@dataclass(frozen=True)
class RelayStatus:
    """What is known about the relay after an operation.

    ``on`` is ``None`` when the state is unknown (a board without readback that has not been
    switched in this session). ``confirmed`` is True when the board itself reported the state,
    False when it is only what was last commanded.
    """

    on: bool | None
    confirmed: bool

    def describe(self) -> str:
        """One human line, e.g. ``on (readback confirmed)``."""
        if self.on is None:
            return "unknown (this board cannot report its state)"
        if self.confirmed:
            return f"{_word(self.on)} (readback confirmed)"
        return f"{_word(self.on)} (as commanded; this board has no readback)"


class LaserRelay(abc.ABC):
    """A relay that switches the laser: abstract base of every relay driver.

    Use it as a context manager (or call ``close()``): leaving it switches the laser off,
    also when an exception is on its way out. Methods are thread-safe: the pipeline, a
    command handler and a shutdown path may call them concurrently.
    """

    #: True when the driver can ask the board for the relay's real state.
    supports_readback: ClassVar[bool] = False

    def __init__(self, *, verify: bool = True, description: str = "laser relay") -> None:
        self.verify = verify
        self.description = description
        # Re-entrant: a subclass hook or a nested safety helper may call a public method again.
        self._lock = threading.RLock()
        self._closed = False
        self._commanded: bool | None = None  # last state we know the board accepted

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.description}{' closed' if self._closed else ''}>"

    # -- public contract --------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        """True once ``close()`` or ``detach()`` has run."""
        return self._closed

    @property
    def readback(self) -> bool:
        """True when this relay's ``state()`` comes from the board, not from memory."""
        return self.supports_readback

    def on(self) -> RelayStatus:
        """Switch the laser on; with readback, confirm the board really switched."""
        return self._switch(True)

    def off(self) -> RelayStatus:
        """Switch the laser off; with readback, confirm the board really switched."""
        return self._switch(False)

    def state(self) -> RelayStatus:
        """The relay's state: read from the board where it can tell, else the last command."""
        with self._lock:
            self._check_open()
            if self.readback:
                return RelayStatus(self._do_read_state(), confirmed=True)
            return RelayStatus(self._commanded, confirmed=False)

    def close(self) -> None:
        """Switch the laser off, then release the port. Safe to call more than once.

        The port is released even when switching off fails; the failure is then raised so
        that the caller knows the laser may still be on.
        """
        with self._lock:
            if self._closed:
                return
            try:
                self._switch(False)
            finally:
                self._release()

    def detach(self) -> None:
        """Release the port WITHOUT switching: the relay stays as it is.

        Only for tools that must not change the state (``edgedsm laser status``) or that were
        told explicitly to leave the laser on. Everything else uses ``close()``.
        """
        with self._lock:
            if self._closed:
                return
            if self._commanded is not False:
                log.warning("%s: released without switching off (last command: %s)",
                            self.description, _word(self._commanded))
            self._release()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            self.close()
        except DeviceError as close_error:
            if exc is None:
                raise
            # Keep the original error in charge, but never hide that the laser may be on.
            log.error("%s: could not switch the laser off while handling %r: %s",
                      self.description, exc, close_error)
            exc.add_note(f"the laser could not be switched off on the way out: {close_error}")

    # -- hooks for drivers ------------------------------------------------------------------

    @abc.abstractmethod
    def _do_switch(self, on: bool) -> None:
        """Send one switching command to the board (bounded in time)."""

    def _do_read_state(self) -> bool:
        """Ask the board whether the relay is on; only for drivers with readback."""
        raise NotImplementedError(f"{type(self).__name__} has no readback")

    @abc.abstractmethod
    def _do_close(self) -> None:
        """Release the port; never switches."""

    # -- internals --------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceError(f"{self.description}: the relay is closed")

    def _switch(self, on: bool) -> RelayStatus:
        with self._lock:
            self._check_open()
            # Unknown until the board has taken the command: a failure half-way leaves the
            # relay in an unknown state, never in a falsely "known off" one.
            self._commanded = None
            self._do_switch(on)
            self._commanded = on
            log.info("%s: switched %s", self.description, _word(on))
            if not (self.verify and self.readback):
                return RelayStatus(on, confirmed=False)
            actual = self._do_read_state()
            if actual != on:
                self._commanded = None
                raise DeviceError(f"{self.description}: commanded {_word(on)} but the board "
                                  f"reports {_word(actual)} (stuck relay or wiring fault?)")
            return RelayStatus(on, confirmed=True)

    def _release(self) -> None:
        self._closed = True
        try:
            self._do_close()
        except Exception as exc:  # the port is gone either way; nothing more to do with it
            log.warning("%s: error while releasing the port: %s", self.description, exc)
