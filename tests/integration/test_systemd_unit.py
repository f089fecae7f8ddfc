"""The service unit: laser off after any death (ExecStopPost=), exit codes systemd acts on, and
hardening checked by systemd's own tools (`systemd-analyze verify` and `security --offline`),
which run without a running systemd.

systemd-analyze is required: without it these tests FAIL (scripts/test.sh installs `systemd`).
"""

from __future__ import annotations

import grp
import re
import shutil
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "edgedsm@.service"
INSTALLED_EDGEDSM = "/opt/edgedsm/.venv/bin/edgedsm"
MAX_EXPOSURE = 2.0


def systemd_analyze() -> str:
    path = shutil.which("systemd-analyze")
    if path is None:
        pytest.fail("systemd-analyze is not installed, so the unit cannot be checked: install it "
                    "with 'apt-get install -y systemd' (scripts/test.sh does)")
    return path


def settings(text: str, wanted: str = "[Service]") -> dict[str, list[str]]:
    """Every KEY=value of one section (``[Service]``), repeated keys kept in order."""
    found: dict[str, list[str]] = {}
    section = ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            section = line
            continue
        if section == wanted:
            key, _, value = line.partition("=")
            found.setdefault(key, []).append(value)
    return found


@pytest.fixture
def testable_unit(tmp_path: Path) -> Path:
    """The unit as an instance file, with the install prefix pointing at a stub executable:
    `verify` checks that every command exists, and /opt/edgedsm is not installed here."""
    stub = tmp_path / "bin" / "edgedsm"
    stub.parent.mkdir()
    stub.write_text("#!/bin/sh\nexit 0\n")
    stub.chmod(0o755)
    unit = tmp_path / "edgedsm@line3.service"
    text = UNIT.read_text()
    assert text.count(INSTALLED_EDGEDSM) == 2  # ExecStart and ExecStopPost, nothing else changes
    unit.write_text(text.replace(INSTALLED_EDGEDSM, str(stub)))
    return unit


def test_laser_off_after_any_death_and_exit_codes() -> None:
    service = settings(UNIT.read_text())
    assert service["ExecStopPost"] == [f"{INSTALLED_EDGEDSM} laser off --config /etc/edgedsm/%i.toml"]
    assert service["ExecStart"] == [f"{INSTALLED_EDGEDSM} run -c /etc/edgedsm/%i.toml"]
    # RestartPreventExitStatus= does not cover ExecStartPre= (systemd#11868): none may exist
    assert "ExecStartPre" not in service
    assert service["Restart"] == ["on-failure"]
    assert service["RestartPreventExitStatus"] == ["78 65"]
    assert int(service["RestartSec"][0]) >= 5  # 69 (device unavailable) restarts with a delay
    assert service["KillMode"] == ["mixed"]


def test_a_crash_loop_is_bounded_by_a_start_limit() -> None:
    # a file that kills the process by a signal is not stopped by RestartPreventExitStatus=
    # (exit statuses only): the start limit ends the loop (5 starts in 10 minutes)
    unit, service = settings(UNIT.read_text(), "[Unit]"), settings(UNIT.read_text())
    assert unit["StartLimitIntervalSec"] == ["600"] and unit["StartLimitBurst"] == ["5"]
    # in [Unit] only: the old [Service] spelling would be a second, conflicting place
    assert not any(key.startswith("StartLimit") for key in service)
    assert not any(name.startswith("SIG") for name in service["RestartPreventExitStatus"][0].split())
    # the restarts a crash gets within the interval fit in it: the limit is reached, not outrun
    restarts = int(unit["StartLimitBurst"][0]) - 1
    assert restarts * int(service["RestartSec"][0]) < int(unit["StartLimitIntervalSec"][0])


def test_devices_and_networks_the_drivers_need_stay_allowed() -> None:
    service = settings(UNIT.read_text())
    assert service["DevicePolicy"] == ["closed"]
    allowed = {value.split()[0] for value in service["DeviceAllow"]}
    assert {"char-ttyUSB", "char-ttyACM", "char-video4linux", "char-usb_device"} <= allowed
    families = service["RestrictAddressFamilies"][0].split()
    assert {"AF_UNIX", "AF_INET", "AF_INET6", "AF_NETLINK"} <= set(families)
    assert set(service["SupplementaryGroups"][0].split()) == {"dialout", "video", "edgedsm"}
    assert service["CapabilityBoundingSet"] == [""]
    assert service["SystemCallFilter"][0] == "@system-service"
    assert service["UMask"] == ["0077"]


def test_systemd_analyze_verify_accepts_the_unit(testable_unit: Path) -> None:
    done = subprocess.run([systemd_analyze(), "verify", "--man=no", str(testable_unit)],
                          capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stderr.strip()) == (0, "")


def test_security_exposure_is_at_most_2(testable_unit: Path) -> None:
    done = subprocess.run([systemd_analyze(), "security", "--offline=yes", "--no-pager", str(testable_unit)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d)", done.stdout)
    assert match is not None, done.stdout[-500:]
    exposure = float(match.group(1))
    print(f"systemd-analyze security exposure: {exposure}")
    assert exposure <= MAX_EXPOSURE
    # the same bound through systemd's own threshold (0..100, exit status 1 above it)
    limited = subprocess.run([systemd_analyze(), "security", "--offline=yes", "--threshold=20",
                              str(testable_unit)], capture_output=True, text=True, timeout=60)
    assert limited.returncode == 0


def test_sysusers_file_creates_the_config_group() -> None:
    sysusers = shutil.which("systemd-sysusers")
    if sysusers is None:
        pytest.fail("systemd-sysusers is not installed: install it with 'apt-get install -y systemd'")
    done = subprocess.run([sysusers, "--dry-run", str(UNIT.parent / "edgedsm.sysusers")],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    # 'Creating group' on a fresh machine; nothing to do where the group exists already
    assert "Creating group 'edgedsm'" in done.stdout + done.stderr or _group_exists("edgedsm")


def _group_exists(name: str) -> bool:
    try:
        grp.getgrnam(name)
    except KeyError:
        return False
    return True
