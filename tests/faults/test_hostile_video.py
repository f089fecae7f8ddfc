"""Fault: hostile and odd AVIs through every entry point, each as a real process (issue 34).

Until PyAV decoded videos, every uncompressed bottom-up DIB AVI killed the process with SIGABRT
or SIGBUS. Here each file of the corpus (tests/hostile_video.py: empty, garbage, cut, forged
frame counts and sizes) goes through `edgedsm analyze`, `edgedsm thsp`, `edgedsm probe camera
replay:...`, `edgedsm check-config` of a daemon config replaying it, and `edgedsm run` with a
PTY-emulated Numato relay: each ends in exit 65 with one line on stderr (the daemon: its last
line), never a signal or a traceback, at a peak RSS under 512 MiB, and the laser is off at the
end of every daemon case. The odd but good DIBs (palettized bottom-up, RGB555, BGR24) are
analysed, and the maps equal what the estimator gives on the frames written.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from helpers_daemon import write_config
from helpers_faults import RelayRig
from helpers_mqtt import child_env

from edgedsm.estimators import s1
from tests.hostile_files import Measured, measure
from tests.hostile_video import colour_palette, colours, dib_avi, expected, hostile_avis, indices

pytestmark = [pytest.mark.faults, pytest.mark.integration]

RSS_LIMIT = 512 * 2 ** 20
CLI_TIMEOUT_S = 60.0
CASES = ("empty", "garbage", "riff only", "headers only", "cut in the frames", "cut in a frame", "2^31 frames",
         "100000x100000", "16000x16000", "45000x4", "45000x4, no count", "FFV1 cut in the frames")


def run_measured(args: list[str], timeout: float = CLI_TIMEOUT_S, cwd: Path | None = None) -> Measured:
    """``python -m edgedsm ARGS``: its exit, output and its own peak RSS (not the test process's)."""
    return measure([sys.executable, "-m", "edgedsm", *args], timeout, env=child_env(), cwd=cwd)


def assert_refused(done: Measured, path: Path, what: str) -> str:
    """Exit 65, one line on stderr naming the file, no traceback, under the RSS limit."""
    lines = [line for line in done.err.splitlines() if line.strip()]
    assert done.code == 65, f"{what}: exit {done.code}\n{done.err}"
    assert "Traceback" not in done.err, f"{what}:\n{done.err}"
    assert lines and str(path.name) in lines[-1] and lines[-1].startswith("edgedsm: bad data: "), \
        f"{what}:\n{done.err}"
    assert done.rss < RSS_LIMIT, f"{what}: peak RSS {done.rss / 2 ** 20:.0f} MiB"
    return lines[-1]


def daemon_toml(tmp_path: Path, camera: str, laser: str) -> Path:
    return write_config(tmp_path / "daemon.toml", {
        "device": {"name": "hostile", "state_dir": tmp_path / "state"},
        "camera": {"uri": camera, "grab_timeout_s": 2.0, "reconnect_initial_s": 0.5, "reconnect_max_s": 1.0},
        "laser": {"uri": laser},
        "acquisition": {"dark_frames": 3, "dark_every_min": 0},
        "estimator": {"activity": "s2", "window": 8, "lag": 2, "q": 1.0},
        "regions": [{"name": "plate", "wet_above": 1e6, "dry_below": 1e5, "hysteresis": 0.05, "min_dwell_s": 0.0}],
        "logging": {"level": "info"},
    })


@pytest.mark.timeout(300)
@pytest.mark.parametrize("case", CASES)
def test_a_hostile_avi_is_refused_by_every_command(tmp_path: Path, case: str) -> None:
    path = hostile_avis(tmp_path)[case]
    config = daemon_toml(tmp_path, f"replay:{path}", "sim:")
    lines = [
        assert_refused(run_measured(["analyze", str(path), "-o", str(tmp_path / "map.npy"), "--no-progress"]),
                       path, "analyze"),
        assert_refused(run_measured(["thsp", str(path), "--row", "3", "-o", str(tmp_path / "thsp"),
                                     "--no-progress"]), path, "thsp"),
        assert_refused(run_measured(["probe", "camera", f"replay:{path}", "--frames", "40"]), path, "probe"),
    ]
    checked = run_measured(["check-config", str(config)])
    if case == "FFV1 cut in the frames":  # compressed: the cut shows only where it is read; run refuses it there
        assert checked.code == 0 and "Traceback" not in checked.err, checked.err
    else:
        lines.append(assert_refused(checked, path, "check-config"))
    assert not (tmp_path / "map.npy").exists() and not list(tmp_path.glob("thsp/*"))  # nothing half-written
    if case == "2^31 frames":
        assert all("announces 2,147,483,648 frames" in line for line in lines), lines


@pytest.mark.timeout(300)
@pytest.mark.parametrize("case", ["garbage", "cut in the frames", "2^31 frames", "16000x16000",
                                  "colour palette, no channel", "FFV1 cut in the frames"])
def test_the_daemon_refuses_a_hostile_replay_with_the_laser_off(tmp_path: Path, relay_board: RelayRig,
                                                                 case: str) -> None:
    if case == "colour palette, no channel":
        path = dib_avi(tmp_path / "colour.avi", indices(30, 48, 64, 4), 4, colour_palette(16))
    else:
        path = hostile_avis(tmp_path)[case]
    config = daemon_toml(tmp_path, f"replay:{path}?rate=50", relay_board.uri)
    done = run_measured(["run", "-c", str(config)], timeout=90.0)
    last = assert_refused(done, path, f"run ({case})")
    assert relay_board.board.is_on is False, done.err
    if case == "FFV1 cut in the frames":  # its first frames decode: the laser went on, then off at the cut
        assert "ends after" in last and "of the 40 frames its header announces" in last, last
        assert [on for _, on in relay_board.board.changes][-2:] == [True, False], relay_board.board.changes
    else:  # refused before the laser went on
        assert True not in [on for _, on in relay_board.board.changes], relay_board.board.changes


GOOD = {  # name: (frames written, bits, palette, channel, the grey frames analyze must see)
    "8-bit grey palette, bottom-up": (8, None, None),
    "4-bit colour palette, bottom-up": (4, "palette", "red"),
    "1-bit grey palette, top-down": (1, None, None),
    "RGB555, bottom-up": (16, None, "green"),
    "BGR24, bottom-up": (24, None, "blue"),
}


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", list(GOOD))
def test_analyze_maps_an_old_capture_softwares_avi_exactly(tmp_path: Path, name: str) -> None:
    bits, palette_kind, channel = GOOD[name]
    if bits <= 8:
        frames = indices(12, 24, 40, bits, seed=bits)
        palette = colour_palette(1 << bits) if palette_kind else None
    else:
        frames, palette = colours(12, 24, 40, top=31 if bits == 16 else 255, seed=bits), None
    path = dib_avi(tmp_path / "old.avi", frames, bits, palette, top_down="top-down" in name)
    rgb = expected(frames, bits, palette)
    grey = rgb[..., {"red": 0, "green": 1, "blue": 2}[channel]] if channel else rgb[..., 0]
    out = tmp_path / "s1.npy"
    done = run_measured(["analyze", str(path), "--estimator", "s1", "--lag", "2", "-o", str(out), "--no-progress",
                         *(["--channel", channel] if channel else [])])
    assert done.code == 0, done.err
    assert np.allclose(np.load(out), s1(grey, 2), rtol=1e-5, atol=1e-4)
