"""Fault: hostile files as the daemon's replay camera (`edgedsm run`, a process) with a Numato
relay on a socat PTY (the laser).

1. A file from the hostile corpus (tests/hostile_files.py) as ``replay:``: the daemon ends with
   exit 65 (66 / 78 for a missing file), no signal, no traceback, the refusal in one line, the
   relay off at the end (never switched on), peak RSS under 512 MiB.
2. A replayed .npy truncated in place, and one rewritten in place, while the laser is ON: no
   SIGBUS (the .npy is read, never memory-mapped); the daemon ends cleanly (exit 65, the file
   named), and the relay is checked off.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers_daemon import Daemon, write_config
from helpers_faults import RelayRig, daemon_config
from helpers_mqtt import child_env

from tests import hostile_files

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]

#: The corpus cases run through the daemon: one per reader and kind of lie (every case runs
#: through the readers, analyze and check-config in tests/unit/frameio and tests/integration).
DAEMON_CASES = ("npy_huge_shape", "npy_negative_shape", "npy_zero_frames", "npy_pickled_objects", "npy_truncated",
                "npy_garbage", "tiff_six_bytes", "tiff_deflate_bomb", "tiff_huge_tile", "folder_png_huge",
                "folder_bmp_huge", "folder_empty_png", "missing")
RSS_LIMIT_MIB = 512
FRAME = (64, 64)


def _config(tmp_path: Path, camera: str, laser: str) -> dict[str, Any]:
    config = daemon_config(tmp_path, camera=camera, port=1, laser=laser)
    for key in ("mqtt", "cadence"):  # no broker: the relay and the exit are what is checked
        config.pop(key)
    return config


def _env() -> dict[str, str]:
    return {k: v for k, v in child_env().items() if not k.startswith(("NOTIFY_SOCKET", "WATCHDOG_"))}


def _refusal_lines(log: str) -> list[str]:
    return [line for line in log.splitlines() if line.startswith("edgedsm: ")]


@pytest.mark.timeout(60)
@pytest.mark.parametrize("case", DAEMON_CASES)
def test_a_hostile_replay_file_ends_the_daemon_cleanly_with_the_laser_off(
        tmp_path: Path, case: str, relay_board: RelayRig) -> None:
    write, code, fragment = hostile_files.CASES[case]
    path = write(tmp_path)
    config = write_config(tmp_path / "daemon.toml", _config(tmp_path, f"replay:{path}", relay_board.uri))
    got, log, rss_mib = hostile_files.run_measured([sys.executable, "-m", "edgedsm", "run", "-c", str(config)],
                                                   timeout=40, env=_env())
    assert got >= 0, f"killed by signal {signal.Signals(-got).name}:\n{log}"
    assert "Traceback" not in log, log
    expected = 78 if case == "missing" else code  # a missing replay path is the config's: exit 78
    assert got == expected, log
    refusals = _refusal_lines(log)
    assert len(refusals) == 1, log  # one refusal ...
    if case == "missing":  # ... under the config's header line, the key path naming the file
        assert refusals == ["edgedsm: configuration error:"] and f"camera.uri: camera URI 'replay:{path}'" in log
    else:  # ... naming the file and what it claims
        assert str(path.parent) in refusals[0] and fragment in refusals[0], log
    assert not relay_board.board.is_on
    assert all(not on for _, on in relay_board.board.commands), relay_board.board.commands  # never on
    print(f"{case}: exit {got}, peak RSS {rss_mib:.0f} MiB")
    assert rss_mib < RSS_LIMIT_MIB


def _stack(path: Path, count: int) -> None:
    rng = np.random.default_rng(1)
    stack = np.lib.format.open_memmap(path, mode="w+", dtype=np.uint8, shape=(count, *FRAME))
    stack[:] = rng.integers(0, 256, (count, *FRAME), dtype=np.uint8)
    stack.flush()
    del stack


def _truncate(path: Path) -> None:
    os.truncate(path, path.stat().st_size // 3)  # in place: same inode, pages gone from under a map


def _rewrite(path: Path) -> None:
    with open(path, "r+b") as file:  # in place, as `cp other.npy path` does: truncated, then written again
        data = file.read()
        file.seek(0)
        file.truncate()
        file.write(data[: len(data) // 2])
        file.flush()
        os.fsync(file.fileno())


@pytest.mark.timeout(90)
@pytest.mark.parametrize("change", [_truncate, _rewrite], ids=["truncated", "rewritten"])
def test_a_replayed_npy_changed_in_place_while_the_laser_is_on(
        tmp_path: Path, change: Callable[[Path], None], relay_board: RelayRig,
        daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    path = tmp_path / "long.npy"
    _stack(path, 6000)  # 60 s at 100 frames/s: still replaying when the file changes
    board = relay_board.board
    daemon = daemons(_config(tmp_path, f"replay:{path}?rate=100", relay_board.uri))
    daemon.wait_until(lambda: board.is_on, 40, "the laser on (measuring)")
    daemon.wait_log(r"measur|frames", 20)
    time.sleep(1.0)
    assert board.is_on and daemon.process.poll() is None
    changed = time.monotonic()
    change(path)
    got = daemon.wait(30)
    log = daemon.log
    assert got >= 0, f"killed by signal {signal.Signals(-got).name} (SIGBUS is what a mapped file gives):\n{log}"
    assert got == 65, log
    assert "Traceback" not in log, log
    assert any(str(path) in line and "changed while being read" in line for line in _refusal_lines(log)), log
    off = board.switched(False, after=changed)
    assert off is not None and not board.is_on, board.changes
    print(f"{change.__name__}: relay off {off - changed:.2f} s after the file changed; the daemon said: "
          f"{_refusal_lines(log)[-1]}")
    assert off - changed < 10.0
