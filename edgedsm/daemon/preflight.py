"""What the daemon would refuse at its start that a file alone cannot say, checked on this
machine before anything is allocated or opened: by ``check-config`` and by ``run`` (before the
sinks, the camera and the relay), and by a reload (without the memory rule, see below). One
rule per fact, each a ConfigError (exit 78) naming its key path:

- ``device.state_dir`` (when something keeps files there: ``[mqtt]``, Sparkplug, Home
  Assistant, ``[recording]`` without a ``dir``) and ``recording.dir``: a writable directory, or
  one that can be created, on a file system that keeps files (not /proc, /sys or /dev); an
  empty file is created and removed to prove it. (A recording directory failing later, a full
  disk, is a fault alert and the measurement goes on: docs/recording.md.)
- ``camera.pixel_format`` of a simulated camera: the one its scene's detector delivers;
  ``laser.uri`` as a pyserial URL (``socket://``, ``rfc2217://``): a protocol pyserial knows
  (checked, nothing opened; the relay itself is opened by the start, a device error then).
- ``http.listen``: the host resolves (``getaddrinfo``) and is an address of this machine (a
  socket binds to it on a free port; the configured port is not taken here: a running daemon
  holds it while ``check-config`` runs, and the start refuses a taken port itself).
- ``[mqtt]``: the TLS files load, the password credential and the command keys read
  (the same functions the MQTT sink calls at its start).
- with the frame size known without opening a device (``known_frame_shape``): the regions
  inside the frame (:func:`edgedsm.config.check_regions`) and the engine and frame queues
  against the memory available (:func:`edgedsm.daemon.engine_budget.check_memory`, applied
  again to the camera's first real frame). A reload skips the memory rule: the running
  engine's memory is freed only when the new one is built (checked then).

Static rules (a topic prefix starting with '$', wildcards) are the config models' validators.
"""

from __future__ import annotations

import contextlib
import os
import socket
import uuid
from pathlib import Path

from edgedsm.config import DaemonConfig, check_regions
from edgedsm.devices.camera.uri import known_frame_shape
from edgedsm.errors import ConfigError, EdgedsmError

#: File systems that keep no files of their own: a state directory there loses or refuses them.
VIRTUAL_FILESYSTEMS = frozenset({"proc", "sysfs", "devtmpfs", "devpts", "cgroup", "cgroup2", "debugfs",
                                 "securityfs", "tracefs", "configfs", "pstore", "bpf", "mqueue", "fusectl",
                                 "hugetlbfs", "efivarfs", "binfmt_misc", "autofs", "nsfs"})


def preflight(config: DaemonConfig, frame_shape: tuple[int, int] | None = None, *, memory: bool = True) -> None:
    """Every rule of the module docstring; ConfigError with one line per problem."""
    problems: list[str] = []
    for check in (_devices, _state_dir, _listen, _mqtt):
        try:
            check(config)
        except ConfigError as exc:
            problems.append(str(exc))
    if frame_shape is not None:
        try:
            check_regions(config, frame_shape)
            if memory:  # after the regions: the engine's box is theirs with area = 'regions'
                _memory(config, frame_shape)
        except ConfigError as exc:
            problems.append(str(exc))
    if problems:
        prefix = f"{config.source}: " if config.source else ""
        raise ConfigError("\n".join(line if line.startswith(prefix) else prefix + line
                                    for problem in problems for line in problem.splitlines()))


def preflight_start(config: DaemonConfig) -> tuple[int, int] | None:
    """:func:`preflight` with the frame size known without opening a device (returned; None
    when only the camera's first frame will say)."""
    frame_shape = known_frame_shape(config.camera.spec)
    preflight(config, frame_shape)
    return frame_shape


# -- camera and laser, without opening them ---------------------------------------------------

def _devices(config: DaemonConfig) -> None:
    """A simulated camera asked for a pixel format its scene's detector does not deliver, and a
    relay URL pyserial does not know: refused by the start too (the first as a device fault,
    exit 69, restarted over and over), found here without touching a device."""
    problems = []
    camera = config.camera
    if camera.pixel_format is not None and camera.spec.scheme == "sim":
        from edgedsm.devices.camera.sim import SimulatedCamera
        from edgedsm.devices.camera.uri import open_camera

        sim = open_camera(camera.spec)  # constructed, not opened: nothing simulated yet
        if isinstance(sim, SimulatedCamera) and camera.pixel_format != sim.delivers:
            problems.append(f"camera.pixel_format: {camera.pixel_format}: the scene's {sim.bits}-bit detector "
                            f"delivers {sim.delivers}")
    if config.laser is not None and config.laser.spec.kind != "sim" and config.laser.spec.is_url:
        from edgedsm.devices.laser import open_port

        try:
            open_port(config.laser.spec, do_not_open=True)
        except ConfigError as exc:
            problems.append(f"laser.uri: {exc}")
    if problems:
        raise ConfigError("\n".join(problems))


# -- device.state_dir ------------------------------------------------------------------------

def _state_dir(config: DaemonConfig) -> None:
    # its users: the MQTT, Sparkplug and Home Assistant sinks, and [recording] without a dir of its own
    if config.mqtt is not None or (config.recording is not None and config.recording.dir is None):
        problem = state_dir_problem(Path(config.device.state_dir))
        if problem:
            raise ConfigError(f"device.state_dir: {config.device.state_dir}: {problem}")
    if config.recording is not None and config.recording.dir is not None and config.recording_dir is not None:
        problem = state_dir_problem(config.recording_dir)
        if problem:
            raise ConfigError(f"recording.dir: {config.recording_dir}: {problem}")


def state_dir_problem(path: Path) -> str | None:
    """Why ``path`` cannot be a state directory (None: it can): not a directory, on a file system
    that keeps nothing, or neither writable nor creatable."""
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    fs = filesystem_type(existing)
    if fs in VIRTUAL_FILESYSTEMS:
        return f"on a {fs} file system, which keeps no files (give a directory on a disk, e.g. /var/lib/edgedsm)"
    if not existing.is_dir():
        return f"{existing} is not a directory" if existing != path else "not a directory"
    probe = existing / f".edgedsm-preflight-{uuid.uuid4().hex[:8]}"
    try:
        os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
    except OSError as exc:
        what = "not writable" if existing == path else f"cannot be created: {existing} is not writable"
        return f"{what} ({exc.strerror or exc})"
    with contextlib.suppress(OSError):
        probe.unlink()
    return None


def filesystem_type(path: Path) -> str | None:
    """The type of the file system ``path`` (existing) is on, from /proc/self/mountinfo (None if unknown)."""
    try:
        target = os.path.realpath(path)
        with open("/proc/self/mountinfo", encoding="utf-8", errors="replace") as handle:
            mounts = [line.split() for line in handle]
    except OSError:
        return None
    best, fs = "", None
    for fields in mounts:
        if "-" not in fields:
            continue
        point = fields[4].replace("\\040", " ")
        inside = target == point or target.startswith(point.rstrip("/") + "/")
        if inside and len(point) >= len(best):  # the deepest mount holding the path (the last one on ties)
            best, fs = point, fields[fields.index("-") + 1]
    return fs


# -- http.listen -----------------------------------------------------------------------------

def _listen(config: DaemonConfig) -> None:
    if config.http is None:
        return
    problem = listen_problem(*config.http.address)
    if problem:
        raise ConfigError(f"http.listen: {config.http.listen}: {problem}")


def listen_problem(host: str, port: int) -> str | None:
    """Why a server cannot listen on ``host`` (None: it can): the name does not resolve, or no
    address it resolves to is this machine's. ``port`` is not bound (see the module docstring),
    only refused for a privileged port this process may not take."""
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as exc:
        return f"{host!r} does not resolve ({getattr(exc, 'strerror', None) or exc})"
    errors = []
    for family, kind, proto, _, address in addresses:
        for trial in (0, port):  # any port: the address is this machine's; the port: privileges
            try:
                with socket.socket(family, kind, proto) as probe:
                    probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    probe.bind((address[0], trial, *address[2:]))
            except OSError as exc:
                if trial == port and exc.errno == getattr(socket, "EADDRINUSE", 98):
                    return None  # taken (perhaps by this daemon): the start says if it is
                errors.append(f"{address[0]}: {exc.strerror or exc}")
                break
        else:
            return None
    return f"cannot listen there ({'; '.join(errors)})"


# -- [mqtt] ----------------------------------------------------------------------------------

def _mqtt(config: DaemonConfig) -> None:
    if config.mqtt is None:
        return
    from edgedsm.publish.connection import build_ssl_context
    from edgedsm.publish.settings import resolve_command_keys, resolve_password

    if config.mqtt.tls is not None:
        build_ssl_context(config.mqtt.tls)
    resolve_password()
    resolve_command_keys(config.mqtt)


# -- memory ----------------------------------------------------------------------------------

def _memory(config: DaemonConfig, frame_shape: tuple[int, int]) -> None:
    from edgedsm.daemon.engine_budget import check_memory

    check_memory(config, frame_shape, known_frame_bits(config), pixels=_engine_pixels(config, frame_shape))


def _engine_pixels(config: DaemonConfig, frame_shape: tuple[int, int]) -> int:
    """What the engine sees: the frame, or with ``estimator.area = 'regions'`` the bounding box of
    every region (one mask at a time: no frame-sized stack of them)."""
    if config.estimator.area != "regions" or not config.regions:
        return frame_shape[0] * frame_shape[1]
    from edgedsm.analysis import bounding_box

    top = left = None
    bottom = right = 0
    for region in config.regions:
        rows, cols = bounding_box([region.mask(frame_shape, config.base_dir)])
        top = rows.start if top is None else min(top, rows.start)
        left = cols.start if left is None else min(left, cols.start)
        bottom, right = max(bottom, rows.stop), max(right, cols.stop)
    return (bottom - (top or 0)) * (right - (left or 0))


def known_frame_bits(config: DaemonConfig) -> int:
    """Bits per pixel of the camera's frames as far as known without opening a device: the pixel
    format asked for, a simulated scene's detector, a recording's sample size; else 8 (the
    first frame's real depth is checked again then)."""
    from edgedsm.devices.camera.pixels import PIXEL_BITS

    if config.camera.pixel_format:
        return PIXEL_BITS.get(config.camera.pixel_format, 16)
    spec = config.camera.spec
    if spec.scheme == "sim":
        from edgedsm.devices.camera.uri import open_camera

        bits = getattr(open_camera(spec), "bits", 8)  # constructed, not opened: nothing simulated yet
        return int(bits)
    if spec.scheme == "replay":
        from edgedsm.frameio import open_frames

        try:
            with open_frames(Path(spec.target), "luma") as reader:
                return 8 if reader.dtype.itemsize == 1 else 16
        except EdgedsmError:
            return 8
    return 8
