"""GigE Vision and USB3 Vision cameras through Aravis 0.8 (PyGObject).

Aravis is imported lazily, when a camera is opened or listed, so edgedsm works without it;
a machine without it gets a ``DeviceError`` that names what to install (Debian 12:
``gir1.2-aravis-0.8``, plus ``aravis-tools`` for the fake camera, and PyGObject < 3.51).

How the driver uses Aravis, and why:

- **Opening.** Every open (reconnections too) updates Aravis' device list first and opens a
  GigE Vision camera named by id, serial or MAC address by its IP address, so that Aravis
  streams to the interface on the camera's subnet (see ``AravisCamera._open_target``).
- **Buffer pool.** ``buffers`` buffers of one payload each are pushed into the stream when
  streaming starts. Every buffer popped is pushed back, on success and on every error path,
  right after its pixels are copied out, so the pool never shrinks. When the consumer falls
  behind, Aravis has no free buffer and counts an *underrun* (the frame is lost upstream and
  the gap shows in ``Frame.seq``).
- **Bad buffers.** A buffer whose status is not ``SUCCESS`` is dropped and counted:
  ``dropped_incomplete`` (missing packets, timeout, aborted), ``dropped_corrupt`` (wrong
  packet id, size mismatch, too few bytes) or ``dropped_invalid``; the exact Aravis status is
  counted too, as ``buffer_<status>`` in ``stats``.
- **Loss.** The device's ``control-lost`` signal (heartbeat failed) sets a flag that the next
  grab turns into ``DeviceLost``. Aravis only notices after 5 s or more, so a grab that has
  waited half its timeout also checks the control channel with one register read, on a
  helper thread: a grab never takes longer than its timeout (a read of a dead GigE Vision
  camera takes 2.5 s of retries, and longer behind a heartbeat). At the timeout, a camera
  that answered is merely silent (``DeviceTimeout``); one that did not answer, or answered
  without our control bits (it restarted), is gone (``DeviceLost``, also raised as soon as
  the read fails).
- **Stop.** ``stop_acquisition()`` does not empty the stream's output queue, so stopping drains it
  back into the pool: a restart never delivers stale frames. The stream (its receive thread and
  socket) lives from start to stop; its statistics are added up in ``stream_statistics()``.
- **Timestamps.** ``Frame.t_ns`` is the buffer's camera timestamp (Aravis converts GigE
  Vision ticks to ns), else its system (host arrival) timestamp, else the host's monotonic
  clock. A camera that reboots may restart its clock.
- **Frame numbers.** GigE Vision 1.x block ids are 16 bit and wrap from 65535 to 1; ``seq``
  unwraps them so that it keeps growing and gaps still mean lost frames. After a reopen
  (reconnection) the sequence goes on from the last ``seq`` + 1, whatever the camera counts.
- **Settings** go through the GenICam features via ``ArvCamera`` (exposure in µs,
  ``AcquisitionFrameRate``, region, ``PixelFormat``); automatic exposure and gain are
  switched off at open where the camera has them, since a measurement needs them fixed.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from edgedsm.devices.camera.aravis_threads import AliveCheck, release_in_background
from edgedsm.devices.camera.base import Camera, Region
from edgedsm.devices.camera.pixels import PIXEL_BITS, PIXEL_FORMAT_CODES, decode_image
from edgedsm.errors import DeviceError, DeviceLost, DeviceTimeout
from edgedsm.frames import Frame, FrameFormat

log = logging.getLogger(__name__)
T = TypeVar("T")

MISSING_ARAVIS = ("Aravis is not available to Python ({reason}). On Debian 12 install the packages "
                  "gir1.2-aravis-0.8 (and aravis-tools for the fake camera) and, in a virtual "
                  "environment, pip install 'PyGObject<3.51' (it builds against the Debian packages "
                  "libgirepository1.0-dev, libcairo2-dev, pkg-config, gcc and python3-dev); "
                  "or pip install 'edgedsm[aravis]'.")

#: Slice of a blocking pop (s): how soon a ``control-lost`` is noticed while waiting.
POLL_S = 0.1
#: Fraction of a grab's timeout after which the control channel is checked (on a helper thread).
ALIVE_CHECK_AFTER = 0.5
#: Device ids of Aravis' in-process fake interface start with this; it is enabled on demand.
FAKE_PREFIX = "Fake_"
DEFAULT_BUFFERS = 8

_INCOMPLETE = {"missing-packets", "timeout", "aborted", "filling", "cleared"}
_CORRUPT = {"wrong-packet-id", "size-mismatch"}

_aravis: tuple[Any, Any] | None = None


def load_aravis() -> tuple[Any, Any]:
    """Import Aravis 0.8 and GLib through PyGObject once; ``DeviceError`` if unavailable."""
    global _aravis
    if _aravis is None:
        try:
            import gi

            gi.require_version("Aravis", "0.8")
            from gi.repository import Aravis, GLib
        except (ImportError, ValueError) as exc:  # ValueError: "Namespace Aravis not available"
            raise DeviceError(MISSING_ARAVIS.format(reason=exc)) from None
        _aravis = (Aravis, GLib)
    return _aravis


@dataclass(frozen=True)
class CameraInfo:
    """One camera Aravis can see."""

    device_id: str
    vendor: str
    model: str
    serial: str
    protocol: str   # GigEVision, USB3Vision, Fake
    address: str    # IP address for GigE Vision, "" else

    @property
    def uri(self) -> str:
        return f"aravis:{self.device_id}"


def list_cameras(include_fake: bool = False) -> list[CameraInfo]:
    """All cameras Aravis discovers now (GigE Vision broadcast, USB3 Vision enumeration).

    ``include_fake`` also enables Aravis' in-process fake interface (device ``Fake_1``).
    """
    Aravis, _ = load_aravis()
    if include_fake:
        Aravis.enable_interface("Fake")
    Aravis.update_device_list()
    return [CameraInfo(device_id=Aravis.get_device_id(i) or "", vendor=Aravis.get_device_vendor(i) or "",
                       model=Aravis.get_device_model(i) or "", serial=Aravis.get_device_serial_nbr(i) or "",
                       protocol=Aravis.get_device_protocol(i) or "", address=Aravis.get_device_address(i) or "")
            for i in range(Aravis.get_n_devices())]


def unwrap_frame_id(previous_raw: int | None, previous_seq: int, raw: int) -> int:
    """The next ``seq`` from a camera frame id that may wrap (GigE Vision 1.x: 65535 → 1).

    A small id just after one near 65535 is a wrap; any other step backwards (a camera that
    restarted) continues the sequence by one, so ``seq`` never repeats or goes back.
    """
    if previous_raw is None:
        return raw
    if raw > previous_raw:
        return previous_seq + (raw - previous_raw)
    if 0xF000 <= previous_raw <= 0xFFFF and raw < 0x1000:
        return previous_seq + (0xFFFF - previous_raw) + raw  # 16-bit ids skip 0
    return previous_seq + 1


class AravisCamera(Camera):
    """A GenICam camera (GigE Vision or USB3 Vision) through Aravis.

    ``device_id`` is what Aravis accepts: an id from ``list_cameras()`` such as
    ``Aravis-Fake-GV01`` or ``Basler-21234567``, an IP address, or None for the first camera.
    ``buffers`` is the size of the buffer pool; ``packet_size`` (GigE Vision only) sets the
    GVSP packet size in bytes, or ``"auto"`` negotiates the largest the path carries (jumbo
    frames cut the CPU cost per frame), None leaves the camera's.
    """

    kind = "aravis"

    def __init__(self, device_id: str | None = None, buffers: int = DEFAULT_BUFFERS,
                 packet_size: int | str | None = None) -> None:
        super().__init__(f"Aravis camera {device_id or '(first found)'}")
        if not 1 <= buffers <= 1024:
            raise DeviceError(f"buffers must be 1..1024, not {buffers}")
        if isinstance(packet_size, str) and packet_size != "auto":
            raise DeviceError(f"packet_size must be a number of bytes or 'auto', not {packet_size!r}")
        self.device_id = device_id
        self.buffers = buffers
        self.packet_size = packet_size
        self._camera: Any = None
        self._device: Any = None
        self._stream: Any = None
        self._lost = threading.Event()
        self._lost_handler: int | None = None
        self._stream_totals: Counter[str] = Counter()
        self._last_raw_id: int | None = None
        self._last_seq = -1
        self._bad_since: float | None = None
        self._pixel_format = "Mono8"

    # -- helpers --------------------------------------------------------------------------
    def _call(self, what: str, fn: Callable[..., T], *args: Any) -> T:
        """Call Aravis, turning ``GLib.Error`` into ``DeviceError`` (``DeviceLost`` once lost)."""
        _, GLib = load_aravis()
        try:
            return fn(*args)
        except GLib.Error as exc:
            error = DeviceLost if self._lost.is_set() else DeviceError
            raise error(f"{self.description}: {what}: {exc.message}") from None

    @property
    def camera(self) -> Any:
        """The underlying ``Aravis.Camera`` (for features edgedsm does not wrap)."""
        if self._camera is None:
            raise DeviceError(f"{self.description}: camera is not open")
        return self._camera

    @property
    def pixel_format(self) -> str:
        return self._pixel_format

    # -- lifecycle ------------------------------------------------------------------------
    def _do_open(self) -> None:
        Aravis, GLib = load_aravis()
        if self.device_id and self.device_id.startswith(FAKE_PREFIX):
            Aravis.enable_interface("Fake")
        self._lost.clear()
        self._last_raw_id = None
        target = self._open_target()
        try:
            camera = Aravis.Camera.new(target)
        except GLib.Error as exc:  # a missing camera is a GLib.Error, not a None or TypeError
            raise DeviceError(f"{self.description}: cannot open: {exc.message}") from None
        self._camera = camera
        self._device = camera.get_device()
        # The signal comes from Aravis' heartbeat thread: only set a flag there.
        lost = self._lost
        self._lost_handler = self._device.connect("control-lost", lambda *_: lost.set())
        name = self._call("model", camera.get_model_name)
        self.description = f"Aravis camera {name} {self._call('id', camera.get_device_id)}"
        try:
            self._configure_at_open()
        except BaseException:
            self._release()
            raise

    def _open_target(self) -> str | None:
        """What to hand to ``Aravis.Camera.new``: a GigE Vision camera's address where one is known.

        Without a fresh device list, Aravis opens a device id with the first discovery answer,
        whichever network interface it came in on; a camera that answers on several (the fake
        camera on loopback answers the broadcast of every interface) then streams to an address
        it cannot reach, and no frame ever arrives. So the list is updated (as ``list_cameras``
        does) and a GigE Vision camera is opened by its address, for which Aravis picks the
        interface on the camera's subnet. An IP address is used as it is; an id the list does
        not show (a user-defined name) is left to Aravis.
        """
        Aravis, _ = load_aravis()
        wanted = self.device_id
        if wanted and _is_ip_address(wanted):
            return wanted
        Aravis.update_device_list()
        for i in range(Aravis.get_n_devices()):
            names = {Aravis.get_device_id(i), Aravis.get_device_serial_nbr(i), Aravis.get_device_physical_id(i)}
            if wanted is None or wanted in names:
                address = Aravis.get_device_address(i) if Aravis.get_device_protocol(i) == "GigEVision" else None
                log.debug("%s: device %d of %d, address %s", self.description, i, Aravis.get_n_devices(), address)
                return address or Aravis.get_device_id(i)
        return wanted

    def _configure_at_open(self) -> None:
        Aravis, _ = load_aravis()
        camera = self._camera
        # A measurement needs a fixed exposure and gain: switch the automatics off.
        if self._call("exposure auto", camera.is_exposure_auto_available):
            self._call("exposure auto off", camera.set_exposure_time_auto, Aravis.Auto.OFF)
        if self._call("gain auto", camera.is_gain_auto_available):
            self._call("gain auto off", camera.set_gain_auto, Aravis.Auto.OFF)
        if self._call("acquisition mode", camera.is_feature_available, "AcquisitionMode"):
            self._call("continuous mode", camera.set_acquisition_mode, Aravis.AcquisitionMode.CONTINUOUS)
        if camera.is_gv_device() and self.packet_size is not None:
            if self.packet_size == "auto":
                self._call("packet size", camera.gv_auto_packet_size)
            else:
                self._call("packet size", camera.gv_set_packet_size, int(self.packet_size))
        self._pixel_format = self._call("pixel format", camera.get_pixel_format_as_string)

    def _do_close(self) -> None:
        if self._stream is not None:
            with contextlib.suppress(DeviceError):
                self._do_stop()
        self._release()

    def _release(self) -> None:
        """Drop the Aravis objects (which also gives up control of a GigE Vision camera).

        Unreferencing a *lost* GigE Vision device blocks for 5-8 s on control-channel
        timeouts; a reaper thread takes that wait so that reconnection can go ahead at once
        (a fresh connection to the restarted camera is not disturbed by it).
        """
        if self._device is not None and self._lost_handler is not None:
            with contextlib.suppress(Exception):
                self._device.disconnect(self._lost_handler)
        self._lost_handler = None
        doomed = [self._stream, self._device, self._camera]
        self._stream = self._device = self._camera = None
        if self._lost.is_set():
            release_in_background(doomed)
        del doomed

    def _do_start(self) -> None:
        Aravis, _ = load_aravis()
        camera = self.camera
        if self._pixel_format not in PIXEL_BITS:
            raise DeviceError(f"{self.description}: the camera is set to {self._pixel_format}, which edgedsm "
                              f"does not measure with; set one of {', '.join(PIXEL_BITS)}")
        self._bad_since = None
        stream = self._call("create stream", camera.create_stream, None, None)
        if stream is None:
            raise DeviceError(f"{self.description}: cannot create a stream")
        if isinstance(stream, Aravis.GvStream):
            # A socket buffer as large as a frame keeps bursts of a big frame from overflowing it.
            stream.set_property("socket-buffer", Aravis.GvStreamSocketBuffer.AUTO)
        payload = self._call("payload", camera.get_payload)
        for _ in range(self.buffers):
            stream.push_buffer(Aravis.Buffer.new_allocate(payload))
        self._stream = stream
        try:
            self._call("start acquisition", camera.start_acquisition)
        except DeviceError:
            self._retire_stream()
            raise

    def _do_stop(self) -> None:
        try:
            if self._camera is not None and not self._lost.is_set():
                self._call("stop acquisition", self._camera.stop_acquisition)
        finally:
            self._retire_stream()

    def _retire_stream(self) -> None:
        """Drain the output queue into the pool, keep the statistics, drop the stream.

        A lost camera's stream is dropped by the reaper thread: finalizing it writes to the
        camera's registers and so blocks for seconds on timeouts.
        """
        stream, self._stream = self._stream, None
        if stream is None:
            return
        drained = 0
        while (buffer := stream.try_pop_buffer()) is not None:
            stream.push_buffer(buffer)
            drained += 1
        if drained:
            log.debug("%s: drained %d buffers after stop", self.description, drained)
        self._stream_totals.update(_stream_infos(stream))
        if self._lost.is_set():
            doomed = [stream]
            del stream
            release_in_background(doomed)

    # -- acquisition ----------------------------------------------------------------------
    def _do_grab(self, timeout_s: float) -> Frame | None:
        # No local reference to the stream: a DeviceLost traceback would keep it (and the
        # lost device) alive, to be finalized, blocking, in the middle of the next stream.
        if self._stream is None:
            raise DeviceError(f"{self.description}: not streaming")
        started = time.monotonic()
        deadline = started + timeout_s
        check: AliveCheck | None = None
        while True:
            if self._lost.is_set():
                raise DeviceLost(f"{self.description}: control of the camera was lost")
            now = time.monotonic()
            if check is None and now >= started + timeout_s * ALIVE_CHECK_AFTER:
                check = AliveCheck(self.description, self._camera, self._device, load_aravis()[1].Error)
            if check is not None and check.lost is not None:
                self._lost.set()
                raise check.lost
            remaining = deadline - now
            if remaining <= 0:
                self._judge_silence(timeout_s, check)
            buffer = self._stream.timeout_pop_buffer(max(1, int(min(remaining, POLL_S) * 1e6)))
            if buffer is not None:
                break
        try:
            frame = self._frame_from(buffer)
        finally:
            self._stream.push_buffer(buffer)  # always back into the pool, whatever happened above
        # Bad buffers alone must not keep frames() busy for ever: after timeout_s of nothing
        # but dropped buffers, say so (heavy packet loss: network, packet size, socket buffer).
        now = time.monotonic()
        if frame is not None:
            self._bad_since = None
        elif self._bad_since is None:
            self._bad_since = now
        elif now - self._bad_since > timeout_s:
            self._bad_since = None
            dropped = ", ".join(f"{k} {v}" for k, v in sorted(self.stats.items()) if k.startswith("dropped_"))
            raise DeviceTimeout(f"{self.description}: no complete frame within {timeout_s:g} s, only dropped "
                                f"ones ({dropped}); check packet loss: network, packet size, socket buffer")
        return frame

    def _judge_silence(self, timeout_s: float, check: AliveCheck | None) -> None:
        """No frame within the timeout: ``DeviceTimeout`` if the camera answered the check,
        else ``DeviceLost`` (the check may still be waiting: the grab does not wait for it)."""
        if check is not None and check.lost is not None:
            self._lost.set()
            raise check.lost
        if check is not None and check.answered.is_set():
            raise DeviceTimeout(f"{self.description}: no frame within {timeout_s:g} s (the camera answers)")
        self._lost.set()
        raise DeviceLost(f"{self.description}: no frame within {timeout_s:g} s and no answer on the control "
                         f"channel within {timeout_s * (1 - ALIVE_CHECK_AFTER):g} s")

    def _frame_from(self, buffer: Any) -> Frame | None:
        status = buffer.get_status().value_nick  # "success", "missing-packets", ...
        if status != "success":
            self.stats[f"buffer_{status.replace('-', '_')}"] += 1
            self._dropped("incomplete" if status in _INCOMPLETE else
                          "corrupt" if status in _CORRUPT else "invalid")
            return None
        code = buffer.get_image_pixel_format()
        pixel_format = PIXEL_FORMAT_CODES.get(code)
        if pixel_format is None:
            raise DeviceError(f"{self.description}: the camera delivers pixel format 0x{code:08x}, which "
                              f"edgedsm does not measure with; set one of {', '.join(PIXEL_BITS)}")
        width, height = buffer.get_image_width(), buffer.get_image_height()
        padding, _ = buffer.get_image_padding()
        try:
            # get_image_data copies the pixels out, so the buffer can go back at once.
            pixels = decode_image(buffer.get_image_data(), pixel_format, width, height, padding)
        except DeviceError as exc:
            log.debug("%s: %s", self.description, exc)
            self.stats["buffer_short"] += 1
            self._dropped("corrupt")
            return None
        raw_id = buffer.get_frame_id()
        if self._last_raw_id is None and self._last_seq >= 0:
            seq = self._last_seq + 1  # first frame after a reopen: the camera's count may have restarted
        else:
            seq = unwrap_frame_id(self._last_raw_id, self._last_seq, raw_id)
        self._last_raw_id, self._last_seq = raw_id, seq
        t_ns = buffer.get_timestamp() or buffer.get_system_timestamp() or time.monotonic_ns()
        return Frame(pixels, seq, t_ns, PIXEL_BITS[pixel_format])

    def stream_statistics(self) -> dict[str, int]:
        """Aravis' stream counters added up over every start/stop since this object was made.

        Keys as Aravis names them: ``n_completed_buffers``, ``n_failures``, ``n_underruns``,
        ``n_timeouts``, ``n_missing_packets``, ``n_resend_requests``, ``n_resent_packets``,
        ``n_transferred_bytes``... (GigE Vision streams have more counters than USB3 or fake ones).
        """
        totals = Counter(self._stream_totals)
        if self._stream is not None:
            totals.update(_stream_infos(self._stream))
        return dict(totals)

    # -- settings -------------------------------------------------------------------------
    def _do_set_exposure(self, microseconds: float) -> float:
        camera = self.camera
        if not self._call("exposure", camera.is_exposure_time_available):
            raise DeviceError(f"{self.description}: exposure cannot be set on this camera")
        low, high = self._call("exposure bounds", camera.get_exposure_time_bounds)
        if not low <= microseconds <= high:
            raise DeviceError(f"{self.description}: exposure {microseconds:g} µs outside the camera's "
                              f"[{low:g}, {high:g}] µs")
        self._call("set exposure", camera.set_exposure_time, microseconds)
        return float(self._call("exposure", camera.get_exposure_time))

    def _do_set_frame_interval(self, seconds: float) -> float:
        camera = self.camera
        if not self._call("frame rate", camera.is_frame_rate_available):
            raise DeviceError(f"{self.description}: frame interval cannot be set on this camera")
        low, high = self._call("frame rate bounds", camera.get_frame_rate_bounds)
        rate = 1.0 / seconds
        if not low <= rate <= high:
            raise DeviceError(f"{self.description}: frame interval {seconds:g} s ({rate:g} frames/s) outside "
                              f"the camera's {low:g}..{high:g} frames/s")
        self._call("set frame rate", camera.set_frame_rate, rate)
        return 1.0 / float(self._call("frame rate", camera.get_frame_rate))

    def _do_frame_format(self) -> FrameFormat | None:
        _, _, width, height = self._call("region", self.camera.get_region)  # a buffer's image is the region
        bits = PIXEL_BITS.get(self._pixel_format)  # None: a format edgedsm does not measure with (refused at start)
        return FrameFormat.of((height, width), bits) if bits else None

    def _do_set_region(self, region: Region) -> Region:
        camera = self.camera
        width, height = self._call("sensor size", camera.get_sensor_size)
        if region.x + region.width > width or region.y + region.height > height:
            raise DeviceError(f"{self.description}: region {region} does not fit the {width}x{height} sensor")
        self._call("set region", camera.set_region, region.x, region.y, region.width, region.height)
        return Region(*self._call("region", camera.get_region))

    def _do_set_pixel_format(self, pixel_format: str) -> str:
        camera = self.camera
        offered = self._call("pixel formats", camera.dup_available_pixel_formats_as_strings) or []
        if pixel_format not in offered:
            mono = [name for name in offered if name in PIXEL_BITS]
            raise DeviceError(f"{self.description}: pixel format {pixel_format} not offered; "
                              f"this camera has {', '.join(mono) or 'no monochrome format edgedsm reads'}")
        self._call("set pixel format", camera.set_pixel_format_from_string, pixel_format)
        self._pixel_format = self._call("pixel format", camera.get_pixel_format_as_string)
        return self._pixel_format


def _is_ip_address(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


def _stream_infos(stream: Any) -> dict[str, int]:
    """The stream's integer counters by name (``arv_stream_get_info_*``)."""
    infos: dict[str, int] = {}
    for i in range(stream.get_n_infos()):
        name = stream.get_info_name(i)
        if stream.get_info_type(i).name == "guint64":
            infos[name] = int(stream.get_info_uint64(i))
    return infos
