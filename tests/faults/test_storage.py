"""Fault: the state directory fails under the running daemon process (the sink-level cases are in
tests/integration/test_storage_faults.py): a 512 kB tmpfs filled up while alerts are being raised
and freed again, and a read-only state directory at start. Each tmpfs is unmounted afterwards.

Full: the daemon never exits, publishes one ``storage`` fault with the real cause, keeps every
alert (in memory, still published: none lost after dedup), keeps measuring, and writes to the
disk again once space returns. Read-only at start: one clear line, exit 78, the laser never on.
"""

from __future__ import annotations

import errno
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from helpers_daemon import DEMO_PLATE, Daemon
from helpers_faults import Plant, RelayRig, daemon_config
from helpers_mqtt import REPO, Broker
from test_storage_faults import tmpfs  # noqa: F401  (the fixture: small tmpfs mounts, unmounted after)

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]

DRYING_CAMERA = f"sim:{REPO / 'config' / 'scenes' / 'drying_demo.toml'}?time_scale=0.2"
TRANSITION = r"region plate: \w+ -> \w+"


def fill(directory: Path) -> Path:
    """Fill the file system under ``directory`` to the last byte; returns the filler file."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        for block in (65536, 4096, 1):  # unbuffered, down to the last byte
            while True:
                try:
                    os.write(fd, b"\0" * block)
                except OSError as exc:
                    assert exc.errno == errno.ENOSPC
                    break
    finally:
        os.close(fd)
    return filler


@pytest.mark.timeout(60)
def test_state_dir_full_while_alerts_are_raised_then_freed(
        tmp_path: Path, tmpfs: Callable[..., Path], relay_board: RelayRig, broker: Broker,  # noqa: F811
        plant: Plant, daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    board = relay_board.board
    disk = tmpfs("size=512k")
    config = daemon_config(tmp_path, camera=DRYING_CAMERA, port=broker.port, laser=relay_board.uri,
                           window=100, lag=5, **DEMO_PLATE, min_dwell_s=1.0)
    config["device"]["state_dir"] = disk / "state"
    daemon = daemons(config)
    daemon.wait_until(lambda: board.is_on and plant.frames() > 0, 30, "measuring with the laser on")
    filler = fill(disk)
    filled = time.monotonic()
    daemon.wait_log(r"region plate: drying -> dry", 40, after=daemon.started)
    daemon.wait_until(lambda: len([a for a in plant.distinct_alerts() if a.get("type") != "fault"])
                      >= len(daemon.matching(TRANSITION)), 15, "every transition's alert at the plant")
    storage = [a for a in plant.fault_alerts() if a["reason"].startswith("storage")]
    raised_full = len([t for t, _ in daemon.matching(TRANSITION) if t > filled])
    filler.unlink()  # space returns
    freed = time.monotonic()
    freed_frames = plant.frames()
    daemon.wait_log(r"storage: .* takes writes again; \d+ alert\(s\) held in memory written back", 10, after=freed)
    daemon.wait_until(lambda: plant.measuring_since(freed_frames), 15, "measuring after the disk was freed")
    daemon.process.send_signal(2)  # SIGINT: a clean stop, so the queue is written back
    code = daemon.process.wait(timeout=15)
    assert code == 0, daemon.log
    alerts = plant.distinct_alerts()
    raised = len(daemon.matching(TRANSITION))
    print(f"512 kB state dir full: {raised_full} of {raised} transitions raised while full, "
          f"{len(alerts)} alerts after dedup (storage faults: {len(storage)})")
    assert raised_full >= 1, "no alert was raised while the disk was full"
    assert len(storage) == 1, plant.distinct_alerts()
    assert "full" in storage[0]["reason"] or "space" in storage[0]["reason"], storage
    assert [a["seq"] for a in alerts] == list(range(1, len(alerts) + 1)), alerts
    assert len(alerts) == raised + len(storage)
    assert "Traceback" not in daemon.log
    assert not board.is_on


@pytest.mark.timeout(60)
def test_read_only_state_dir_at_start_is_one_line_exit_78_laser_never_on(
        tmp_path: Path, tmpfs: Callable[..., Path], relay_board: RelayRig, broker: Broker,  # noqa: F811
        daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    read_only = tmpfs("size=64k,ro")
    config = daemon_config(tmp_path, camera=DRYING_CAMERA, port=broker.port, laser=relay_board.uri)
    config["device"]["state_dir"] = read_only / "state"
    daemon = daemons(config)
    code = daemon.process.wait(timeout=30)
    daemon.kill()  # joins the log reader
    assert code == 78, daemon.log
    assert "Traceback" not in daemon.log
    errors = [line for _, line in daemon.matching(r"state_dir")]
    assert errors and "Read-only file system" in errors[0], daemon.log
    assert not [on for _, on in relay_board.board.commands if on], relay_board.board.commands
