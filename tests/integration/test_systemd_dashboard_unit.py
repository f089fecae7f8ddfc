"""The dashboard's service unit, checked by systemd's own tools (no running systemd needed):
`systemd-analyze verify` accepts it and `security --offline` rates it at most 2.0. It never
touches devices (no laser, no camera) and reads the daemons' configs it is given."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "edgedsm-dashboard.service"
INSTALLED = "/opt/edgedsm/.venv/bin/edgedsm"


@pytest.fixture
def testable_unit(tmp_path: Path) -> Path:
    stub = tmp_path / "edgedsm"
    stub.write_text("#!/bin/sh\nexit 0\n")
    stub.chmod(0o755)
    text = UNIT.read_text()
    assert text.count(INSTALLED) == 1
    unit = tmp_path / UNIT.name
    unit.write_text(text.replace(INSTALLED, str(stub)))
    return unit


def _analyze() -> str:
    path = shutil.which("systemd-analyze")
    if path is None:
        pytest.fail("systemd-analyze is not installed: apt-get install -y systemd (scripts/test.sh does)")
    return path


def test_the_unit_runs_the_dashboard_without_devices() -> None:
    text = UNIT.read_text()
    # this machine only: the plant network through a TLS proxy or a drop-in with HTTPS and a viewer login
    assert f"ExecStart={INSTALLED} dashboard --config-dir /etc/edgedsm --listen 127.0.0.1:8080" in text
    assert "LoadCredential=dashboard-viewer-password:/etc/edgedsm/credentials/dashboard.viewer-password" in text
    # the key that signs rebaseline and dark for the daemons (edgedsm.publish.command_auth)
    assert "LoadCredential=command-key:/etc/edgedsm/credentials/dashboard.command-key" in text
    assert "PrivateDevices=yes" in text and "DevicePolicy=closed" in text and "DeviceAllow" not in text
    assert "RestartPreventExitStatus=78" in text


def test_verify_and_security_exposure_at_most_2(testable_unit: Path) -> None:
    verify = subprocess.run([_analyze(), "verify", "--man=no", str(testable_unit)], capture_output=True, text=True,
                            timeout=60)
    assert verify.returncode == 0, verify.stderr
    security = subprocess.run([_analyze(), "security", "--offline=yes", "--no-pager", str(testable_unit)],
                              capture_output=True, text=True, timeout=60)
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d)", security.stdout)
    assert match is not None, security.stdout[-500:]
    assert float(match.group(1)) <= 2.0
