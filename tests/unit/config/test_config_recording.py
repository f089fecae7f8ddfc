"""``[recording]``: defaults, bounds, the folder resolved against the config file's folder (or
the state directory), unknown codecs and keys refused with their key path, a reload of it keeps
the measurement, and check-config's disk budget."""

from __future__ import annotations

import json

import pytest

from edgedsm.cli import main
from edgedsm.config import load_config
from edgedsm.daemon.reload import restart_reasons


def _write(path, recording: str, extra: str = ""):
    path.write_text(f'[device]\nstate_dir = "/var/lib/x"\n[camera]\nuri = "sim:default"\n{extra}'
                    f"[recording]\n{recording}", encoding="utf-8")
    return path


def test_dir_is_relative_to_the_config_file_or_under_the_state_dir(tmp_path):
    (tmp_path / "etc").mkdir()
    config = load_config(_write(tmp_path / "etc" / "a.toml", 'dir = "rec"\nmode = "continuous"\n'))
    assert config.recording_dir == tmp_path / "etc" / "rec"
    config = load_config(_write(tmp_path / "b.toml", 'mode = "timelapse"\nevery_s = 5\n'))
    assert str(config.recording_dir) == "/var/lib/x/recordings"
    config = load_config(_write(tmp_path / "c.toml", 'dir = "/data/rec"\n'))
    assert str(config.recording_dir) == "/data/rec" and config.recording.mode == "alerts"


@pytest.mark.parametrize(("line", "key"), [('codec = "jpeg"', "recording.codec"), ('mode = "often"', "recording.mode"),
                                           ("max_bytes = 1000", "recording.max_bytes"),
                                           ("pre_s = -1", "recording.pre_s"), ("speed = 2", "recording.speed")])
def test_bad_settings_are_refused_with_their_key_path(tmp_path, capsys, line, key):
    path = _write(tmp_path / "bad.toml", line + "\n")
    assert main(["check-config", str(path)]) == 78
    assert key in capsys.readouterr().err


def test_a_changed_recording_table_keeps_the_measurement(tmp_path):
    old = load_config(_write(tmp_path / "a.toml", 'mode = "alerts"\n'))
    new = load_config(_write(tmp_path / "b.toml", 'mode = "continuous"\nmax_bytes = 100000000\n'))
    assert restart_reasons(new, old) == []


def test_check_config_prints_the_disk_budget(tmp_path, capsys):
    camera = '[camera]\nuri = "sim:default"\nframe_interval_s = 0.04\n'
    path = tmp_path / "c.toml"
    path.write_text(f'{camera}[recording]\nmode = "continuous"\nmax_bytes = 1_000_000_000\nkeep_days = 7\n',
                    encoding="utf-8")
    assert main(["check-config", str(path)]) == 0
    line = next(text for text in capsys.readouterr().out.splitlines() if text.startswith("recording:"))
    # 256² 8-bit at 25 frames/s: 1.64 MB/s raw, ÷ 1.37 (zstd on speckle) = 1.2 MB/s: 1 GB in 0.232 h
    assert "1.64 MB/s raw" in line and "1.2 MB/s on disk" in line and "after 0.232 h" in line, line
    assert main(["check-config", "--json", str(path)]) == 0
    budget = json.loads(capsys.readouterr().out)["recording"]
    assert budget["turnover_h"] == pytest.approx(1e9 / (25 * 65536 / 1.37) / 3600)
    path.write_text(f'{camera}[recording]\nmode = "alerts"\npre_s = 10\npost_s = 20\nring_max_mib = 4\n',
                    encoding="utf-8")
    assert main(["check-config", "--json", str(path)]) == 0
    budget = json.loads(capsys.readouterr().out)["recording"]
    assert budget["ring_frames"] == 64 and budget["ring_s"] == pytest.approx(2.56)  # 4 MiB of 64 KiB frames
    assert budget["clip_mb"] == pytest.approx((64 + 500) * 65536 / 1.37 / 1e6)


def test_the_example_configs_recording_table_is_valid_uncommented(repo, tmp_path):
    text = (repo / "config" / "daemon" / "example.toml").read_text()
    head, _, rest = text.partition("\n# [recording]\n")
    assert rest, "example.toml has no commented [recording] table"
    table = rest.split("\n\n", 1)[0]
    lines = [line.removeprefix("# ") for line in table.splitlines() if line.startswith("# ")]
    path = tmp_path / "example.toml"
    path.write_text(head + "\n[recording]\n" + "\n".join(lines) + "\n", encoding="utf-8")
    config = load_config(path)
    assert config.recording is not None and config.recording.mode == "alerts"
    assert config.recording_dir == tmp_path / "recordings" and config.recording.max_bytes == 10 * 2**30
