"""Exit codes systemd can act on: 78 configuration, 65 bad data, 69 device unavailable; one clear
message on stderr, never a traceback for bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.devices.camera.replay import ReplayCamera
from edgedsm.errors import ConfigError, DataError, DeviceError, DeviceUnavailable, EdgedsmError


def test_each_error_carries_its_exit_code():
    assert (ConfigError.exit_code, DataError.exit_code, DeviceError.exit_code) == (78, 65, 69)
    assert DeviceUnavailable.exit_code == 69 and issubclass(DeviceUnavailable, DeviceError)
    assert EdgedsmError.exit_code == 1


def test_a_missing_input_exits_66_and_says_no_input(tmp_path, capsys):
    assert main(["analyze", str(tmp_path / "absent.npy"), "--estimator", "s1", "--window", "4",
                 "--lag", "1", "-o", str(tmp_path / "map.npy")]) == 66
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("edgedsm: no input: "), err
    assert not (tmp_path / "map.npy").exists()


def _folder(tmp_path, sizes):
    folder = tmp_path / "frames"
    folder.mkdir()
    for index, (height, width) in enumerate(sizes):
        cv2.imwrite(str(folder / f"{index:03d}.png"), np.full((height, width), 7 * index, np.uint8))
    return folder


def test_replay_of_frames_that_change_size_names_the_file(tmp_path):
    folder = _folder(tmp_path, [(16, 16), (16, 16), (16, 20), (16, 16)])
    with pytest.raises(DataError, match=r"002\.png: 16x20 frame .* 16x16"), ReplayCamera(folder):
        pass


def test_probe_of_a_corrupt_recording_exits_65(tmp_path, capsys):
    folder = _folder(tmp_path, [(16, 16), (12, 16)])
    assert main(["probe", "camera", f"replay:{folder}", "--frames", "2"]) == 65
    err = capsys.readouterr().err
    assert "001.png" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_replay_of_a_file_that_is_not_a_recording_exits_65(tmp_path, capsys):
    path = tmp_path / "rec.npy"
    path.write_bytes(b"this is not numpy")
    assert main(["probe", "camera", f"replay:{path}", "--frames", "2"]) == 65
    assert "rec.npy" in capsys.readouterr().err


def test_a_replay_frame_of_another_size_mid_stream_is_bad_data(tmp_path):
    folder = _folder(tmp_path, [(16, 16), (16, 16)])
    camera = ReplayCamera(folder)
    with camera:
        frames = camera.frames(1, timeout_s=1.0)
        assert next(iter(frames)).shape == (16, 16)
        # replaced after the headers were checked at open: found when it is decoded
        cv2.imwrite(str(folder / "001.png"), np.zeros((8, 8), np.uint8))
        with pytest.raises(DataError, match=r"001\.png: frame 1 is a 8x8 frame"):
            list(camera.frames(1, timeout_s=1.0))


def test_a_missing_device_at_start_exits_69(tmp_path, capsys):
    assert main(["probe", "camera", "v4l2:/dev/no-such-video", "--frames", "1"]) == 69
    err = capsys.readouterr().err
    assert "/dev/no-such-video" in err and "Traceback" not in err


def test_analyze_of_a_corrupt_recording_exits_65(tmp_path, capsys):
    path = tmp_path / "rec.npy"
    path.write_bytes(b"\x93NUMPY garbage")
    assert main(["analyze", str(path), "--estimator", "s1", "--window", "4", "--lag", "1",
                 "-o", str(tmp_path / "map.npy")]) == 65
    err = capsys.readouterr().err
    assert "rec.npy" in err and "Traceback" not in err


def test_probe_of_a_colour_replay_needs_a_channel(tmp_path, capsys):
    folder = tmp_path / "colour"
    folder.mkdir()
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (12, 16, 3), dtype=np.uint8) for _ in range(3)]
    for index, frame in enumerate(frames, start=1):
        cv2.imwrite(str(folder / f"img_{index}.bmp"), frame)
    assert main(["probe", "camera", f"replay:{folder}", "--frames", "2"]) == 65
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "colour" in err and "channel=" in err
    assert main(["probe", "camera", f"replay:{folder}?channel=green", "--frames", "3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["mean"] == pytest.approx(np.mean([f[:, :, 1] for f in frames]))  # green is index 1 of B, G, R
