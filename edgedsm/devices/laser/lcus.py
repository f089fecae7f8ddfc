"""LCUS relay boards (LC Technology, CH340 USB-serial chip; LCUS-1/2/4/8).

Protocol (9600 baud, 8N1; board documentation as quoted in public drivers, e.g.
jarwyg/USB_RELAY and exmakhina/xm_tesmes ``relay_lcus.py``): four bytes per command::

    A0  channel  state  checksum        state 01 = on (closed), 00 = off (open)
    checksum = (0xA0 + channel + state) & 0xFF

    A0 01 01 A2   relay 1 on
    A0 01 00 A1   relay 1 off

The board never answers, so there is no readback: ``state()`` reports the last command,
marked as unconfirmed, and a dead board cannot be told from a live one.
"""

from __future__ import annotations

from edgedsm.devices.laser._serial import SerialRelay

START = 0xA0


def checksum(channel: int, on: bool) -> int:
    """The fourth byte: (0xA0 + channel + state) & 0xFF."""
    return (START + channel + int(on)) & 0xFF


def encode_switch(channel: int, on: bool) -> bytes:
    """The 4-byte command that switches ``channel`` (1..255) on or off."""
    if not 1 <= channel <= 0xFF:
        raise ValueError(f"LCUS channel must be 1..255, not {channel}")
    return bytes((START, channel, int(on), checksum(channel, on)))


class LcusRelay(SerialRelay):
    """LCUS/CH340 relay board: write-only, no readback."""

    protocol = "lcus"
    supports_readback = False

    def _do_switch(self, on: bool) -> None:
        self._send(encode_switch(self.channel, on))
