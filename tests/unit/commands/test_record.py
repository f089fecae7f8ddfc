"""`edgedsm record`: what the simulated camera produced comes back bit-identically through
`analyze` and `replay:`; the laser is on while recording only and off on every way out."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.devices.camera import open_camera
from edgedsm.devices.laser import forget_simulated_boards, simulated_board
from edgedsm.estimators import s1
from edgedsm.frameio import open_frames
from edgedsm.frameio.recording import RecordingWriter

SCENE = """[scene]
size = 48
frames = 40
seed = 3
dt = 0.02

[activity]
tau_c = 6.0

[detector]
n_max = 3000
bits = 12
"""


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    return path


@pytest.fixture
def board():
    forget_simulated_boards()
    yield simulated_board("record-test")
    forget_simulated_boards()


def _config(tmp_path, scene, extra=""):
    path = tmp_path / "line.toml"
    path.write_text(f'[device]\nname = "line"\n\n[camera]\nuri = "sim:{scene}?time_scale=0{extra}"\n'
                    f'exposure_us = 800\n\n[laser]\nuri = "sim:record-test"\n')
    return path


def test_a_recording_of_the_simulated_camera_reads_back_bit_identically(tmp_path, scene, capsys):
    uri = f"sim:{scene}?time_scale=0"
    out = tmp_path / "run.tif"
    assert main(["record", uri, "-o", str(out), "--frames", "12", "--no-progress"]) == 0
    assert "recorded 12 frames of 48x48 uint16 (12 bits)" in capsys.readouterr().out
    with open_camera(uri) as camera:  # the same seeded scene: the frames the camera produced
        produced = list(camera.frames(12))
    with open_frames(out) as reader:
        recorded = list(reader.frames())
        stamps = reader.stamps()
    assert all(np.array_equal(a, b.pixels) for a, b in zip(recorded, produced, strict=True))
    assert stamps.seq.tolist() == [f.seq for f in produced] and stamps.t_ns.tolist() == [f.t_ns for f in produced]
    assert stamps.laser == ("none",) * 12
    # analyze: the map of the recording is the map of the camera's frames
    assert main(["analyze", str(out), "--window", "12", "--lag", "2", "-o", str(tmp_path / "m.npy")]) == 0
    assert np.array_equal(np.load(tmp_path / "m.npy"), s1(np.stack([f.pixels for f in produced]), 2))
    # replay: the same pixels, sequence numbers and timestamps
    with open_camera(f"replay:{out}") as replay:
        replayed = list(replay.frames())
    assert [(f.seq, f.t_ns, f.bits) for f in replayed] == [(f.seq, f.t_ns, 12) for f in produced]
    assert all(np.array_equal(a.pixels, b.pixels) for a, b in zip(replayed, produced, strict=True))


def test_with_a_config_the_laser_is_on_while_recording_and_off_after(tmp_path, scene, board, capsys):
    out = tmp_path / "lit.tif"
    assert main(["record", "-c", str(_config(tmp_path, scene)), "-o", str(out), "--frames", "5",
                 "--no-progress"]) == 0
    assert not board.is_on
    assert [s.on for s in board.history][:2] == [False, True] and not board.history[-1].on
    with open_frames(out) as reader:
        stamps = reader.stamps()
        assert reader.header["exposure_us"] == 800.0 and reader.count == 5
        lit = np.stack(list(reader.frames())).astype(float)
    assert stamps.laser == ("on",) * 5 and stamps.seq.tolist() == [1, 2, 3, 4, 5]  # frame 0: while switching
    assert lit.std() > 50  # speckle: the simulated camera saw the laser


def test_the_laser_is_off_after_a_camera_error_and_the_frames_so_far_are_kept(tmp_path, scene, board, capsys):
    out = tmp_path / "lost.tif"
    config = _config(tmp_path, scene, extra="&lose_after=4")
    assert main(["record", "-c", str(config), "-o", str(out), "--frames", "10", "--no-progress"]) == 69
    err = capsys.readouterr().err
    assert "keeps the 3 frames recorded before" in err and "Traceback" not in err
    assert not board.is_on and not board.history[-1].on
    with open_frames(out) as reader:
        assert reader.count == 3


@pytest.mark.parametrize(("stop", "code", "said"), [("ctrl-c", 130, "Ctrl-C"), ("sigterm", 143, "SIGTERM")])
def test_the_laser_is_off_after_ctrl_c_or_sigterm(tmp_path, scene, board, capsys, monkeypatch, stop, code, said):
    write = RecordingWriter.write

    def interrupted(self, frame, laser="none"):
        if self.count == 2:
            assert board.is_on
            if stop == "ctrl-c":
                raise KeyboardInterrupt
            os.kill(os.getpid(), signal.SIGTERM)  # handled by the laser's safety: raises in this thread
        write(self, frame, laser)

    monkeypatch.setattr(RecordingWriter, "write", interrupted)
    out = tmp_path / "stopped.tif"
    assert main(["record", "-c", str(_config(tmp_path, scene)), "-o", str(out), "--frames", "50",
                 "--no-progress"]) == code
    assert f"stopped by {said}: {out} holds the 2 frames recorded" in capsys.readouterr().err
    assert not board.is_on
    with open_frames(out) as reader:
        assert reader.count == 2


def test_seconds_a_config_camera_and_refusals(tmp_path, scene, board, capsys):
    out = tmp_path / "timed.tif"
    assert main(["record", "-c", str(_config(tmp_path, scene)), "-o", str(out), "--seconds", "0.3",
                 "--no-progress"]) == 0
    with open_frames(out) as reader:
        assert reader.count >= 1
    before = out.read_bytes()
    assert main(["record", f"sim:{scene}", "-o", str(out), "--frames", "3"]) == 73
    assert "never overwritten" in capsys.readouterr().err and out.read_bytes() == before
    assert main(["record", "-o", str(tmp_path / "x.tif"), "--frames", "3"]) == 78
    assert main(["record", "sim:default?bogus=1", "-o", str(tmp_path / "y.tif"), "--frames", "3"]) == 78
    assert not (tmp_path / "x.tif").exists() and not (tmp_path / "y.tif").exists()


def test_a_full_disk_is_one_line_exit_74_and_the_frames_before_stay_readable(tmp_path, scene):
    # RLIMIT_FSIZE makes writes past 300 kB fail with EFBIG, as a full disk fails them with ENOSPC
    out = tmp_path / "full.tif"
    script = ("import resource, sys\n"
              "resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, resource.RLIM_INFINITY))\n"
              "from edgedsm.cli import main\n"
              f"sys.exit(main(['record', 'sim:{scene}?time_scale=0', '-o', '{out}', '--frames', '100',"
              " '--no-progress', '--codec', 'none']))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 74, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "could not be written" in done.stderr
    with open_frames(out) as reader:  # 48x48 uint16 = 4.6 kB per page: about 60 frames fit
        kept = reader.count
        assert 40 < kept < 66 and sum(1 for _ in reader.frames()) == kept
    assert f"keeps the {kept} frames recorded before" in done.stderr
