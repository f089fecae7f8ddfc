"""The hostile-file corpus (tests/hostile_files.py) through the commands, one process per case:
``edgedsm analyze FILE -o MAP.npy --png`` and ``edgedsm check-config`` of a daemon config whose
camera is ``replay:FILE`` (and one whose region mask lies). Each: no signal, no traceback, exit
65 (66 for a missing file; 78 for a missing replay path, the config's problem), one line on
stderr naming the file and its claim, nothing written, and the process's peak RSS (wait4) under
512 MiB. ``edgedsm run`` on the same files: tests/faults/test_hostile_replay.py.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from tests.hostile_files import CASES, mask_cases, run_measured

pytestmark = [pytest.mark.integration, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
RSS_LIMIT_MIB = 512
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}


def _edgedsm(*args: str) -> tuple[int, str, float]:
    return run_measured([sys.executable, "-m", "edgedsm", *args], timeout=60, env=ENV)


def _config(tmp_path: Path, camera: str, regions: str | None = None) -> Path:
    config = tmp_path / "daemon.toml"
    config.write_text(f'[device]\nname = "hostile"\nstate_dir = "{tmp_path / "state"}"\n'
                      f'[camera]\nuri = "{camera}"\n'
                      f'[estimator]\nactivity = "s2"\nwindow = 20\nlag = 2\n'
                      + (regions or '[[regions]]\nname = "plate"\nwet_above = 1.0\ndry_below = 0.5\n'))
    return config


def _one_refusal(stderr: str, path: Path, fragment: str) -> str:
    lines = stderr.splitlines()
    assert "Traceback" not in stderr and len(lines) == 1, stderr
    assert str(path.parent) in lines[0] and fragment in lines[0], stderr
    return lines[0]


@pytest.mark.timeout(90)
@pytest.mark.parametrize("name", sorted(CASES))
def test_analyze_refuses_each_case_in_one_line_writing_nothing(tmp_path, name):
    write, code, fragment = CASES[name]
    path = write(tmp_path)
    out = tmp_path / "out"
    got, stderr, rss = _edgedsm("analyze", str(path), "--estimator", "s2", "--window", "4", "--lag", "1",
                                "-o", str(out / "map.npy"), "--png")
    print(f"analyze {name}: exit {got}, peak RSS {rss:.0f} MiB")
    assert got == code, stderr
    line = _one_refusal(stderr, path, fragment)
    assert line.startswith("edgedsm: bad data: " if code == 65 else "edgedsm: no input: ")
    assert not out.exists() or list(out.iterdir()) == []
    assert rss < RSS_LIMIT_MIB


@pytest.mark.timeout(90)
@pytest.mark.parametrize("name", sorted(CASES))
def test_check_config_refuses_each_case_as_a_replay_camera(tmp_path, name):
    write, code, fragment = CASES[name]
    path = write(tmp_path)
    got, stderr, rss = _edgedsm("check-config", str(_config(tmp_path, f"replay:{path}")))
    print(f"check-config {name}: exit {got}, peak RSS {rss:.0f} MiB")
    assert rss < RSS_LIMIT_MIB
    if name == "missing":  # the config names a file that is not there: a configuration error, key path first
        assert got == 78 and "Traceback" not in stderr, stderr
        assert stderr.splitlines()[0] == "edgedsm: configuration error:" and "camera.uri" in stderr
        return
    assert got == code, stderr
    assert _one_refusal(stderr, path, fragment).startswith("edgedsm: bad data: ")


@pytest.mark.timeout(90)
@pytest.mark.parametrize("name", ["png_huge", "bmp_huge"])
def test_check_config_refuses_a_mask_whose_header_claims_too_much(tmp_path, name):
    mask = mask_cases(tmp_path)[name]
    regions = f'[[regions]]\nname = "plate"\nwet_above = 1.0\ndry_below = 0.5\nshape = "mask"\npath = "{mask}"\n'
    got, stderr, rss = _edgedsm("check-config", str(_config(tmp_path, "sim:default", regions)))
    print(f"check-config mask {name}: exit {got}, peak RSS {rss:.0f} MiB")
    assert got == 65, stderr
    _one_refusal(stderr, mask, "header of the mask claims frames of")
    assert rss < RSS_LIMIT_MIB
