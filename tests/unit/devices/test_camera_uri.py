"""Camera URIs: the grammar, option validation with clear reasons, and the open_camera factory."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.devices.camera import ReplayCamera, SimulatedCamera
from edgedsm.devices.camera.aravis import AravisCamera
from edgedsm.devices.camera.uri import list_cameras, open_camera, parse_camera_uri
from edgedsm.devices.camera.v4l2 import V4L2Camera
from edgedsm.errors import ConfigError

SCENE = """
[scene]
size = 16
frames = 4
seed = 3
[activity]
tau_c = 5.0
[detector]
bits = 8
"""


@pytest.mark.parametrize(("uri", "scheme", "target", "options"), [
    ("aravis:", "aravis", "", {}),
    ("aravis:Aravis-Fake-GV01", "aravis", "Aravis-Fake-GV01", {}),
    ("aravis:127.0.0.1?buffers=16&packet_size=8000", "aravis", "127.0.0.1", {"buffers": 16, "packet_size": 8000}),
    ("aravis:Fake_1?packet_size=auto", "aravis", "Fake_1", {"packet_size": "auto"}),
    ("ARAVIS:Basler-21234567", "aravis", "Basler-21234567", {}),
    ("v4l2:/dev/video0", "v4l2", "/dev/video0", {}),
    ("v4l2:2?fourcc=grey&width=640&height=480", "v4l2", "2", {"fourcc": "GREY", "width": 640, "height": 480}),
    ("v4l2:/dev/v4l/by-id/usb-cam-video-index0?fourcc=Y16", "v4l2", "/dev/v4l/by-id/usb-cam-video-index0",
     {"fourcc": "Y16 "}),
    ("replay:/data/run.npy?rate=30&loop=true", "replay", "/data/run.npy", {"rate": 30.0, "loop": True}),
    ("replay:frames/?rate=recorded&dt=0.04&bits=12", "replay", "frames/",
     {"rate": "recorded", "dt": 0.04, "bits": 12}),
    ("replay:drying/%04d.bmp?channel=red", "replay", "drying/%04d.bmp", {"channel": "red"}),
    ("v4l2:0?fourcc=YUYV&channel=luma", "v4l2", "0", {"fourcc": "YUYV", "channel": "luma"}),
    ("sim:scene.toml?time_scale=0", "sim", "scene.toml", {"time_scale": 0.0}),
    ("sim:default", "sim", "", {}),
    ("sim:", "sim", "", {}),
    ("sim:default?precision=double&lose_after=5&corrupt_every=3", "sim", "",
     {"precision": "double", "lose_after": 5, "corrupt_every": 3}),
])
def test_valid_uris(uri, scheme, target, options):
    spec = parse_camera_uri(uri)
    assert (spec.scheme, spec.target, spec.options) == (scheme, target, options)


@pytest.mark.parametrize(("uri", "reason"), [
    ("", "empty"),
    ("/dev/video0", "unknown scheme"),
    ("gige:cam1", "unknown scheme 'gige'"),
    ("aravis:?buffer=4", "unknown option 'buffer' for aravis (known: buffers, packet_size)"),
    ("aravis:cam?buffers=0", "buffers=0 is out of range 1..1024"),
    ("aravis:cam?buffers=many", "buffers='many' is not a whole number"),
    ("aravis:cam?packet_size=100", "packet_size=100 is out of range 576..65535"),
    ("aravis:my cam", "may hold only letters"),
    ("aravis:cam?buffers=4&buffers=5", "given twice"),
    ("aravis:cam?buffers=", "has no value"),
    ("aravis:cam?buffers", "cannot read the options"),
    ("v4l2:", "no device"),
    ("v4l2:video0", "neither a device path"),
    ("v4l2:0?fourcc=MJPG", "uncompressed format"),
    ("v4l2:0?width=0", "width=0 is out of range"),
    ("v4l2:0?rate=30", "unknown option 'rate' for v4l2"),
    ("replay:", "no path"),
    ("replay:x.npy?rate=-1", "rate=-1 must be >= 0"),
    ("replay:x.npy?rate=fast", "rate='fast' is not a number"),
    ("replay:x.npy?dt=0", "dt=0 must be > 0"),
    ("replay:x.npy?loop=sometimes", "loop='sometimes' must be true or false"),
    ("replay:x.npy?bits=17", "bits=17 is out of range 1..16"),
    ("replay:x.npy?time_scale=0", "unknown option 'time_scale' for replay"),
    ("replay:x.npy?channel=purple", "channel='purple' must be one of red, green, blue, luma"),
    ("v4l2:0?channel=Red", "channel='Red' must be one of"),
    ("sim:default?time_scale=nan", "time_scale=nan must be >= 0"),
    ("sim:default?precision=half", "precision='half' must be single or double"),
    ("sim:default?corrupt_every=1", "corrupt_every=1 is out of range"),
])
def test_invalid_uris_say_why(uri, reason):
    with pytest.raises(ConfigError) as caught:
        parse_camera_uri(uri)
    assert reason in str(caught.value)
    if uri:
        assert repr(uri) in str(caught.value)  # the message names the URI


def test_open_camera_builds_the_named_driver_unopened(tmp_path):
    stack = np.arange(2 * 4 * 5, dtype=np.uint8).reshape(2, 4, 5)
    np.save(tmp_path / "rec.npy", stack)
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE)

    aravis = open_camera("aravis:Fake_1?buffers=3")
    assert isinstance(aravis, AravisCamera) and aravis.device_id == "Fake_1" and aravis.buffers == 3
    assert open_camera("aravis:").device_id is None  # first camera found
    v4l2 = open_camera("v4l2:3?fourcc=GREY")
    assert isinstance(v4l2, V4L2Camera) and v4l2.device == 3 and v4l2.path == "/dev/video3"
    assert open_camera("v4l2:/dev/video7").device == "/dev/video7"

    replay = open_camera(f"replay:{tmp_path / 'rec.npy'}?rate=0&loop=true")
    assert isinstance(replay, ReplayCamera) and replay.loop and not replay.is_open
    with replay:
        frames = list(replay.frames(3))
    np.testing.assert_array_equal(frames[2].pixels, stack[0])  # looped

    sim = open_camera(f"sim:{scene}?time_scale=0")
    assert isinstance(sim, SimulatedCamera) and sim.scene.scene.size == 16
    with sim:
        assert next(sim.frames(1)).pixels.shape == (16, 16)
    lit = {"on": False}
    default = open_camera("sim:default?time_scale=0", illuminated=lambda: lit["on"])
    assert isinstance(default, SimulatedCamera) and default.scene.scene.size == 256
    assert default.illuminated is not None and default.illuminated() is False


def test_bad_scene_file_is_a_config_error(tmp_path):
    scene = tmp_path / "bad.toml"
    scene.write_text("[scene]\nsize = 16\nframez = 3\n")
    with pytest.raises(ConfigError):
        open_camera(f"sim:{scene}")


def test_list_cameras_of_an_unlistable_kind_is_refused():
    with pytest.raises(ConfigError, match="aravis and v4l2"):
        list_cameras("replay")
    assert all(uri.startswith("v4l2:/dev/video") for uri in list_cameras("v4l2"))


def test_a_replay_pattern_resolves_against_its_folder(tmp_path):
    from edgedsm.devices.camera.uri import resolve_camera_spec

    (tmp_path / "seq").mkdir()
    spec = resolve_camera_spec(parse_camera_uri("replay:seq/%04d.png?channel=red"), tmp_path)
    assert spec.target == str(tmp_path / "seq" / "%04d.png")
    with pytest.raises(ConfigError, match="no such directory"):
        resolve_camera_spec(parse_camera_uri("replay:missing/%04d.png"), tmp_path)
