"""The camera contract: what every camera driver, real or simulated, promises.

Public methods hold the rules (open/closed checks, argument validation, counting, reconnection);
drivers implement private hooks, in the python-microscope style:

``_do_open()`` / ``_do_close()``
    Acquire and release the device. ``_do_close`` must never raise for an already-lost device.
``_do_start()`` / ``_do_stop()``
    Start and stop streaming.
``_do_grab(timeout_s) -> Frame | None``
    The next frame. Return ``None`` for a buffer that arrived incomplete or corrupt (after
    calling ``self._dropped(reason)``); raise ``DeviceTimeout`` when nothing came within
    ``timeout_s`` and ``DeviceLost`` when the device is gone.
``_do_set_exposure(us)``, ``_do_set_frame_interval(s)``, ``_do_set_region(region)``,
``_do_set_pixel_format(fmt)``
    Apply a setting and return the value the device really took (devices round).

Errors: ``DeviceError`` > ``DeviceTimeout``, ``DeviceLost`` (``edgedsm.errors``).
"""

from __future__ import annotations

import abc
import contextlib
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import ClassVar, Self, TypeVar

from edgedsm.errors import DeviceError, DeviceLost, DeviceTimeout
from edgedsm.frames import Frame, FrameFormat

log = logging.getLogger(__name__)
T = TypeVar("T")

#: Pixel formats edgedsm understands (GenICam names) and their significant bits.
PIXEL_FORMATS = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono12Packed": 12, "Mono12p": 12,
                 "Mono14": 14, "Mono16": 16}


@dataclass(frozen=True)
class Region:
    """Sensor region of interest in pixels: top-left corner (x = column, y = row) and size."""

    x: int
    y: int
    width: int
    height: int

    def __post_init__(self) -> None:
        if self.x < 0 or self.y < 0 or self.width < 1 or self.height < 1:
            raise DeviceError(f"invalid region {self}: need x, y >= 0 and width, height >= 1")


@dataclass(frozen=True)
class Backoff:
    """Reconnection policy: delays initial, initial*factor, ... capped at maximum (seconds).

    ``attempts`` = 0 retries for ever (the daemon's choice); a positive number gives up with
    the last ``DeviceLost`` after that many failed attempts.
    """

    initial: float = 0.5
    factor: float = 2.0
    maximum: float = 30.0
    attempts: int = 0

    def delays(self) -> Iterator[float]:
        delay, tried = self.initial, 0
        while self.attempts == 0 or tried < self.attempts:
            yield delay
            tried += 1
            delay = min(delay * self.factor, self.maximum)


@dataclass(frozen=True)
class ReconnectWatch:
    """Who is told about a reconnection (``Camera.frames``): both callbacks run on the grabbing
    thread; ``stop`` set ends the stream, also while waiting between attempts."""

    on_lost: Callable[[DeviceError], None] = lambda cause: None
    on_reconnected: Callable[[], None] = lambda: None
    stop: threading.Event | None = None


def pace(due: float, interval: float) -> float:
    """Sleep until ``due`` (monotonic seconds; 0 = now) and return when the next frame is due.

    A consumer that falls behind is not answered with a burst: the cadence restarts from now.
    """
    now = time.monotonic()
    if due > now:
        time.sleep(due - now)
        now = due
    return max(due, now) + interval


class EndOfStream(DeviceError):
    """Raised by ``_do_grab`` of a finite source (a replay) at its end: ``frames()`` then ends."""


class Camera(abc.ABC):
    """A monochrome camera: abstract base of every camera driver. Use as a context manager."""

    #: Short name of the driver kind, used in URIs and logs ("aravis", "sim", ...).
    kind: ClassVar[str] = "camera"

    def __init__(self, description: str) -> None:
        self.description = description
        self._opened = False
        self._streaming = False
        self.stats: Counter[str] = Counter()  # delivered, dropped_<reason>, timeouts, lost, reconnects
        self._settings: dict[str, object] = {}  # applied settings, re-applied after a reconnect
        self._sleep: Callable[[float], None] = time.sleep

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.description}>"

    @property
    def paced(self) -> bool:
        """True when frames come at the source's own pace (a real camera cannot wait): a slow
        consumer must drop frames. False for a source that can wait (a replay as fast as
        possible), which a consumer should hold back instead."""
        return True

    # -- lifecycle ------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._opened

    def open(self) -> Self:
        if not self._opened:
            self._do_open()
            self._opened = True
            log.info("%s: opened", self.description)
        return self

    def close(self) -> None:
        """Stop streaming and release the device; safe to call more than once."""
        if not self._opened:
            return
        try:
            if self._streaming:
                self._stop_quietly()
        finally:
            self._opened = False
            self._do_close()
            log.info("%s: closed", self.description)

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def _check_open(self) -> None:
        if not self._opened:
            raise DeviceError(f"{self.description}: camera is not open")

    # -- settings -------------------------------------------------------------------------
    def set_exposure(self, microseconds: float) -> float:
        """Exposure time in µs; returns the value the camera took."""
        self._check_open()
        if not 0 < microseconds <= 60e6:
            raise DeviceError(f"exposure {microseconds} µs outside (0, 60 s]")
        return self._remember("exposure", self._do_set_exposure(float(microseconds)))

    def set_frame_interval(self, seconds: float) -> float:
        """Frame interval Δt in seconds (1/frame rate); returns the value the camera took."""
        self._check_open()
        if not 0 < seconds <= 3600:
            raise DeviceError(f"frame interval {seconds} s outside (0, 3600]")
        return self._remember("frame_interval", self._do_set_frame_interval(float(seconds)))

    def set_region(self, region: Region) -> Region:
        self._check_open()
        if self._streaming:
            raise DeviceError(f"{self.description}: stop streaming before changing the region")
        return self._remember("region", self._do_set_region(region))

    def set_pixel_format(self, pixel_format: str) -> str:
        self._check_open()
        if pixel_format not in PIXEL_FORMATS:
            raise DeviceError(f"pixel format {pixel_format!r} not supported; use one of {sorted(PIXEL_FORMATS)}")
        if self._streaming:
            raise DeviceError(f"{self.description}: stop streaming before changing the pixel format")
        return self._remember("pixel_format", self._do_set_pixel_format(pixel_format))

    def frame_format(self) -> FrameFormat | None:
        """Shape, bits and dtype of the frames the open camera will deliver with its settings now,
        or None where only a frame tells. Before frames flow, the daemon loads the kernels that size
        of frame runs (a small frame runs none of the parallel ones) and builds its engine."""
        self._check_open()
        return self._do_frame_format()

    def _remember(self, name: str, value: T) -> T:
        self._settings[name] = value
        return value

    def _reapply_settings(self) -> None:
        hooks = {"pixel_format": self._do_set_pixel_format, "region": self._do_set_region,
                 "exposure": self._do_set_exposure, "frame_interval": self._do_set_frame_interval}
        for name, hook in hooks.items():
            if name in self._settings:
                hook(self._settings[name])

    # -- acquisition ----------------------------------------------------------------------
    def frames(self, count: int | None = None, timeout_s: float = 5.0, reconnect: Backoff | None = None,
               *, watch: ReconnectWatch | None = None) -> Iterator[Frame]:
        """Yield ``count`` good frames (for ever if None); bad buffers are dropped and counted.

        Without ``reconnect`` a lost device raises ``DeviceLost`` and a silent one
        ``DeviceTimeout``. With it, both count as lost: the driver closes, waits per the backoff
        and reopens (counting ``reconnects``), then streams on; ``watch`` is told when the device
        is lost and when it is back, and its ``stop`` event ends the stream (even mid-backoff).
        The backoff starts over only once a frame has come: a device that reopens but stays
        silent (flapping) is retried ever more slowly. This is the one reconnection path: the
        daemon's capture thread uses it too.
        """
        self._check_open()
        delivered = 0
        delays: Iterator[float] | None = None  # the backoff of the current outage
        self._start()
        try:
            while count is None or delivered < count:
                try:
                    frame = self._do_grab(timeout_s)
                except EndOfStream:
                    return
                except (DeviceLost, DeviceTimeout) as exc:
                    self.stats["lost" if isinstance(exc, DeviceLost) else "timeouts"] += 1
                    if reconnect is None:
                        raise
                    if delays is None:
                        delays = reconnect.delays()
                    if not self._reconnect(delays, exc, watch or ReconnectWatch()):
                        return  # stopped while waiting to reconnect
                    continue
                if frame is None:
                    continue
                self.stats["delivered"] += 1
                delivered += 1
                delays = None
                yield frame
        finally:
            if self._opened and self._streaming:
                self._stop_quietly()

    def _start(self) -> None:
        if not self._streaming:
            self._do_start()
            self._streaming = True

    def _stop_quietly(self) -> None:
        self._streaming = False
        try:
            self._do_stop()
        except DeviceError as exc:  # a lost device cannot be stopped; that is fine
            log.debug("%s: stop failed: %s", self.description, exc)

    def _reconnect(self, delays: Iterator[float], cause: DeviceError, watch: ReconnectWatch) -> bool:
        """Close, then reopen after each of ``delays``; False if ``watch.stop`` was set meanwhile."""
        log.warning("%s: device lost (%s), reconnecting", self.description, cause)
        watch.on_lost(cause)  # first: closing a dead device can take seconds
        self._streaming = False
        with contextlib.suppress(DeviceError):
            self._do_close()
        self._opened = False
        last: DeviceError = cause
        for delay in delays:
            if watch.stop is not None:
                if watch.stop.wait(delay):
                    return False
            else:
                self._sleep(delay)
            try:
                self._do_open()
                self._opened = True
                self._reapply_settings()
                self._start()
            except DeviceError as exc:  # not back yet (a half-open device is closed again)
                last = exc
                log.info("%s: reconnect failed (%s)", self.description, exc)
                if self._opened:
                    self._streaming = False
                    with contextlib.suppress(DeviceError):
                        self._do_close()
                    self._opened = False
                continue
            self.stats["reconnects"] += 1
            log.warning("%s: reconnected", self.description)
            watch.on_reconnected()
            return True
        raise DeviceLost(f"{self.description}: gave up reconnecting: {last}")

    def _dropped(self, reason: str) -> None:
        """Count a buffer that was thrown away (``incomplete``, ``corrupt``, ``invalid``...)."""
        self.stats[f"dropped_{reason}"] += 1
        log.debug("%s: dropped a frame (%s)", self.description, reason)

    # -- hooks ----------------------------------------------------------------------------
    @abc.abstractmethod
    def _do_open(self) -> None: ...

    @abc.abstractmethod
    def _do_close(self) -> None: ...

    def _do_start(self) -> None:
        return None

    def _do_stop(self) -> None:
        return None

    @abc.abstractmethod
    def _do_grab(self, timeout_s: float) -> Frame | None: ...

    def _do_frame_format(self) -> FrameFormat | None:
        return None

    def _do_set_exposure(self, microseconds: float) -> float:
        raise DeviceError(f"{self.description}: exposure cannot be set on this camera")

    def _do_set_frame_interval(self, seconds: float) -> float:
        raise DeviceError(f"{self.description}: frame interval cannot be set on this camera")

    def _do_set_region(self, region: Region) -> Region:
        raise DeviceError(f"{self.description}: region cannot be set on this camera")

    def _do_set_pixel_format(self, pixel_format: str) -> str:
        raise DeviceError(f"{self.description}: pixel format cannot be set on this camera")
