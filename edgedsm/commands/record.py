"""Record a camera to a file that `analyze` and `replay:` read back bit-identically.

  edgedsm record sim:default -o run.tif --frames 400
  edgedsm record aravis: -c /etc/edgedsm/edgedsm.toml -o run.tif --seconds 60
  edgedsm record -c edgedsm.toml -o run.tif --frames 1200        (the config's camera)
  edgedsm record 'v4l2:/dev/video0?fourcc=YUYV&channel=red' -o red.tif --seconds 10

The file is a BigTIFF, one page per frame, compressed losslessly (zstd by default; --codec
deflate, lzw or none), each page carrying its frame's sequence number, timestamp and laser
state (docs/recording.md). Frames are appended page by page: a recorder killed (even by
SIGKILL) leaves every complete frame readable. Recordings are never overwritten.

With -c CONFIG the camera settings (pixel format, exposure, frame interval) of a daemon config
are applied, and its [laser] relay is switched on for the recording only: off before the
camera starts, off again at the end, on an error, on Ctrl-C, SIGTERM and SIGHUP. The first
frame after switching on is left out (it may have been exposed while the relay switched), as
the daemon does. Stop the edgedsm service first: it holds the camera and the relay.

Exit status: 0 recorded; 130 Ctrl-C and 143 SIGTERM (the file keeps the frames recorded so
far); 65 bad frames, 69 camera or relay unavailable (the laser is said to be off, or NOT off),
73 the output exists, 74 the file could not be written (disk full), 78 bad URI or config.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from edgedsm.commands.broker_options import seconds
from edgedsm.commands.common import add_progress_flag, progress
from edgedsm.commands.probe import _positive_int
from edgedsm.errors import ConfigError, DeviceError, EdgedsmError
from edgedsm.frameio.recording import CODECS, DEFAULT_CODEC, RecordingWriter

if TYPE_CHECKING:
    from edgedsm.config import DaemonConfig
    from edgedsm.devices.camera.base import Camera
    from edgedsm.devices.laser import LaserRelay

NAME = "record"
HELP = "record a camera (any URI) to a lossless BigTIFF with per-frame timestamps"
#: Frames left out after the laser is switched on (exposed while it switched): the daemon's rule.
SKIP_AFTER_ON = 1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("uri", metavar="CAMERA_URI", nargs="?",
                        help="the camera, e.g. sim:default, aravis:, v4l2:/dev/video0, replay:run.avi "
                             "(default: the camera of -c CONFIG)")
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="OUT.tif", help="the recording to write")
    length = parser.add_mutually_exclusive_group(required=True)
    length.add_argument("--frames", "-n", type=_positive_int, metavar="N", help="record N frames")
    length.add_argument("--seconds", type=seconds, metavar="S", help="record for S seconds")
    parser.add_argument("-c", "--config", type=Path, metavar="CONFIG.toml",
                        help="take the camera settings and the [laser] relay from this daemon config")
    parser.add_argument("--codec", choices=tuple(CODECS), default=DEFAULT_CODEC,
                        help=f"lossless compression (default {DEFAULT_CODEC}; see docs/recording.md)")
    parser.add_argument("--timeout", type=seconds, metavar="SECONDS",
                        help="longest wait for one frame (default: the config's grab_timeout_s, else 5)")
    add_progress_flag(parser)


class Stopped(Exception):
    """A stop signal arrived while recording (SIGTERM, SIGHUP), outside the laser's own handling."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_stopped(signum: int, frame: FrameType | None) -> None:
    raise Stopped(signum)


def run(args: argparse.Namespace) -> int:
    from edgedsm.devices.camera.uri import open_camera, parse_camera_uri

    if args.uri is None and args.config is None:
        raise ConfigError("name the camera: give CAMERA_URI, or -c CONFIG to use the config's camera")
    config = _load(args.config)
    spec = parse_camera_uri(args.uri) if args.uri is not None else config.camera.spec  # type: ignore[union-attr]
    camera = open_camera(spec)
    header = {"camera": camera.description, "config": str(args.config) if args.config else None}
    writer = RecordingWriter(args.output, codec=args.codec, source=spec.uri, header=header)
    recorder = Recorder(args, config, camera, writer)
    started = time.monotonic()
    try:
        with writer, _stop_signals():
            recorder.record()
    except (KeyboardInterrupt, Stopped) as stop:
        why = "Ctrl-C" if isinstance(stop, KeyboardInterrupt) else str(stop)
        kept = f"{args.output} holds the {writer.count} frames recorded" if writer.count else "nothing recorded"
        laser = "" if recorder.laser_not_off is None else "; THE LASER MAY STILL BE ON"
        print(f"edgedsm: record stopped by {why}: {kept}{laser}", file=sys.stderr)
        if recorder.laser_not_off is not None:
            return DeviceError.exit_code
        return 130 if isinstance(stop, KeyboardInterrupt) else 128 + stop.signum
    except EdgedsmError as exc:
        if writer.count:
            exc.args = (f"{exc} ({args.output} keeps the {writer.count} frames recorded before)",)
        raise
    _report(args, writer, time.monotonic() - started)
    return 0


def _load(path: Path | None) -> DaemonConfig | None:
    if path is None:
        return None
    from edgedsm.config import load_config

    return load_config(path)


@contextlib.contextmanager
def _stop_signals() -> Iterator[None]:
    """SIGTERM and SIGHUP end the recording like Ctrl-C (the file is closed, the laser off)."""
    from edgedsm.signals import handling

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with handling({signal.SIGTERM: _raise_stopped, signal.SIGHUP: _raise_stopped}):
        yield


class Recorder:
    """Camera (and laser) to a recording writer, everything released on every way out."""

    def __init__(self, args: argparse.Namespace, config: DaemonConfig | None, camera: Camera,
                 writer: RecordingWriter) -> None:
        self.args = args
        self.config = config
        self.camera = camera
        self.writer = writer
        self.laser_not_off: str | None = None  # why the laser could not be switched off at the end

    def record(self) -> None:
        """Open the relay (last, as the daemon does) and the camera, record, close both."""
        from edgedsm.devices.laser import LaserSafety, SignalExit, open_relay

        relay: LaserRelay | None = None
        if self.config is not None and self.config.laser is not None:
            from edgedsm.daemon.devices import couple_simulated_laser

            relay = open_relay(self.config.laser.spec)
            couple_simulated_laser(self.camera, relay)
        in_main = threading.current_thread() is threading.main_thread()
        safety = LaserSafety(relay, signals=(signal.SIGTERM, signal.SIGHUP) if in_main else ()) if relay else None
        try:
            with safety or contextlib.nullcontext(), self.camera:
                self._frames(relay)
        except SignalExit as stop:  # LaserSafety's handler; the laser was switched off on the way here
            raise Stopped(stop.signum) from None
        finally:
            if safety is not None and safety.off_error is not None:
                self.laser_not_off = str(safety.off_error)
                print(f"edgedsm: THE LASER COULD NOT BE SWITCHED OFF and may still be on: {safety.off_error}",
                      file=sys.stderr)

    def _frames(self, relay: LaserRelay | None) -> None:
        from edgedsm.daemon.capture import apply_camera_settings

        args, writer = self.args, self.writer
        if self.config is not None:
            writer.header.update(apply_camera_settings(self.camera, self.config.camera))
        timeout = args.timeout or (self.config.camera.grab_timeout_s if self.config is not None else 5.0)
        laser, skip = "none", 0
        if relay is not None:
            relay.on()
            laser, skip = "on", SKIP_AFTER_ON
        wanted = None if args.frames is None else args.frames + skip
        deadline = None if args.seconds is None else time.monotonic() + args.seconds
        for frame in progress(self.camera.frames(wanted, timeout_s=timeout), wanted, "record", args.progress):
            if skip:
                skip -= 1
                continue
            writer.write(frame, laser)
            if deadline is not None and time.monotonic() >= deadline:
                break
        if writer.count == 0:
            raise DeviceError(f"{self.camera.description}: no frames")


def _report(args: argparse.Namespace, writer: RecordingWriter, elapsed: float) -> None:
    from edgedsm.frameio import open_frames

    size = args.output.stat().st_size
    with open_frames(args.output) as reader:
        raw = reader.count * reader.shape[0] * reader.shape[1] * reader.dtype.itemsize  # type: ignore[operator]
        stamps = reader.stamps()
        rate = 1 / reader.dt if reader.dt else float("nan")
        print(f"recorded {reader.count} frames of {reader.shape[1]}x{reader.shape[0]} {reader.dtype} "
              f"({reader.bits} bits) in {elapsed:.1f} s, {rate:.1f} frames/s by their timestamps, "
              f"seq {stamps.seq[0]}..{stamps.seq[-1]}; {args.codec}: {size / 1e6:.1f} MB, "  # type: ignore[union-attr]
              f"ratio {raw / size:.2f} -> {args.output}")
