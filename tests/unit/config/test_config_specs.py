"""The config owns parsing: camera and relay specs parsed once, relative paths resolved against the
config file's directory, and regions checked against the camera's frame size before the laser goes on."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.config import check_regions, load_config, load_relay_spec
from edgedsm.daemon.devices import open_camera_for
from edgedsm.devices.camera.replay import ReplayCamera
from edgedsm.devices.camera.sim import SimulatedCamera
from edgedsm.devices.camera.uri import CameraSpec, known_frame_shape
from edgedsm.errors import ConfigError

SCENE = "[scene]\nsize = 32\n[activity]\ntau_c = 5\n[detector]\nbits = 8\n"
REGION = "[[regions]]\nname = '{name}'\nwet_above = 2\ndry_below = 1\n"


def _write(path, text: str):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _config(folder, camera: str, regions: str = "", laser: str = ""):
    text = f"[camera]\nuri = '{camera}'\n" + (f"[laser]\nuri = '{laser}'\n" if laser else "")
    return _write(folder / "etc" / "c.toml", text + (regions or REGION.format(name="all")))


def test_camera_spec_is_parsed_once_with_paths_relative_to_the_config(tmp_path, monkeypatch):
    _write(tmp_path / "scenes" / "s.toml", SCENE)
    monkeypatch.chdir(tmp_path / "scenes")  # the working directory must not matter
    config = load_config(_config(tmp_path, "sim:../scenes/s.toml?time_scale=0", laser="sim:x?readback=false"))
    spec = config.camera.spec
    assert isinstance(spec, CameraSpec) and spec.scheme == "sim"
    assert spec.target == str((tmp_path / "scenes" / "s.toml").resolve())
    assert spec.scene is not None and spec.scene.scene.size == 32  # the scene file was read once, here
    assert spec.options == {"time_scale": 0.0}
    assert config.laser is not None
    relay = config.laser.spec
    assert (relay.kind, relay.port, relay.options) == ("sim", "x", {"readback": False})
    camera = open_camera_for(config)
    assert isinstance(camera, SimulatedCamera) and camera.scene.scene.size == 32 and camera.time_scale == 0


def test_replay_path_is_relative_to_the_config(tmp_path):
    np.save(_npy(tmp_path), np.zeros((3, 8, 8), np.uint8))
    config = load_config(_config(tmp_path, "replay:rec.npy?rate=0"))
    assert config.camera.spec.target == str((tmp_path / "etc" / "rec.npy").resolve())
    assert isinstance(open_camera_for(config), ReplayCamera)


def _npy(tmp_path):
    (tmp_path / "etc").mkdir(parents=True, exist_ok=True)
    return tmp_path / "etc" / "rec.npy"


@pytest.mark.parametrize(("camera", "message"), [
    ("sim:no-such-scene.toml", r"camera\.uri: .*no-such-scene\.toml: file not found"),
    ("replay:no-such-recording.npy", r"camera\.uri: .*no-such-recording\.npy: no such file or directory"),
    ("sim:bad.toml", r"camera\.uri: .*bad\.toml: scene\.colour: unknown key"),
    ("sim:nodetector.toml", r"camera\.uri: .*nodetector\.toml: .*\[detector\] table"),
])
def test_what_opening_the_camera_would_find_is_found_at_load(tmp_path, capsys, camera, message):
    _write(tmp_path / "etc" / "bad.toml", "[scene]\ncolour = 1\n[activity]\ntau_c = 5\n")
    _write(tmp_path / "etc" / "nodetector.toml", "[activity]\ntau_c = 5\n")
    path = _config(tmp_path, camera)
    with pytest.raises(ConfigError, match=message):
        load_config(path)
    assert main(["check-config", str(path)]) == 78
    assert "Traceback" not in capsys.readouterr().err


def test_known_frame_shapes(tmp_path):
    _write(tmp_path / "etc" / "s.toml", SCENE)
    assert known_frame_shape(load_config(_config(tmp_path, "sim:s.toml")).camera.spec) == (32, 32)
    assert known_frame_shape(load_config(_config(tmp_path, "sim:default")).camera.spec) == (256, 256)
    np.save(_npy(tmp_path), np.zeros((3, 6, 9), np.uint8))
    assert known_frame_shape(load_config(_config(tmp_path, "replay:rec.npy")).camera.spec) == (6, 9)
    (tmp_path / "etc" / "frames").mkdir()
    for index in range(2):
        cv2.imwrite(str(tmp_path / "etc" / "frames" / f"{index}.png"), np.zeros((5, 7), np.uint8))
    assert known_frame_shape(load_config(_config(tmp_path, "replay:frames")).camera.spec) == (5, 7)
    assert known_frame_shape(load_config(_config(tmp_path, "v4l2:0?width=640&height=480")).camera.spec) == (480, 640)
    assert known_frame_shape(load_config(_config(tmp_path, "aravis:Fake_1")).camera.spec) is None


def _regions(*bodies: str) -> str:
    return "".join(REGION.format(name=f"r{index}") + body + "\n" for index, body in enumerate(bodies))


def test_check_regions_against_the_frame(tmp_path):
    regions = _regions("shape = 'rect'\nx = 10\ny = 10\nwidth = 20\nheight = 20",           # inside 32x32
                       "shape = 'rect'\nx = 100\ny = 100\nwidth = 5\nheight = 5",           # no pixel inside
                       "shape = 'circle'\ncx = 30\ncy = 16\nradius = 8",                    # partly outside
                       "shape = 'polygon'\npoints = [[-4, 0], [10, 0], [0, 10]]",           # partly outside
                       "")                                                                  # full: always fits
    config = load_config(_config(tmp_path, "sim:default", regions))
    with pytest.raises(ConfigError) as info:
        check_regions(config, (32, 32))
    lines = str(info.value).splitlines()
    assert len(lines) == 3
    assert lines[0].endswith("regions.1: region 'r1' has no pixel inside the 32x32 frame")
    assert lines[1].endswith("regions.2: region 'r2' reaches outside the 32x32 frame (right)")
    assert lines[2].endswith("regions.3: region 'r3' reaches outside the 32x32 frame (left)")
    assert all(line.startswith(str(tmp_path / "etc" / "c.toml")) for line in lines)
    check_regions(config.model_copy(update={"regions": [config.regions[0], config.regions[4]]}), (32, 32))


def test_check_regions_passes_regions_that_fit(tmp_path):
    config = load_config(_config(tmp_path, "sim:default", _regions("shape = 'rect'\nwidth = 32\nheight = 32",
                                                                    "shape = 'circle'\ncx = 16\ncy = 16\nradius = 16")))
    check_regions(config, (32, 32))
    with pytest.raises(ConfigError, match=r"regions\.0: region 'r0' reaches outside the 32x31 frame \(bottom\)"):
        check_regions(config, (31, 32))  # rows, columns


def test_check_config_checks_regions_when_the_frame_size_is_known(tmp_path, capsys):
    _write(tmp_path / "etc" / "s.toml", SCENE)
    path = _config(tmp_path, "sim:s.toml", _regions("shape = 'rect'\nx = 20\ny = 20\nwidth = 20\nheight = 5"))
    assert main(["check-config", str(path)]) == 78
    err = capsys.readouterr().err
    assert "regions.0: region 'r0' reaches outside the 32x32 frame (right)" in err and "Traceback" not in err
    _write(path, path.read_text().replace("width = 20", "width = 10"))
    assert main(["check-config", str(path)]) == 0
    assert "1 region(s) inside the 32x32 frame" in capsys.readouterr().out


def test_the_relay_is_found_even_in_an_otherwise_broken_config(tmp_path):
    # `edgedsm laser off --config FILE` (ExecStopPost) must switch off even when the scene is gone
    path = _write(tmp_path / "c.toml", "[camera]\nuri = 'sim:gone.toml'\n[estimator]\nwindow = 'x'\n"
                                       "[laser]\nuri = 'serial:/dev/ttyUSB0?protocol=lcus&channel=2'\n")
    with pytest.raises(ConfigError):
        load_config(path)
    spec = load_relay_spec(path)
    assert spec is not None and (spec.protocol, spec.port, spec.channel) == ("lcus", "/dev/ttyUSB0", 2)
    assert load_relay_spec(_write(tmp_path / "none.toml", "[camera]\nuri = 'sim:'\n")) is None
    with pytest.raises(ConfigError, match=r"bad\.toml: laser\.uri: .*unknown option 'chanel'"):
        load_relay_spec(_write(tmp_path / "bad.toml", "[laser]\nuri = 'sim:?chanel=1'\n"))
