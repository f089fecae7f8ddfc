"""The lock files agree with pyproject.toml and with themselves, so that the README's commands install
what pyproject asks for at the versions the suite ran (requirements/*.lock; docs/install.md,
"Versions and locks"). Whoever adds or changes a dependency is told here to re-lock."""
from __future__ import annotations

import os
import re
import tomllib
from importlib import metadata

import pytest
from packaging.requirements import Requirement

from tests.locks import REPO, canonical, differences, installed, lock_path, pins, same_version

RELOCK = ("re-lock: scripts/upgrade-locks.sh --keep (keeps the other pins; or without --keep, the newest "
          "versions), then commit requirements/ with the change")

PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
#: Each lock and the extras it installs (scripts/demo.sh: demo with [fast]; scripts/test.sh: test with [test]).
LOCK_EXTRAS = {"demo": "fast", "test": "test"}


def unmet(requirements: list[str], lock: str, extra: str = "") -> list[str]:
    """The requirements that requirements/<lock>.lock does not pin a version of that satisfies them."""
    locked = pins(lock)
    problems = []
    for text in requirements:
        requirement = Requirement(text)
        if requirement.marker is not None and not requirement.marker.evaluate({"extra": extra}):
            continue
        version = locked.get(canonical(requirement.name))
        if version is None:
            problems.append(f"{text!r} is not in requirements/{lock}.lock")
        elif not requirement.specifier.contains(version, prereleases=True):
            problems.append(f"{text!r}: requirements/{lock}.lock pins {version}")
    return problems


@pytest.mark.parametrize("lock", sorted(LOCK_EXTRAS))
def test_each_lock_pins_a_version_of_everything_pyproject_asks_for(lock: str) -> None:
    extra = LOCK_EXTRAS[lock]
    asked = PYPROJECT["project"]["dependencies"] + PYPROJECT["project"]["optional-dependencies"][extra]
    problems = unmet(asked, lock, extra)
    assert not problems, f"pyproject.toml and requirements/{lock}.lock disagree: {problems}; {RELOCK}"


def test_the_test_lock_pins_what_the_lab_needs() -> None:
    """scripts/_env.sh installs the lab (lab/pyproject.toml) into the test venv with --no-deps: each of
    its dependencies but edgedsm itself (installed beside it, editable) comes from test.lock."""
    lab = tomllib.loads((REPO / "lab" / "pyproject.toml").read_text())
    asked = [text for text in lab["project"]["dependencies"] if Requirement(text).name != "edgedsm"]
    assert asked, "the lab's own dependencies (matplotlib for the figures)"
    problems = unmet(asked, "test")
    assert not problems, f"lab/pyproject.toml and requirements/test.lock disagree: {problems}; {RELOCK}"


def test_the_build_lock_pins_what_the_builds_need() -> None:
    build_in = [line.split("#")[0].strip() for line in (REPO / "requirements/build.in").read_text().splitlines()]
    asked = PYPROJECT["build-system"]["requires"] + [line for line in build_in if line]
    problems = unmet(asked, "build")
    assert not problems, f"requirements/build.lock misses a build dependency: {problems}; {RELOCK}"


@pytest.mark.parametrize("lock", ["demo", "build"])
def test_the_other_locks_take_the_test_locks_versions(lock: str) -> None:
    test = pins("test")
    different = {name: (version, test[name]) for name, version in pins(lock).items()
                 if name in test and not same_version(version, test[name])}
    assert not different, f"requirements/{lock}.lock and test.lock pin different versions: {different}; {RELOCK}"


@pytest.mark.parametrize("lock", ["pip", "build", "demo", "test", "tools"])
def test_every_pin_is_exact_and_hashed(lock: str) -> None:
    lines = lock_path(lock).read_text().splitlines()
    assert lines[0].startswith(f"# requirements/{lock}.lock: "), "the header says what the file is"
    assert any("scripts/upgrade-locks.sh" in line for line in lines[:4]), "and how to remake it"
    entries = [line for line in lines if line and not line[0].isspace() and not line.startswith("#")]
    assert entries, "pins something"
    for number, line in enumerate(lines):
        if line in entries:
            assert re.fullmatch(r"[a-z0-9][a-z0-9._-]*==[^\s;]+ \\", line), f"not an exact pin: {line!r}"
            assert lines[number + 1].lstrip().startswith("--hash=sha256:"), f"no hash: {line!r}"


def test_each_lock_holds_what_its_packages_depend_on() -> None:
    """scripts/_env.sh installs with --no-deps: a package's dependency missing from its lock would be
    missing from the venv. Checked with the installed packages' metadata, where installed at the
    locked version."""
    problems = []
    for lock in LOCK_EXTRAS:
        locked = pins(lock)
        for name, version in locked.items():
            have = installed(name)
            if have is None or not same_version(have, version):
                continue
            for text in metadata.requires(name) or []:
                requirement = Requirement(text)
                if requirement.marker is not None and not requirement.marker.evaluate({"extra": ""}):
                    continue
                pinned = locked.get(canonical(requirement.name))
                if pinned is None or not requirement.specifier.contains(pinned, prereleases=True):
                    problems.append(f"{lock}.lock: {name} {version} needs {text!r}, the lock pins {pinned}")
    assert not problems, f"{problems}; {RELOCK}"


@pytest.mark.skipif(os.environ.get("CI") != "true", reason="outside CI a difference is the header's warning line")
def test_ci_runs_the_versions_the_test_lock_pins() -> None:
    """CI installs a fresh venv from the lock (.ci/run -> scripts/test.sh -> ensure_venv), so any
    difference means that install path is broken and the run would not vouch for the locked versions."""
    assert not differences("test"), f"installed vs requirements/test.lock (installed, locked): {differences('test')}"
