"""Aravis' fake GigE Vision camera as a real process (used by test_aravis.py and tests/faults).

``arv-fake-gv-camera-0.8 -i 127.0.0.1`` speaks real GigE Vision (GVCP control, GVSP stream over
UDP) on loopback. Aravis and the fake camera come from the Debian packages that
scripts/test.sh installs; when they are missing, tests using these FAIL and say so.
Only one fake camera can answer on 127.0.0.1 at a time (GVCP port 3956).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from edgedsm.devices.camera.aravis import list_cameras, load_aravis
from edgedsm.errors import DeviceError

FAKE_BINARY = "arv-fake-gv-camera-0.8"
ADDRESS = "127.0.0.1"
DISCOVERY_TIMEOUT_S = 10.0


def require_aravis() -> None:
    try:
        load_aravis()
    except DeviceError as exc:
        pytest.fail(f"Aravis is required for these tests (scripts/test.sh installs it): {exc}")


def serial_for_test() -> str:
    """A serial number of this test process (the fake camera's device id is Aravis-Fake-SERIAL)."""
    return f"EDG{os.getpid() % 100000}"


class FakeGvCamera:
    """One ``arv-fake-gv-camera-0.8`` process on loopback with its own serial number."""

    def __init__(self, log_dir: Path, serial: str, lost_per_thousand: int = 0) -> None:
        self.serial = serial
        self.device_id = f"Aravis-Fake-{serial}"
        self.lost_per_thousand = lost_per_thousand
        self.log_path = log_dir / f"fake-gv-{serial}.log"
        self.process: subprocess.Popen[bytes] | None = None

    def start(self, wait: bool = True) -> FakeGvCamera:
        """Start the process; ``wait`` until Aravis discovers it (bounded)."""
        binary = shutil.which(FAKE_BINARY)
        if binary is None:
            pytest.fail(f"{FAKE_BINARY} not found: install the Debian package aravis-tools (scripts/test.sh does)")
        args = [binary, "-i", ADDRESS, "-s", self.serial]
        if self.lost_per_thousand:
            args += ["-r", str(self.lost_per_thousand)]
        with self.log_path.open("ab") as log:
            self.process = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        if wait:
            self.wait_discoverable()
        return self

    def wait_discoverable(self) -> None:
        deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
        while time.monotonic() < deadline:
            assert self.process is not None
            if self.process.poll() is not None:
                pytest.fail(f"{FAKE_BINARY} exited with {self.process.returncode}: {self.log()}")
            if any(info.device_id == self.device_id for info in list_cameras()):
                return
        pytest.fail(f"{self.device_id} not discoverable within {DISCOVERY_TIMEOUT_S} s: {self.log()}")

    def kill(self) -> float | None:
        """SIGKILL (a camera losing power); returns when it was sent (monotonic), None if not running."""
        if self.process is None or self.process.poll() is not None:
            self.process = None
            return None
        killed = time.monotonic()
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(timeout=10)
        self.process = None
        return killed

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-2000:] if self.log_path.exists() else ""


def fail_if_address_taken() -> None:
    already = [info for info in list_cameras() if info.address == ADDRESS]
    if already:
        pytest.fail(f"a camera already answers on {ADDRESS} ({already[0].device_id}); stop it first "
                    f"(pgrep -a {FAKE_BINARY[:15]})")


def fake_gv_cameras(log_dir: Path) -> Iterator[Callable[..., FakeGvCamera]]:
    """Body of a fixture: starts fake cameras on loopback and kills every one of them afterwards."""
    require_aravis()
    fail_if_address_taken()
    started: list[FakeGvCamera] = []

    def make(lost_per_thousand: int = 0) -> FakeGvCamera:
        camera = FakeGvCamera(log_dir, serial_for_test(), lost_per_thousand)
        started.append(camera)
        return camera.start()

    yield make
    for camera in started:
        camera.kill()
