"""``edgedsm probe camera``: the field tool, on simulated and replayed cameras."""

from __future__ import annotations

import numpy as np

from edgedsm.cli import main

SCENE = """
[scene]
size = 16
frames = 4
seed = 3
dt = 0.01
[activity]
tau_c = 5.0
[detector]
bits = 8
"""


def test_probe_a_simulated_camera(tmp_path, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE)
    assert main(["probe", "camera", f"sim:{scene}?time_scale=0", "--frames", "5", "--frame-rate", "50"]) == 0
    out = capsys.readouterr().out
    assert "size: 16 x 16 pixels" in out and "uint8 with 8 significant bits" in out
    assert "frame rate set: 50 frames/s" in out
    assert "50.0 frames/s by the frame timestamps" in out  # the simulated camera's clock
    assert "frame numbers: 0..4, 0 missing upstream" in out


def test_probe_reports_grey_levels_and_saturation(tmp_path, capsys):
    frames = np.zeros((4, 10, 10), dtype=np.uint16)
    frames[:, 0, :5] = 4095  # 5 % of the pixels at the top of 12 bits
    frames[:, 1, :] = 100
    np.save(tmp_path / "rec.npy", frames)
    assert main(["probe", "camera", f"replay:{tmp_path / 'rec.npy'}?bits=12", "--frames", "4"]) == 0
    out = capsys.readouterr().out
    assert "grey levels: mean 214.8, min 0, max 4095 (of 4095); saturated 5.000 %" in out
    assert "warning: more than 0.1 % of the pixels are saturated" in out


def test_probe_errors_exit_codes(capsys):
    assert main(["probe", "camera", "v4l2:/dev/video-missing"]) == 69  # EX_UNAVAILABLE
    assert "no such device /dev/video-missing" in capsys.readouterr().err
    assert main(["probe", "camera", "sim:default?speed=3"]) == 78
    assert "unknown option 'speed' for sim" in capsys.readouterr().err
