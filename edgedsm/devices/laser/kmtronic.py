"""KMTronic USB relay boards (FTDI USB-serial; 1, 2, 4 and 8 relays).

Protocol (9600 baud, 8N1; KMTronic's own Arduino examples, kmtronic-ltd/
arduino-control-rs485-relays, and public drivers that read the status):

* switch: three bytes ``FF ch state``, relay ``ch`` 1..8, state ``01`` on, ``00`` off;
  the board does not answer;
* status of all relays (4- and 8-relay boards): ``FF 09 00``; the board answers one byte
  per relay, ``00`` off or ``01`` on, relay 1 first;
* status of one relay (1- and 2-relay boards): ``FF ch 03``; the board answers
  ``FF ch state``.

Which status request is used follows the number of relays on the board (URI ``relays=``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from edgedsm.devices.laser._serial import SerialRelay, hexdump
from edgedsm.devices.uri import RelaySpec
from edgedsm.errors import DeviceError

if TYPE_CHECKING:
    from serial import SerialBase

HEADER = 0xFF
STATUS_ALL = bytes((0xFF, 0x09, 0x00))
RELAY_COUNTS = (1, 2, 4, 8)


def _check_channel(channel: int) -> None:
    if not 1 <= channel <= 8:
        raise ValueError(f"KMTronic relay must be 1..8, not {channel}")


def encode_switch(channel: int, on: bool) -> bytes:
    """``FF ch 01`` (on) or ``FF ch 00`` (off)."""
    _check_channel(channel)
    return bytes((HEADER, channel, int(on)))


def encode_status(channel: int, relays: int) -> bytes:
    """The status request for a board with ``relays`` relays (see the module docstring)."""
    _check_channel(channel)
    if relays not in RELAY_COUNTS:
        raise ValueError(f"KMTronic boards have 1, 2, 4 or 8 relays, not {relays}")
    return STATUS_ALL if relays > 2 else bytes((HEADER, channel, 0x03))


def status_length(relays: int) -> int:
    """Bytes in the answer to ``encode_status``: one per relay, or FF ch state."""
    return relays if relays > 2 else 3


def _state_byte(value: int, what: str, answer: bytes) -> bool:
    if value not in (0, 1):
        raise DeviceError(f"KMTronic board reported {what} as {value:#04x}, expected 00 or 01 "
                          f"(answer {hexdump(answer)})")
    return value == 1


def decode_status(answer: bytes, channel: int, relays: int) -> bool:
    """The state of ``channel`` from the answer to ``encode_status(channel, relays)``."""
    _check_channel(channel)
    if len(answer) != status_length(relays):
        raise DeviceError(f"KMTronic status answer has {len(answer)} bytes, expected "
                          f"{status_length(relays)}: {hexdump(answer)}")
    if relays > 2:
        states = [_state_byte(b, f"relay {i}", answer) for i, b in enumerate(answer, 1)]
        return states[channel - 1]
    if answer[0] != HEADER or answer[1] != channel:
        raise DeviceError(f"KMTronic status answer for relay {channel} should start "
                          f"FF {channel:02X}: {hexdump(answer)}")
    return _state_byte(answer[2], f"relay {channel}", answer)


class KmtronicRelay(SerialRelay):
    """KMTronic USB relay board; readback through the status request."""

    protocol = "kmtronic"
    supports_readback = True

    def __init__(self, port: SerialBase, *, channel: int, timeout: float = 0.5,
                 verify: bool = True, description: str | None = None, relays: int = 8) -> None:
        super().__init__(port, channel=channel, timeout=timeout, verify=verify,
                         description=description)
        if relays not in RELAY_COUNTS or self.channel > relays:
            raise ValueError(f"KMTronic relay {self.channel} does not exist on a "
                             f"{relays}-relay board")
        self.relays = relays

    @classmethod
    def _spec_options(cls, spec: RelaySpec) -> dict[str, Any]:
        return {"relays": spec.options.get("relays", 8)}

    def _do_switch(self, on: bool) -> None:
        self._send(encode_switch(self.channel, on))

    def _do_read_state(self) -> bool:
        deadline = self._send(encode_status(self.channel, self.relays))
        count = status_length(self.relays)
        what = f"the status request (a {self.relays}-relay board answers {count} bytes; " \
               f"set relays= to match the board)"
        answer = self._read_exact(count, deadline, what)
        return decode_status(answer, self.channel, self.relays)
