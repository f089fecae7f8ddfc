"""The laser relay contract: checks every relay driver must pass, real and emulated alike.

The laser must be off whenever it is not needed and on every failure path. These checks
switch your driver through its public methods and watch the contact *independently of the
driver* (an emulated board, a simulated one, or on hardware a second channel, a photodiode,
a multimeter polled by code): a driver cannot vouch for itself. Describe your set-up with a
:class:`RelayRig` and run :func:`check_relay_contract`, or the checks one by one from
:data:`RELAY_CHECKS`. A failed check raises ``AssertionError``; no pytest is needed.
See docs/drivers.md.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from edgedsm.devices.laser import LaserRelay, LaserSafety
from edgedsm.errors import DeviceError
from edgedsm.testing._expect import check, eventually, expect_error


class _ContractError(RuntimeError):
    """The error the checks raise inside a with-block to test the failure path."""


@dataclass
class RelayRig:
    """How the relay checks reach your driver and the contact behind it.

    ``open``: returns a new, open driver instance (e.g. ``lambda: open_relay(uri)``); called
    once or more per check, each instance is closed by the check.
    ``is_on``: the contact's real state, seen without the driver under test.
    ``readback``: whether the driver must report readback (``relay.readback``).
    ``force``: sets the contact behind the driver's back ("someone left the laser on"); without
    it, the check of switching off at start only checks switching off on error.
    ``settle_s``: how long the contact may take to follow (boards that never answer switch
    after the driver has returned).
    """

    open: Callable[[], LaserRelay]
    is_on: Callable[[], bool]
    readback: bool
    force: Callable[[bool], None] | None = None
    settle_s: float = 2.0

    def settled(self, on: bool) -> bool:
        """Whether the contact reaches ``on`` within ``settle_s``."""
        return eventually(lambda: self.is_on() == on, self.settle_s)

    def expect(self, on: bool, when: str) -> None:
        check(self.settled(on), f"the contact is {'off' if on else 'ON'} {when} "
                                f"(expected {'on' if on else 'off'} within {self.settle_s:g} s)")


def check_relay_close_leaves_it_off(rig: RelayRig) -> None:
    """close() switches off; closing again is harmless; a closed relay refuses on()."""
    relay = rig.open()
    try:
        relay.on()
        rig.expect(True, "after on()")
        relay.close()
        rig.expect(False, "after close()")
        relay.close()
        with expect_error(DeviceError, "closed", f"{relay!r}: on() after close()"):
            relay.on()
        rig.expect(False, "after on() on a closed relay")
    finally:
        relay.close()  # a failed check must not leave the laser on


def check_relay_closed_refuses(rig: RelayRig) -> None:
    """After close(): on(), off() and state() raise DeviceError; close() and detach() do nothing."""
    relay = rig.open()
    relay.close()
    relay.close()
    relay.detach()
    for method in (relay.on, relay.off, relay.state):
        with expect_error(DeviceError, "closed", f"{relay!r}: {method.__name__}() after close()"):
            method()
    rig.expect(False, "after close()")


def check_relay_exit_on_exception_leaves_it_off(rig: RelayRig) -> None:
    """An exception leaving the relay's with-block switches the laser off and stays in charge."""
    with expect_error(_ContractError, "camera lost", "the error raised in the with-block"), \
            rig.open() as relay:
        relay.on()
        rig.expect(True, "after on()")
        raise _ContractError("camera lost")
    rig.expect(False, "after an exception left the with-block")


def check_relay_safety_off_at_start_and_on_error(rig: RelayRig) -> None:
    """LaserSafety switches a laser someone left on off at start, and off again on an error."""
    if rig.force is not None:
        rig.force(True)  # someone left the laser on
        rig.expect(True, "after forcing it on behind the driver's back")
    with expect_error(_ContractError, "bad frame", "the error raised under LaserSafety"), \
            LaserSafety(rig.open()) as relay:
        rig.expect(False, "at the start of LaserSafety")
        relay.on()
        rig.expect(True, "after on() under LaserSafety")
        raise _ContractError("bad frame")
    rig.expect(False, "after an error under LaserSafety")


def check_relay_readback_is_reported_honestly(rig: RelayRig) -> None:
    """``readback`` is what the rig says; on() is confirmed only with readback; state() says on."""
    with rig.open() as relay:
        check(relay.readback is rig.readback, f"{relay!r}: readback is {relay.readback}, "
                                              f"the board {'has' if rig.readback else 'has no'} readback")
        status = relay.on()
        check(status.confirmed is rig.readback,
              f"{relay!r}: on() says confirmed={status.confirmed} with readback={rig.readback}")
        check(relay.state().on is True, f"{relay!r}: state() after on() says {relay.state().describe()}")
    rig.expect(False, "after the with-block")


def check_relay_sigterm_leaves_it_off(rig: RelayRig) -> None:
    """SIGTERM under LaserSafety(signals=(SIGTERM,)) exits with the laser off (main thread only:
    raises RuntimeError elsewhere, since Python delivers signals to the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("check_relay_sigterm_leaves_it_off must run in the main thread")
    safety = LaserSafety(rig.open(), signals=(signal.SIGTERM,))
    with expect_error(SystemExit, None, "SIGTERM under LaserSafety"), safety as relay:
        relay.on()
        rig.expect(True, "after on()")
        signal.raise_signal(signal.SIGTERM)
        time.sleep(5)  # the handler raises SystemExit long before this ends
    rig.expect(False, "after SIGTERM")


RELAY_CHECKS: dict[str, Callable[[RelayRig], None]] = {
    "close_leaves_it_off": check_relay_close_leaves_it_off,
    "closed_refuses": check_relay_closed_refuses,
    "exit_on_exception_leaves_it_off": check_relay_exit_on_exception_leaves_it_off,
    "safety_off_at_start_and_on_error": check_relay_safety_off_at_start_and_on_error,
    "readback_is_reported_honestly": check_relay_readback_is_reported_honestly,
    "sigterm_leaves_it_off": check_relay_sigterm_leaves_it_off,
}
"""Every relay check by name, in the order :func:`check_relay_contract` runs them."""


def check_relay_contract(rig: RelayRig) -> None:
    """Run every relay check against ``rig``; the first failure raises AssertionError."""
    for relay_check in RELAY_CHECKS.values():
        relay_check(rig)
