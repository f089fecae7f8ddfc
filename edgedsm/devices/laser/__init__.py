"""Laser relays: one contract (``LaserRelay``), drivers for real boards, a simulator.

Open any relay from its URI (grammar in ``edgedsm.devices.uri``)::

    from edgedsm.devices.laser import LaserSafety, open_relay

    with LaserSafety(open_relay("serial:/dev/ttyUSB0?protocol=lcus&channel=1")) as laser:
        laser.on()
        ...                       # off again on exit, on error and (if asked) on SIGTERM

Drivers: ``LcusRelay`` (LCUS/CH340), ``NumatoRelay`` (Numato ASCII), ``KmtronicRelay``
(KMTronic), ``ModbusCoilRelay`` (Modbus RTU coil), ``SimulatedRelay``.
"""

from __future__ import annotations

from edgedsm.devices.laser._serial import PortLocked, SerialRelay, open_port
from edgedsm.devices.laser.base import LaserRelay, RelayStatus
from edgedsm.devices.laser.kmtronic import KmtronicRelay
from edgedsm.devices.laser.lcus import LcusRelay
from edgedsm.devices.laser.modbus import ModbusCoilRelay
from edgedsm.devices.laser.numato import NumatoRelay
from edgedsm.devices.laser.safety import LaserSafety, SignalExit
from edgedsm.devices.laser.sim import (
    SimulatedBoard,
    SimulatedRelay,
    Switching,
    forget_simulated_boards,
    simulated_board,
)
from edgedsm.devices.uri import RelaySpec, parse_relay_uri

DRIVERS: dict[str, type[SerialRelay]] = {
    "lcus": LcusRelay,
    "numato": NumatoRelay,
    "kmtronic": KmtronicRelay,
    "modbus": ModbusCoilRelay,
}


def open_relay(uri: str | RelaySpec, *, exclusive: bool = True) -> LaserRelay:
    """Open the relay a URI names. Bad URI: ConfigError; port trouble: DeviceError (a serial
    port another process holds locked: ``PortLocked``).

    Opening never switches: wrap the relay in ``LaserSafety`` (or switch it off yourself)
    to start from a known state. ``exclusive=False`` opens a serial port without its lock:
    only to switch off (``edgedsm laser off``, docs/laser-safety.md), never to switch on.
    """
    spec = uri if isinstance(uri, RelaySpec) else parse_relay_uri(uri)
    if spec.kind == "sim":
        return SimulatedRelay.from_spec(spec)
    return DRIVERS[spec.protocol].from_spec(spec, exclusive=exclusive)


__all__ = [
    "DRIVERS",
    "KmtronicRelay",
    "LaserRelay",
    "LaserSafety",
    "LcusRelay",
    "ModbusCoilRelay",
    "NumatoRelay",
    "PortLocked",
    "RelaySpec",
    "RelayStatus",
    "SerialRelay",
    "SignalExit",
    "SimulatedBoard",
    "SimulatedRelay",
    "Switching",
    "forget_simulated_boards",
    "open_port",
    "open_relay",
    "parse_relay_uri",
    "simulated_board",
]
