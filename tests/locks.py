"""The lock files in requirements/ (scripts/upgrade-locks.sh writes them, scripts/_env.sh installs
them with pip --require-hashes --no-deps): what they pin, and how the installed packages compare.
Used by the report header (tests/conftest.py) and tests/unit/test_locks.py."""
from __future__ import annotations

import os
import platform
import re
from importlib import metadata
from pathlib import Path

from packaging.version import InvalidVersion, Version

REPO = Path(__file__).resolve().parents[1]
LOCKS = REPO / "requirements"
#: The Python the locks are resolved for (scripts/upgrade-locks.sh, --python-version).
LOCKED_PYTHON = "3.11"
#: The packages whose versions change results or break things most often, named in the header.
REPORTED = ("numpy", "numba", "opencv-python-headless", "scipy", "paho-mqtt", "pydantic", "tifffile",
            "imagecodecs", "av", "protobuf")

_PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;\\]+)")


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def lock_path(lock: str) -> Path:
    return LOCKS / f"{lock}.lock"


def pins(lock: str) -> dict[str, str]:
    """Package (canonical name) -> the version requirements/<lock>.lock pins."""
    found = {}
    for line in lock_path(lock).read_text().splitlines():
        if match := _PIN.match(line):
            found[canonical(match[1])] = match[2]
    return found


def installed(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def same_version(a: str, b: str) -> bool:
    try:
        return Version(a) == Version(b)
    except InvalidVersion:
        return a == b


def differences(lock: str = "test") -> dict[str, tuple[str | None, str]]:
    """Package -> (installed version or None, locked version), for each locked package that this
    environment does not have at the locked version."""
    return {name: (have, want) for name, want in pins(lock).items()
            if (have := installed(name)) is None or not same_version(have, want)}


def report_lines(lock: str = "test") -> list[str]:
    """The report header's lines: the versions this run ran and whether they are the lock's. A
    difference is a line, not a failure (scripts/upgrade-locks.sh runs the suite on new locks, a
    developer's venv may lag); under CI tests/unit/test_locks.py fails on it."""
    try:
        locked = pins(lock)
    except OSError as error:
        return [f"versions: cannot read the lock ({error})"]
    diff = differences(lock)
    python = platform.python_version()
    parts = [f"python {python}" + ("" if python.startswith(LOCKED_PYTHON + ".")
                                   else f" (the locks are for {LOCKED_PYTHON})")]
    for name in REPORTED:
        have = installed(name)
        if have is None and name not in locked:
            continue
        label = "opencv" if name == "opencv-python-headless" else name
        parts.append(f"{label} {have or 'missing'}" + (f" (lock {locked[name]})" if name in diff else ""))
    lines = ["versions: " + ", ".join(parts)]
    where = f"requirements/{lock}.lock"
    if not diff:
        lines.append(f"versions: all {len(locked)} packages at the versions {where} pins")
    else:
        listed = ", ".join(f"{name} {have or 'missing'} (lock {want})" for name, (have, want) in sorted(diff.items()))
        lines.append(f"versions: WARNING: {len(diff)} of {len(locked)} packages are not at the versions {where} "
                     f"pins: {listed}")
        if os.environ.get("CI") == "true":
            lines.append("versions: under CI this fails tests/unit/test_locks.py")
    return lines
