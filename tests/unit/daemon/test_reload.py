"""A reload checks the new configuration completely before the running one is touched (issue 11 §3)."""

from __future__ import annotations

import uuid
from pathlib import Path

import pytest

from edgedsm.config import load_config
from edgedsm.daemon.reload import ReloadRefused, check_reload
from edgedsm.devices.laser import forget_simulated_boards, simulated_board

SCENE = Path(__file__).resolve().parents[3] / "config" / "scenes" / "drying_demo.toml"  # 128x128


def config_text(camera: str, laser: str | None = None, region: str = "") -> str:
    text = f'[device]\nname = "reload"\n\n[camera]\nuri = "{camera}"\n\n'
    if laser is not None:
        text += f'[laser]\nuri = "{laser}"\n\n'
    return text + f'[[regions]]\nname = "plate"\nwet_above = 0.3\ndry_below = 0.16\n{region}\n'


@pytest.fixture
def running(tmp_path):
    path = tmp_path / "running.toml"
    path.write_text(config_text(f"sim:{SCENE}?time_scale=0.2"), encoding="utf-8")
    return load_config(path)


@pytest.fixture
def board_name():
    forget_simulated_boards()
    yield f"reload-{uuid.uuid4().hex[:8]}"
    forget_simulated_boards()


OUTSIDE = 'shape = "rect"\nx = 500\ny = 500\nwidth = 10\nheight = 10'


def test_a_good_file_for_another_camera_is_opened_checked_and_accepted(tmp_path, running):
    path = tmp_path / "new.toml"
    path.write_text(config_text(f"sim:{SCENE}", region='shape = "rect"\nx = 10\ny = 10\nwidth = 20\nheight = 20'),
                    encoding="utf-8")
    new = check_reload(path, running, running_shape=(64, 64))
    assert new.camera.uri == f"sim:{SCENE}" and new.regions[0].x == 10


def test_a_region_outside_the_frame_of_a_new_camera_is_refused(tmp_path, running):
    path = tmp_path / "new.toml"
    path.write_text(config_text(f"sim:{SCENE}", region=OUTSIDE), encoding="utf-8")
    # the new camera is opened and its 128x128 frame is what the region is checked against
    with pytest.raises(ReloadRefused, match=r"cannot run: .*regions\.0: region 'plate' has no pixel inside the 128"):
        check_reload(path, running, running_shape=(4096, 4096))


def test_a_region_outside_the_running_cameras_frame_is_refused(tmp_path, running):
    path = tmp_path / "new.toml"
    path.write_text(config_text(running.camera.uri, region=OUTSIDE), encoding="utf-8")
    with pytest.raises(ReloadRefused, match=r"no pixel inside the 128x128 frame"):
        check_reload(path, running, running_shape=(128, 128))


def test_a_new_relay_that_does_not_answer_is_refused(tmp_path, running, board_name):
    path = tmp_path / "new.toml"
    path.write_text(config_text(running.camera.uri, laser=f"sim:{board_name}?fault=no-answer&timeout=0.01"),
                    encoding="utf-8")
    with pytest.raises(ReloadRefused, match=r"cannot run: .*no answer within 0.01 s"):
        check_reload(path, running, running_shape=(128, 128))
    path.write_text(config_text(running.camera.uri, laser=f"sim:{board_name}?timeout=0.01"), encoding="utf-8")
    simulated_board(board_name).fault = "none"
    new = check_reload(path, running, running_shape=(128, 128))
    assert new.laser is not None and not simulated_board(board_name).is_on


@pytest.mark.parametrize(("data", "why"), [
    (b'[device]\nname = "\xff\xfe"\n', "UnicodeDecodeError|not UTF-8"),
    (b"[device\n", "not valid TOML"),
    (b"[device]\nname = 5\n", "bad configuration"),
])
def test_a_file_that_does_not_decode_or_validate_is_refused_not_a_traceback(tmp_path, running, data, why):
    path = tmp_path / "new.toml"
    path.write_bytes(data)
    with pytest.raises(ReloadRefused, match=why):
        check_reload(path, running, running_shape=(128, 128))
