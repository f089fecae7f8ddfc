"""The machine rules of edgedsm.daemon.preflight, one by one (the commands that apply them:
tests/unit/commands/test_check_config.py)."""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest

from edgedsm.config import load_config
from edgedsm.daemon import engine_budget
from edgedsm.daemon.preflight import (
    _engine_pixels,
    filesystem_type,
    known_frame_bits,
    listen_problem,
    preflight,
    state_dir_problem,
)
from edgedsm.daemon.reload import ReloadRefused, check_reload
from edgedsm.errors import ConfigError


def _load(directory: Path, text: str) -> Path:
    path = directory / "line3.toml"
    path.write_text(text)
    return path


def test_file_system_types_from_the_mount_table(tmp_path: Path) -> None:
    assert filesystem_type(Path("/proc")) == "proc"
    assert filesystem_type(Path("/proc/self/status")) == "proc"
    assert filesystem_type(Path("/sys")) == "sysfs"
    assert filesystem_type(tmp_path) not in (None, "proc", "sysfs", "devtmpfs")


def test_a_state_dir_is_probed_and_left_as_it_was(tmp_path: Path) -> None:
    assert state_dir_problem(tmp_path) is None
    assert list(tmp_path.iterdir()) == []  # the probe file is gone
    assert state_dir_problem(tmp_path / "a" / "b") is None  # can be created ...
    assert not (tmp_path / "a").exists()  # ... and is not
    (tmp_path / "f").write_text("")
    assert state_dir_problem(tmp_path / "f") == "not a directory"
    assert state_dir_problem(Path("/proc/1")) == ("on a proc file system, which keeps no files (give a directory "
                                                  "on a disk, e.g. /var/lib/edgedsm)")


def test_a_read_only_state_dir_is_refused(tmp_path: Path) -> None:
    # a read-only bind of the folder is the sure way (root passes permission bits)
    target = tmp_path / "ro"
    target.mkdir()
    if subprocess.run(["mount", "--bind", "-o", "ro", str(tmp_path), str(target)], capture_output=True).returncode:
        pytest.skip("cannot bind-mount here (not root or no mount namespace)")
    try:
        assert state_dir_problem(target) == "not writable (Read-only file system)"
        said = state_dir_problem(target / "new")
        assert said == f"cannot be created: {target} is not writable (Read-only file system)"
    finally:
        subprocess.run(["umount", str(target)], check=True)


def test_listen_addresses() -> None:
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    assert listen_problem("127.0.0.1", port) is None
    assert listen_problem("localhost", port) is None
    assert listen_problem("0.0.0.0", port) is None
    assert "does not resolve" in (listen_problem("no-such-host.invalid", port) or "")
    assert listen_problem("192.0.2.1", port) == "cannot listen there (192.0.2.1: Cannot assign requested address)"


def test_the_largest_part_of_the_memory_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(engine_budget, "available_memory", lambda: 10 * 2**30)  # 8 GiB usable
    shape = (1024, 1024)
    engine_budget.check_engine_memory(shape, 4000.0, queues={"acquisition.queue_max_mib": 2**30})  # 3.9 + 1 GiB
    with pytest.raises(ConfigError, match=r"^estimator\.window: .* needs 7\.8 GiB .*; with the frame queues "
                                          r"\(acquisition\.queue_max_mib 1\.0 GiB\) 8\.8 GiB; this machine has 10\.0"):
        engine_budget.check_engine_memory(shape, 8000.0, queues={"acquisition.queue_max_mib": 2**30})
    with pytest.raises(ConfigError, match=r"^recording\.queue_max_mib: .* need 9\.0 GiB \(estimator 1\.0 GiB, "
                                          r"acquisition\.queue_max_mib 0\.5 GiB, recording\.queue_max_mib 7\.5 GiB\)"):
        engine_budget.check_engine_memory(shape, 1024.0, queues={"acquisition.queue_max_mib": 2**29,
                                                                 "recording.queue_max_mib": 15 * 2**29})


def test_queue_bytes_follow_the_config(tmp_path: Path) -> None:
    path = _load(tmp_path, '[camera]\nuri = "sim:default"\n[acquisition]\nqueue_max_mib = 100\n'
                           '[recording]\nmode = "alerts"\nring_max_mib = 30\nqueue_max_mib = 20\n')
    config = load_config(path)
    frame = 1000 * 1000
    # the camera's queue holds whole frames up to its bound: 104 frames of 1 MB = 99.2 MiB
    assert engine_budget.queue_bytes(config, (1000, 1000), 8) == {
        "acquisition.queue_max_mib": (100 * 2**20 // frame) * frame,
        "recording.queue_max_mib": 20 * 2**20, "recording.ring_max_mib": 30 * 2**20}
    config.acquisition.queue_frames = 7
    assert engine_budget.queue_bytes(config, (1000, 1000), 12)["acquisition.queue_frames"] == 7 * 2 * frame


def test_frame_bits_known_before_opening(tmp_path: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text("[scene]\nsize = 64\n[activity]\ntau_c = 3.0\n[detector]\nn_max = 1000\nbits = 12\n")
    np.save(tmp_path / "rec16.npy", np.zeros((3, 8, 8), np.uint16))
    np.save(tmp_path / "rec8.npy", np.zeros((3, 8, 8), np.uint8))
    cases = {f'uri = "sim:{scene}"': 12, f'uri = "sim:{scene}"\npixel_format = "Mono16"': 16,
             'uri = "replay:rec16.npy"': 16, 'uri = "replay:rec8.npy"': 8, 'uri = "aravis:"': 8}
    for camera, bits in cases.items():
        assert known_frame_bits(load_config(_load(tmp_path, f"[camera]\n{camera}\n"))) == bits, camera


def test_the_engine_of_area_regions_sees_their_box(tmp_path: Path) -> None:
    regions = "".join(f'[[regions]]\nname = "r{i}"\nshape = "rect"\nx = {x}\ny = {y}\nwidth = 10\nheight = 20\n'
                      "wet_above = 0.2\ndry_below = 0.05\n" for i, (x, y) in enumerate([(5, 7), (100, 50)]))
    config = load_config(_load(tmp_path, f'[camera]\nuri = "sim:default"\n[estimator]\narea = "regions"\n{regions}'))
    assert _engine_pixels(config, (256, 256)) == (70 - 7) * (110 - 5)
    config.estimator.area = "frame"
    assert _engine_pixels(config, (256, 256)) == 256 * 256


def test_regions_outside_the_frame_are_said_before_memory(tmp_path: Path) -> None:
    text = ('[camera]\nuri = "sim:default"\n[[regions]]\nname = "far"\nshape = "rect"\nx = 5000\ny = 0\n'
            "width = 10\nheight = 10\nwet_above = 0.2\ndry_below = 0.05\n")
    with pytest.raises(ConfigError, match=r"regions\.0: region 'far' has no pixel inside the 64x64 frame"):
        preflight(load_config(_load(tmp_path, text)), (64, 64))


def test_a_reload_is_refused_by_the_same_rules(tmp_path: Path) -> None:
    base = f'[device]\nstate_dir = "{tmp_path}/state"\n[camera]\nuri = "sim:default"\n'
    running = load_config(_load(tmp_path, base))
    _load(tmp_path, base + '[http]\nlisten = "no-such-host.invalid:9108"\n')
    with pytest.raises(ReloadRefused, match=r"http\.listen: no-such-host\.invalid:9108: 'no-such-host\.invalid' "
                                            "does not resolve"):
        check_reload(tmp_path / "line3.toml", running, (64, 64))
