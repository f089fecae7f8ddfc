"""Device URIs for laser relays: one documented scheme, parsed in one place.

Grammar::

    RELAY_URI = "sim:" [NAME] ["?" OPTIONS]
              | "serial:" PORT "?" OPTIONS
    PORT      = a device path      /dev/ttyUSB0, /dev/serial/by-id/usb-1a86_..., COM3
              | a pyserial URL     socket://HOST:PORT, rfc2217://HOST:PORT, loop://
    OPTIONS   = KEY "=" VALUE *("&" KEY "=" VALUE)

Examples::

    serial:/dev/ttyUSB0?protocol=lcus&channel=1
    serial:/dev/ttyACM0?protocol=numato&channel=0&timeout=0.3
    serial:/dev/ttyUSB1?protocol=kmtronic&channel=2&relays=4
    serial:/dev/ttyUSB2?protocol=modbus&slave=3&channel=0&baud=19200&parity=E
    serial:socket://127.0.0.1:5000?protocol=modbus
    sim:                       a private simulated relay
    sim:bench?fault=stuck      the process-wide simulated board named "bench", stuck relay

Serial options (unknown keys are refused, so a typo never goes unnoticed):

``protocol`` (required)
    ``lcus`` (LCUS/CH340 boards), ``numato`` (Numato USB relay modules, ASCII),
    ``kmtronic`` (KMTronic USB relay boards), ``modbus`` (Modbus RTU coil).
``channel``
    The relay in the board's own numbering, as printed on the board and in its manual:
    LCUS 1..255 (default 1), Numato 0..31 (default 0), KMTronic 1..8 (default 1),
    Modbus coil address 0..65535 (default 0).
``baud``
    Line speed in bit/s, default 9600 (19200 for Numato, whose USB CDC link ignores it).
``timeout``
    Seconds to wait for an answer, 0.01..30, default 0.5. Every exchange with a board is
    bounded by it: a board that does not answer raises ``DeviceTimeout``.
``verify``
    ``true`` (default) or ``false``: read the relay back after switching, where the board can.
``slave`` (modbus)
    Modbus slave address 1..247, default 1.
``parity`` (modbus)
    ``N`` (default; what cheap relay boards use), ``E`` (the Modbus standard) or ``O``.
``pulse`` (modbus)
    Seconds, 0.5..6553.5 in steps of 0.1: a hardware dead man's switch for boards with
    Waveshare's "flash on" command (Waveshare Modbus RTU Relay and compatible boards): 'on'
    is sent as "on for ``pulse`` s, then off by itself" (function 05 on coil 0x0200 +
    channel, value = tenths of a second) and renewed every ``pulse``/3 s while the laser is
    meant to be on. If the host dies, hangs or loses the cable, the board switches the laser
    off within ``pulse`` s. Channel 0..255.
``relays`` (kmtronic)
    Number of relays on the board: 1, 2, 4 or 8 (default 8). Boards with 4 or 8 relays
    answer the status request ``FF 09 00`` with one byte per relay; 1- and 2-relay boards
    are asked ``FF ch 03`` instead.

Options of a pyserial URL itself (``?logging=debug`` ...) are not supported: the query
belongs to edgedsm.

Simulated relay options: ``readback`` (``true``/``false``; ``false`` behaves like a board
without readback), ``fault`` (``none``, ``no-answer``, ``garbage``, ``stuck``, ``lost``; see
``edgedsm.devices.laser.sim``) and ``timeout`` (seconds, default 0.05).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from edgedsm.devices.uriopts import UriOptions
from edgedsm.errors import ConfigError

PROTOCOLS = ("lcus", "numato", "kmtronic", "modbus")
SIM_FAULTS = ("none", "no-answer", "garbage", "stuck", "lost")

# (lowest, highest, default) channel in each board's own numbering.
CHANNEL_RANGE: dict[str, tuple[int, int, int]] = {
    "lcus": (1, 255, 1),
    "numato": (0, 31, 0),
    "kmtronic": (1, 8, 1),
    "modbus": (0, 0xFFFF, 0),
}
DEFAULT_BAUD = {"lcus": 9600, "numato": 19200, "kmtronic": 9600, "modbus": 9600}
DEFAULT_TIMEOUT = 0.5
DEFAULT_SIM_TIMEOUT = 0.05
TIMEOUT_RANGE = (0.01, 30.0)
BAUD_RANGE = (50, 4_000_000)
KMTRONIC_RELAY_COUNTS = (1, 2, 4, 8)

_COMMON_KEYS = {"protocol", "channel", "baud", "timeout", "verify"}
_PROTOCOL_KEYS = {"lcus": set(), "numato": set(), "kmtronic": {"relays"},
                  "modbus": {"slave", "parity", "pulse"}}
PULSE_RANGE = (0.5, 6553.5)  # seconds; the board counts tenths in 16 bits
_SIM_KEYS = {"readback", "fault", "timeout"}


@dataclass(frozen=True)
class RelaySpec:
    """A parsed relay URI: which driver to open and with which settings."""

    uri: str
    kind: str                   # "serial" or "sim"
    port: str = ""              # serial device path or pyserial URL; sim board name
    protocol: str = ""          # one of PROTOCOLS for kind == "serial"
    channel: int = 0
    baud: int = 9600
    timeout: float = DEFAULT_TIMEOUT
    verify: bool = True
    options: dict[str, object] = field(default_factory=dict)  # protocol-specific extras

    @property
    def is_url(self) -> bool:
        """True when ``port`` is a pyserial URL (socket://, loop://, ...) not a device path."""
        return "://" in self.port


def _opts(uri: str) -> UriOptions:
    return UriOptions("relay", uri)


def _fail(uri: str, reason: str) -> ConfigError:
    return _opts(uri).fail(reason)


def _options(uri: str, query: str, allowed: set[str]) -> dict[str, str]:
    return _opts(uri).split(query, allowed)


def parse_relay_uri(uri: str) -> RelaySpec:
    """Parse a relay URI (see the module docstring); a bad one raises ConfigError."""
    if not isinstance(uri, str) or not uri.strip():
        raise ConfigError("relay URI is empty: expected e.g. serial:/dev/ttyUSB0?protocol=lcus")
    uri = uri.strip()
    scheme, sep, rest = uri.partition(":")
    if not sep:
        raise _fail(uri, "no scheme: expected 'serial:PORT?protocol=...' or 'sim:'")
    scheme = scheme.lower()
    # The first '?' separates edgedsm's options; pyserial URLs never need one of their own here.
    target, _, query = rest.partition("?")
    if scheme == "sim":
        return _parse_sim(uri, target, query)
    if scheme == "serial":
        return _parse_serial(uri, target, query)
    raise _fail(uri, f"unknown scheme {scheme!r}: relays use 'serial:' or 'sim:'")


def _parse_sim(uri: str, name: str, query: str) -> RelaySpec:
    if name and not all(c.isalnum() or c in "-_." for c in name):
        raise _fail(uri, f"simulated board name {name!r} may hold only letters, digits, - _ .")
    opts = _options(uri, query, _SIM_KEYS)
    extras: dict[str, object] = {}
    if "readback" in opts:
        extras["readback"] = _opts(uri).boolean("readback", opts["readback"])
    if "fault" in opts:
        if opts["fault"] not in SIM_FAULTS:
            raise _fail(uri, f"fault={opts['fault']!r} is not one of {', '.join(SIM_FAULTS)}")
        extras["fault"] = opts["fault"]
    timeout = (_opts(uri).number("timeout", opts["timeout"], *TIMEOUT_RANGE, unit="seconds")
               if "timeout" in opts else DEFAULT_SIM_TIMEOUT)
    return RelaySpec(uri=uri, kind="sim", port=name, protocol="sim", channel=0,
                     timeout=timeout, options=extras)


def _parse_serial(uri: str, port: str, query: str) -> RelaySpec:
    if not port:
        raise _fail(uri, "no serial port: expected e.g. serial:/dev/ttyUSB0?protocol=lcus")
    if any(c.isspace() for c in port):
        raise _fail(uri, f"serial port {port!r} contains white space")
    loose = _options(uri, query, _COMMON_KEYS | set().union(*_PROTOCOL_KEYS.values()))
    protocol = loose.get("protocol", "").lower()
    if not protocol:
        raise _fail(uri, f"missing protocol=...; one of {', '.join(PROTOCOLS)}")
    if protocol not in PROTOCOLS:
        raise _fail(uri, f"protocol={protocol!r} is not one of {', '.join(PROTOCOLS)}")
    # Now that the protocol is known, refuse another protocol's options (slave= on an LCUS...).
    opts = _options(uri, query, _COMMON_KEYS | _PROTOCOL_KEYS[protocol])
    low, high, default_channel = CHANNEL_RANGE[protocol]
    channel = (_opts(uri).integer("channel", opts["channel"], low, high)
               if "channel" in opts else default_channel)
    baud = (_opts(uri).integer("baud", opts["baud"], *BAUD_RANGE)
            if "baud" in opts else DEFAULT_BAUD[protocol])
    timeout = (_opts(uri).number("timeout", opts["timeout"], *TIMEOUT_RANGE, unit="seconds")
               if "timeout" in opts else DEFAULT_TIMEOUT)
    verify = _opts(uri).boolean("verify", opts["verify"]) if "verify" in opts else True
    extras: dict[str, object] = {}
    if protocol == "modbus":
        extras["slave"] = _opts(uri).integer("slave", opts["slave"], 1, 247) if "slave" in opts else 1
        parity = opts.get("parity", "N").upper()
        if parity not in ("N", "E", "O"):
            raise _fail(uri, f"parity={opts['parity']!r} must be N, E or O")
        extras["parity"] = parity
        if "pulse" in opts:
            pulse = _opts(uri).number("pulse", opts["pulse"], *PULSE_RANGE, unit="seconds")
            if abs(pulse * 10 - round(pulse * 10)) > 1e-6:
                raise _fail(uri, f"pulse={opts['pulse']}: the board counts tenths of a second")
            if channel > 0xFF:
                raise _fail(uri, f"pulse= needs channel 0..255 (the flash command's coil is 0x0200 + channel), "
                                 f"not {channel}")
            extras["pulse"] = pulse
    if protocol == "kmtronic":
        relays = _opts(uri).integer("relays", opts["relays"], 1, 8) if "relays" in opts else 8
        if relays not in KMTRONIC_RELAY_COUNTS:
            raise _fail(uri, f"relays={relays}: KMTronic USB boards have 1, 2, 4 or 8 relays")
        if channel > relays:
            raise _fail(uri, f"channel={channel} but the board has only relays={relays}")
        extras["relays"] = relays
    return RelaySpec(uri=uri, kind="serial", port=port, protocol=protocol, channel=channel,
                     baud=baud, timeout=timeout, verify=verify, options=extras)
