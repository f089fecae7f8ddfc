"""Installable as a package: a wheel built offline from this tree carries the example configs,
scenes and the systemd unit, and an installed (non-editable) edgedsm uses them: `check-config`
on the shipped demo config, `init`, and the unit's `laser off --config`, all from a fresh venv
and away from the repository. The lab (edgedsm_lab, its own project lab/) is not in the wheel:
there `edgedsm bench` and `edgedsm reproduce` say how to install it and exit 69.

The venv is made with --system-site-packages and edgedsm installed with --no-deps; the
dependencies come from the environment running the tests (a .pth file lists its site-packages,
whose own .pth files, such as an editable edgedsm, are NOT processed from there).
"""

from __future__ import annotations

import os
import shutil
import site
import stat
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.integration, pytest.mark.timeout(600)]

REPO = Path(__file__).resolve().parents[2]
SHIPPED = ["edgedsm/data/config/daemon/demo.toml", "edgedsm/data/config/daemon/example.toml",
           "edgedsm/data/config/scenes/drying_demo.toml", "edgedsm/data/config/scenes/logos.toml",
           "edgedsm/data/systemd/edgedsm@.service", "edgedsm/data/systemd/edgedsm.sysusers"]


def run(command: list[str], cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{command} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done


def test_wheel_installs_and_runs_from_package_data(tmp_path: Path) -> None:
    # a copy of the tree, so the build leaves nothing behind in the repository
    source = tmp_path / "src"
    source.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    for name in ("edgedsm", "config", "systemd", "edgedsm_lab"):  # the lab beside it, as in the repository
        shutil.copytree(REPO / name, source / name, symlinks=True, ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
         "-w", str(tmp_path / "dist"), str(source)], cwd=tmp_path)
    (wheel,) = (tmp_path / "dist").glob("edgedsm-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert set(SHIPPED) <= names
    # every file of the package data, through the links too, and nothing else from the tree
    data = source / "edgedsm" / "data"
    packaged = {f"edgedsm/data/{Path(root, name).relative_to(data).as_posix()}"
                for root, _, files in os.walk(data, followlinks=True) for name in files}
    assert packaged <= names and len(packaged) >= len(SHIPPED)
    assert not any(name.startswith(("config/", "systemd/")) for name in names)  # only inside the package
    benches = {name for name in names if name.startswith("edgedsm_lab/") or "bench" in name.rpartition("/")[2]}
    assert benches == {"edgedsm/commands/bench.py"}, "benchmark code in the wheel"

    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(venv)], cwd=tmp_path)
    python = venv / "bin" / "python"
    run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index",
         str(wheel)], cwd=tmp_path)
    purelib = Path(run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                       cwd=tmp_path).stdout.strip())
    (purelib / "_edgedsm_test_dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")

    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    work = tmp_path / "elsewhere"  # not the repository: nothing may be read from there
    work.mkdir()
    where = run([str(python), "-c", "import edgedsm, edgedsm.commands.demo as demo; "
                 "print(edgedsm.__file__); print(demo.DEMO_CONFIG)"], cwd=work, env=env).stdout.split()
    assert all(Path(path).is_relative_to(purelib) for path in where), where
    demo_config = where[1]

    edgedsm = str(venv / "bin" / "edgedsm")
    checked = run([edgedsm, "check-config", demo_config], cwd=work, env=env)
    assert checked.stdout.startswith(f"{demo_config}: OK")
    off = run([edgedsm, "laser", "off", "--config", demo_config], cwd=work, env=env)
    assert off.stdout == "laser: off (readback confirmed)\n"

    made = run([edgedsm, "init", "line9", "--dir", str(work / "etc")], cwd=work, env=env)
    written = work / "etc" / "line9.toml"
    assert made.stdout.startswith(f"wrote {written} (mode 0640")
    assert "systemctl enable --now edgedsm@line9" in made.stdout
    unit = purelib / "edgedsm" / "data" / "systemd" / "edgedsm@.service"
    assert f"cp {unit} /etc/systemd/system/" in made.stdout
    assert stat.S_IMODE(written.stat().st_mode) == 0o640
    assert 'name = "line9"' in written.read_text()
    run([edgedsm, "check-config", str(written)], cwd=work, env=env)

    for command in (["bench", "sim", "--quick"], ["reproduce", "--quick", "-o", str(work / "repro")]):
        missing = subprocess.run([edgedsm, *command], cwd=work, env=env, capture_output=True, text=True, timeout=120)
        assert missing.returncode == 69, missing
        assert missing.stderr.count("\n") == 1 and "not installed" in missing.stderr, missing.stderr
        assert "pip install -e ./lab" in missing.stderr
    assert not (work / "repro").exists()
