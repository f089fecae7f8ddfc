"""Camera URIs: one documented scheme, parsed in one place, and the ``open_camera`` factory.

Grammar::

    CAMERA_URI = "aravis:" [DEVICE_ID] ["?" OPTIONS]
               | "v4l2:" (DEVICE_PATH | INDEX) ["?" OPTIONS]
               | "replay:" PATH ["?" OPTIONS]
               | "sim:" (SCENE_PATH | "default") ["?" OPTIONS]
    OPTIONS    = KEY "=" VALUE *("&" KEY "=" VALUE)

Examples::

    aravis:                              the first camera Aravis finds
    aravis:Aravis-Fake-GV01              a camera by its Aravis device id (see `edgedsm probe camera aravis:`)
    aravis:192.168.10.21?packet_size=8000
    aravis:Fake_1                        Aravis' in-process fake camera (enabled on demand)
    v4l2:/dev/video0?fourcc=GREY         a V4L2 device by path ...
    v4l2:0                               ... or by index
    replay:/data/run-12.npy?rate=30&loop=true
    replay:frames/?rate=recorded&dt=0.04
    replay:drying/%04d.bmp?channel=red   the red channel of a colour series (a red laser's speckle)
    sim:config/scenes/logos.toml?time_scale=0
    sim:default                          the built-in default scene (also plain "sim:")

Everything after the first ``?`` is edgedsm's options, so a path cannot contain ``?``.
Unknown, repeated or empty options are refused with a ``ConfigError`` saying why, so a typo
never goes unnoticed. Options per scheme:

``aravis``
    ``buffers`` size of the buffer pool, 1..1024 (default 8); ``packet_size`` GigE Vision
    packet size in bytes 576..65535, or ``auto`` to negotiate the largest the network carries
    (default: the camera's own setting).
``v4l2``
    ``fourcc`` the uncompressed format to ask for: GREY, Y10, Y12, Y16, YUYV or UYVY (default:
    the device's; compressed formats such as MJPG are refused for measurement);
    ``width``, ``height`` the resolution to ask for, 1..16384; ``channel`` red, green, blue or
    luma of a YUYV/UYVY device (default luma: the Y the device sends).
``replay``
    ``rate`` frames/s (0 = as fast as possible, the default) or ``recorded`` (the recording's
    own interval); ``dt`` the recording's frame interval in seconds where the file has none;
    ``loop`` true/false; ``bits`` significant bits per pixel 1..16 (default: the recording's, else
    from the dtype); ``channel`` red, green, blue or luma (ITU-R BT.601) of a colour recording
    (required for one: colour frames are refused without it).
``sim``
    ``time_scale`` pacing factor on the scene's Δt, >= 0 (0 = as fast as possible; default 1);
    ``precision`` single or double; ``lose_after`` frames before one simulated loss (tests);
    ``corrupt_every`` drop every n-th buffer as corrupt (tests).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from edgedsm.devices.camera.base import Camera
from edgedsm.devices.uriopts import UriOptions
from edgedsm.errors import ConfigError

if TYPE_CHECKING:
    from edgedsm.sim import Scene

SCHEMES = ("aravis", "v4l2", "replay", "sim")
#: Uncompressed V4L2 formats the V4L2 driver accepts (FOURCC → significant bits).
V4L2_RAW_FOURCCS = {"GREY": 8, "Y10 ": 10, "Y12 ": 12, "Y16 ": 16, "YUYV": 8, "UYVY": 8}

_KEYS = {
    "aravis": {"buffers", "packet_size"},
    "v4l2": {"fourcc", "width", "height", "channel"},
    "replay": {"rate", "dt", "loop", "bits", "channel"},
    "sim": {"time_scale", "precision", "lose_after", "corrupt_every"},
}
_DEVICE_ID = re.compile(r"^[\w.:\-]+$")  # Aravis ids: vendor-model-serial, IP addresses, Fake_1


@dataclass(frozen=True)
class CameraSpec:
    """A parsed camera URI: which driver, which device, which options (already typed)."""

    uri: str
    scheme: str
    target: str  # device id / device path or index / file path / scene path ("" = default)
    options: dict[str, object] = field(default_factory=dict)
    #: a sim: camera's scene, read by ``resolve_camera_spec`` (None: read when the camera is built)
    scene: Scene | None = field(default=None, compare=False, repr=False)


def _opts(uri: str) -> UriOptions:
    return UriOptions("camera", uri)


def _fail(uri: str, reason: str) -> ConfigError:
    return _opts(uri).fail(reason)


def _options(uri: str, scheme: str, query: str) -> dict[str, str]:
    return _opts(uri).split(query, _KEYS[scheme], scheme)


def parse_camera_uri(uri: str) -> CameraSpec:
    """Parse a camera URI (see the module docstring); a bad one raises ``ConfigError``."""
    if not isinstance(uri, str) or not uri.strip():
        raise ConfigError("camera URI is empty: expected e.g. aravis:, v4l2:/dev/video0, replay:PATH or sim:default")
    uri = uri.strip()
    scheme, sep, rest = uri.partition(":")
    scheme = scheme.lower()
    if not sep or scheme not in SCHEMES:
        raise _fail(uri, f"unknown scheme {scheme!r}: cameras use {', '.join(s + ':' for s in SCHEMES)}")
    target, _, query = rest.partition("?")
    raw = _options(uri, scheme, query)
    parse = {"aravis": _parse_aravis, "v4l2": _parse_v4l2, "replay": _parse_replay, "sim": _parse_sim}[scheme]
    target, options = parse(uri, target, raw)
    return CameraSpec(uri=uri, scheme=scheme, target=target, options=options)


def _parse_aravis(uri: str, target: str, raw: dict[str, str]) -> tuple[str, dict[str, object]]:
    if target and not _DEVICE_ID.match(target):
        raise _fail(uri, f"device id {target!r} may hold only letters, digits and - _ . :")
    options: dict[str, object] = {}
    if "buffers" in raw:
        options["buffers"] = _opts(uri).integer("buffers", raw["buffers"], 1, 1024)
    if "packet_size" in raw:
        text = raw["packet_size"]
        options["packet_size"] = "auto" if text == "auto" else _opts(uri).integer("packet_size", text, 576, 65535)
    return target, options


def _parse_v4l2(uri: str, target: str, raw: dict[str, str]) -> tuple[str, dict[str, object]]:
    if not target:
        raise _fail(uri, "no device: expected v4l2:/dev/video0 or v4l2:0")
    if not target.isdigit() and not target.startswith("/"):
        raise _fail(uri, f"{target!r} is neither a device path (/dev/video0) nor an index (0)")
    options: dict[str, object] = {}
    if "fourcc" in raw:
        fourcc = raw["fourcc"].upper().ljust(4)
        if fourcc not in V4L2_RAW_FOURCCS:
            raise _fail(uri, f"fourcc={raw['fourcc']!r}: measurement needs an uncompressed format, one of "
                             f"{', '.join(f.strip() for f in V4L2_RAW_FOURCCS)}")
        options["fourcc"] = fourcc
    for key in ("width", "height"):
        if key in raw:
            options[key] = _opts(uri).integer(key, raw[key], 1, 16384)
    if "channel" in raw:
        options["channel"] = _channel(uri, raw["channel"])
    return target, options


def _channel(uri: str, text: str) -> str:
    from edgedsm.frameio.channels import CHANNELS

    if text not in CHANNELS:
        raise _fail(uri, f"channel={text!r} must be one of {', '.join(CHANNELS)}")
    return text


def _parse_replay(uri: str, target: str, raw: dict[str, str]) -> tuple[str, dict[str, object]]:
    if not target:
        raise _fail(uri, "no path: expected replay:FILE_OR_FOLDER")
    options: dict[str, object] = {}
    if "rate" in raw:
        options["rate"] = "recorded" if raw["rate"] == "recorded" else _opts(uri).number("rate", raw["rate"], 0.0, 1e6)
    if "dt" in raw:
        options["dt"] = _opts(uri).number("dt", raw["dt"], 0.0, 3600.0, open_low=True)
    if "loop" in raw:
        options["loop"] = _opts(uri).boolean("loop", raw["loop"])
    if "bits" in raw:
        options["bits"] = _opts(uri).integer("bits", raw["bits"], 1, 16)
    if "channel" in raw:
        options["channel"] = _channel(uri, raw["channel"])
    return target, options


def _parse_sim(uri: str, target: str, raw: dict[str, str]) -> tuple[str, dict[str, object]]:
    target = "" if target in ("", "default") else target
    options: dict[str, object] = {}
    if "time_scale" in raw:
        options["time_scale"] = _opts(uri).number("time_scale", raw["time_scale"], 0.0, 1e6)
    if "precision" in raw:
        if raw["precision"] not in ("single", "double"):
            raise _fail(uri, f"precision={raw['precision']!r} must be single or double")
        options["precision"] = raw["precision"]
    if "lose_after" in raw:
        options["lose_after"] = _opts(uri).integer("lose_after", raw["lose_after"], 0, 2**62)
    if "corrupt_every" in raw:
        options["corrupt_every"] = _opts(uri).integer("corrupt_every", raw["corrupt_every"], 2, 2**62)
    return target, options


def resolve_camera_spec(spec: CameraSpec, base_dir: Path) -> CameraSpec:
    """The spec with a relative replay or scene path made absolute against ``base_dir`` (the
    config file's directory), and what building the camera would find checked now: a replay
    path must exist, a scene file must be valid and have a [detector]. ConfigError says why."""
    if spec.scheme not in ("sim", "replay"):
        return spec
    if spec.scheme == "sim" and not spec.target:
        from edgedsm.sim.defaults import default_scene

        return dataclasses.replace(spec, scene=default_scene())
    target = Path(spec.target)
    target = (target if target.is_absolute() else base_dir / target).resolve()
    if spec.scheme == "replay":
        if "%" in target.name:  # a numbered series: frames/%05d.png
            if not target.parent.is_dir():
                raise _fail(spec.uri, f"{target.parent}: no such directory")
            return dataclasses.replace(spec, target=str(target))
        if not target.exists():
            raise _fail(spec.uri, f"{target}: no such file or directory")
        if not (target.is_file() or target.is_dir()):
            raise _fail(spec.uri, f"{target}: not a recording (neither a regular file nor a folder)")
        return dataclasses.replace(spec, target=str(target))
    from edgedsm.sim import load_scene

    scene = load_scene(target)
    if scene.detector is None:
        raise _fail(spec.uri, f"{target}: a simulated camera needs a scene with a [detector] table")
    return dataclasses.replace(spec, target=str(target), scene=scene)


def known_frame_shape(spec: CameraSpec) -> tuple[int, int] | None:
    """(rows, columns) of the frames the camera will deliver where that is known without opening
    a device: a scene's size, a recording's first frame, a v4l2 width and height asked for. A
    recording the replay camera would refuse raises ``DataError`` (exit 65) naming the file."""
    if spec.scheme == "sim":
        if spec.scene is not None:
            return spec.scene.shape
        from edgedsm.sim import load_scene
        from edgedsm.sim.defaults import default_scene

        return (load_scene(spec.target) if spec.target else default_scene()).shape
    if spec.scheme == "replay":
        from edgedsm.devices.camera.replay import first_frame_shape

        return first_frame_shape(Path(spec.target), spec.options.get("channel"))  # type: ignore[arg-type]
    if spec.scheme == "v4l2" and "width" in spec.options and "height" in spec.options:
        return (int(spec.options["height"]), int(spec.options["width"]))  # type: ignore[call-overload]
    return None


def open_camera(uri: str | CameraSpec, *, illuminated: Callable[[], bool] | None = None) -> Camera:
    """The driver a camera URI names, constructed but not opened (use it as a context manager).

    ``illuminated`` couples a simulated camera to the laser (ignored by real cameras). Scene
    files are read here, so a bad scene raises ``ConfigError`` at once; devices are only
    touched when the camera is opened (a missing device then raises ``DeviceError``).
    """
    spec = uri if isinstance(uri, CameraSpec) else parse_camera_uri(uri)
    options = dict(spec.options)
    if spec.scheme == "aravis":
        from edgedsm.devices.camera.aravis import AravisCamera

        return AravisCamera(spec.target or None, **options)  # type: ignore[arg-type]
    if spec.scheme == "v4l2":
        from edgedsm.devices.camera.v4l2 import V4L2Camera

        device: str | int = int(spec.target) if spec.target.isdigit() else spec.target
        return V4L2Camera(device, **options)  # type: ignore[arg-type]
    if spec.scheme == "replay":
        from edgedsm.devices.camera.replay import ReplayCamera

        return ReplayCamera(Path(spec.target), **options)  # type: ignore[arg-type]
    from edgedsm.devices.camera.sim import SimulatedCamera
    from edgedsm.sim import load_scene
    from edgedsm.sim.defaults import default_scene

    if spec.scene is not None:
        scene = spec.scene.model_copy(deep=True)  # a camera may change its scene; the config keeps its own
    else:
        scene = load_scene(spec.target) if spec.target else default_scene()
    return SimulatedCamera(scene, illuminated=illuminated, **options)  # type: ignore[arg-type]


def list_cameras(scheme: str = "aravis", include_fake: bool = False) -> list[str]:
    """URIs of the cameras of one kind that can be seen now (``aravis`` or ``v4l2``).

    Aravis: every camera it discovers (``include_fake`` adds its in-process ``Fake_1``); raises
    ``DeviceError`` when Aravis is not installed. V4L2: the ``/dev/video*`` device nodes.
    """
    if scheme == "aravis":
        from edgedsm.devices.camera.aravis import list_cameras as aravis_cameras

        return [info.uri for info in aravis_cameras(include_fake=include_fake)]
    if scheme == "v4l2":
        from edgedsm.devices.camera.v4l2 import list_devices

        return [f"v4l2:{path}" for path in list_devices()]
    raise ConfigError(f"cameras can be listed for aravis and v4l2, not {scheme!r}")
