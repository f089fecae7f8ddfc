"""Check a camera before starting the service: list what is there, grab frames, show numbers.

  edgedsm probe camera aravis:                      list every Aravis camera, probe the first
  edgedsm probe camera aravis:Aravis-Fake-GV01      probe one camera by its device id (or IP)
  edgedsm probe camera v4l2:/dev/video0 --frames 100
  edgedsm probe camera replay:run-12.npy
  edgedsm probe camera sim:default

For each probe it prints the cameras it can see (Aravis: all it discovers; V4L2: the
/dev/video* nodes), then grabs N frames and prints the image size, pixel format, frames/s
and grey-level statistics: mean, min, max and the saturated fraction (pixels at the top of
the bit depth: more than a few per mille means lower the exposure or the laser power).
Dropped buffers and the stream counters (lost and resent packets) follow where the driver
keeps them. Stop the edgedsm service first: a GigE Vision camera has one controller at a time.

CAMERA_URI (see edgedsm/devices/camera/uri.py for every option):
  aravis:[DEVICE_ID][?buffers=8&packet_size=auto]
  v4l2:/dev/video0 | v4l2:0 [?fourcc=GREY&width=1280&height=720]
  replay:PATH[?rate=30&loop=true]
  sim:SCENE.toml | sim:default [?time_scale=0]

Exit status: 0 frames grabbed, 1 no camera or no frames, 78 bad CAMERA_URI.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import sys
import time

import numpy as np

from edgedsm.commands.broker_options import seconds
from edgedsm.devices.camera.base import Camera
from edgedsm.devices.camera.uri import CameraSpec, open_camera, parse_camera_uri
from edgedsm.errors import DeviceError
from edgedsm.frames import Frame

NAME = "probe"
HELP = "check a camera: list cameras, grab frames, print size, format, frames/s, grey levels"


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 1 <= value <= 1_000_000:
        raise argparse.ArgumentTypeError("give 1 to 1000000")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("device", choices=("camera",), help="what to probe (camera)")
    parser.add_argument("uri", metavar="CAMERA_URI", help="the camera, e.g. aravis:, v4l2:/dev/video0, sim:default")
    parser.add_argument("--frames", "-n", type=_positive_int, default=30, metavar="N",
                        help="frames to grab (default 30)")
    parser.add_argument("--timeout", type=seconds, default=5.0, metavar="SECONDS",
                        help="longest wait for one frame (default 5)")
    parser.add_argument("--pixel-format", metavar="FORMAT", help="set a pixel format first, e.g. Mono12p")
    parser.add_argument("--exposure", type=seconds, metavar="MICROSECONDS",
                        help="set the exposure first (µs)")
    parser.add_argument("--frame-rate", type=seconds, metavar="FPS", help="set the frame rate first")
    parser.add_argument("--json", action="store_true",
                        help="print the measurements as one JSON object on stdout (the lines go to stderr)")


def _say(text: str) -> None:
    print(text, flush=True)


def list_visible(spec: CameraSpec) -> None:
    """Print the cameras of the URI's kind that can be seen now."""
    if spec.scheme == "aravis":
        from edgedsm.devices.camera.aravis import list_cameras

        cameras = list_cameras(include_fake=spec.target.startswith("Fake_"))
        _say(f"Aravis cameras found: {len(cameras)}")
        for info in cameras:
            where = f" at {info.address}" if info.protocol == "GigEVision" else ""
            _say(f"  {info.uri:<32} {info.vendor} {info.model}, serial {info.serial}, {info.protocol}{where}")
        if not cameras:
            _say("  (none: check cabling, power, the network interface's address and subnet, and the firewall "
                 "for UDP 3956)")
    elif spec.scheme == "v4l2":
        from edgedsm.devices.camera.v4l2 import list_devices

        devices = list_devices()
        _say(f"V4L2 devices found: {len(devices)}" + "".join(f"\n  v4l2:{path}" for path in devices))


def describe_format(camera: Camera, frame: Frame) -> str:
    name = getattr(camera, "pixel_format", None)
    kind = f"{name}, " if isinstance(name, str) and name else ""
    return f"{kind}{frame.pixels.dtype} with {frame.bits} significant bits"


def summarize(frames: list[Frame], seconds: float) -> dict[str, float]:
    """Frames/s and grey-level statistics over all grabbed frames."""
    stack = np.stack([f.pixels for f in frames])
    top = 2 ** frames[0].bits - 1
    fps = (len(frames) - 1) / seconds if len(frames) > 1 and seconds > 0 else float("nan")
    span = (frames[-1].t_ns - frames[0].t_ns) / 1e9
    return {"fps": fps, "camera_fps": (len(frames) - 1) / span if span > 0 else float("nan"),
            "mean": float(stack.mean()), "min": float(stack.min()), "max": float(stack.max()),
            "saturated": float(np.count_nonzero(stack >= top)) / stack.size, "top": float(top)}


def run(args: argparse.Namespace) -> int:
    if not args.json:
        _probe(args)
        return 0
    with contextlib.redirect_stdout(sys.stderr):  # the readable lines go to stderr, the JSON alone to stdout
        result = _probe(args)
    print(json.dumps(result, default=_json_number))
    return 0


def _json_number(value: object) -> object:
    return None if isinstance(value, float) and not math.isfinite(value) else str(value)


def _probe(args: argparse.Namespace) -> dict[str, object]:
    """Probe the camera, printing as it goes; returns what was measured."""
    spec = parse_camera_uri(args.uri)
    list_visible(spec)
    camera = open_camera(spec)
    _say(f"probing {spec.uri} ...")
    with camera:
        _say(f"opened: {camera.description}")
        if args.pixel_format:
            _say(f"pixel format set: {camera.set_pixel_format(args.pixel_format)}")
        if args.exposure:
            _say(f"exposure set: {camera.set_exposure(args.exposure):g} µs")
        if args.frame_rate:
            _say(f"frame rate set: {1 / camera.set_frame_interval(1 / args.frame_rate):g} frames/s")
        frames: list[Frame] = []
        started = time.monotonic()
        first_at = started
        for frame in camera.frames(args.frames, timeout_s=args.timeout):
            if not frames:
                first_at = time.monotonic()  # frames/s from the first frame on: start-up is not the rate
            frames.append(frame)
        elapsed = time.monotonic() - first_at
        if not frames:
            raise DeviceError(f"{camera.description}: no frames")
        stats = summarize(frames, elapsed)
        height, width = frames[0].shape
        _say(f"size: {width} x {height} pixels")
        _say(f"format: {describe_format(camera, frames[0])}")
        _say(f"frames: {len(frames)} in {time.monotonic() - started:.2f} s (first after "
             f"{first_at - started:.2f} s); {stats['fps']:.1f} frames/s received, "
             f"{stats['camera_fps']:.1f} frames/s by the frame timestamps")
        _say(f"grey levels: mean {stats['mean']:.1f}, min {stats['min']:.0f}, max {stats['max']:.0f} "
             f"(of {stats['top']:.0f}); saturated {100 * stats['saturated']:.3f} %")
        gaps = sum(b.seq - a.seq - 1 for a, b in itertools.pairwise(frames))
        _say(f"frame numbers: {frames[0].seq}..{frames[-1].seq}, {gaps} missing upstream")
        counters = {k: v for k, v in sorted(camera.stats.items()) if k != "delivered"}
        _say("driver counters: " + (", ".join(f"{k} {v}" for k, v in counters.items()) or "no drops"))
        stream_stats = getattr(camera, "stream_statistics", None)
        if callable(stream_stats):
            shown = {k: v for k, v in stream_stats().items() if v}
            _say("stream counters: " + ", ".join(f"{k.removeprefix('n_')} {v}" for k, v in shown.items()))
        if stats["saturated"] > 0.001:
            _say("warning: more than 0.1 % of the pixels are saturated; lower the exposure or laser power")
    finite = {key: (value if math.isfinite(value) else None) for key, value in stats.items()}
    return {"uri": spec.uri, "camera": camera.description, "width": width, "height": height,
            "format": describe_format(camera, frames[0]), "bits": frames[0].bits, "frames": len(frames),
            "first_seq": frames[0].seq, "last_seq": frames[-1].seq, "missing_upstream": gaps,
            "driver_counters": counters, **finite}
