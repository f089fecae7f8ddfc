"""Waveshare's "flash on" request for the Modbus relay's pulse mode, and its URI option."""

from __future__ import annotations

import pytest

from edgedsm.devices.laser import modbus
from edgedsm.devices.uri import parse_relay_uri

H = bytes.fromhex


def test_flash_on_known_vector() -> None:
    # Waveshare Modbus RTU Relay manual: relay 0 of slave 1 on for 700 ms, then off by itself
    assert modbus.encode_flash_on(1, 0, 0.7) == H("01 05 02 00 00 07 8D B0")


def test_flash_on_fields() -> None:
    request = modbus.encode_flash_on(7, 5, 6553.5)
    assert request[:6] == H("07 05 02 05 FF FF")
    assert modbus.check_frame(request) == request[:6]
    # its echo is accepted like any write-coil answer
    modbus.decode_write_coil(request, request)


@pytest.mark.parametrize(("channel", "pulse"), [(256, 1.0), (0, 0.0), (0, 6553.6)])
def test_flash_on_refuses_what_the_board_cannot_do(channel: int, pulse: float) -> None:
    with pytest.raises(ValueError, match="flash on needs"):
        modbus.encode_flash_on(1, channel, pulse)


def test_uri_option() -> None:
    spec = parse_relay_uri("serial:/dev/ttyUSB0?protocol=modbus&channel=3&pulse=2.5")
    assert spec.options == {"slave": 1, "parity": "N", "pulse": 2.5}
    assert "pulse" not in parse_relay_uri("serial:/dev/ttyUSB0?protocol=modbus").options
