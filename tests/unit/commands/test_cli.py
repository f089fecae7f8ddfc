"""The command line end to end (in-process, real files)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.estimators import s2
from edgedsm.estimators.jit import configure_threading

SMALL = """
[scene]
size = 32
frames = 40
seed = 2
[activity]
tau_c = 10.0
[[activity.regions]]
shape = "rect"
x = 0
y = 0
width = 16
height = 32
tau_c = 2.0
[detector]
bits = 8
"""


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(SMALL)
    return path


def test_simulate_then_analyze(tmp_path, scene_file, capsys):
    frames = tmp_path / "frames.npy"
    assert main(["simulate", str(scene_file), "-o", str(frames), "--no-progress"]) == 0
    stack = np.load(frames)
    assert stack.shape == (40, 32, 32) and stack.dtype == np.uint8
    out = tmp_path / "s2.npy"
    assert main(["analyze", str(frames), "--estimator", "s2", "--window", "30", "--lag", "5",
                 "--start", "4", "-o", str(out), "--png"]) == 0
    result = np.load(out)
    assert np.allclose(result, s2(stack[4:34], 5))
    assert (tmp_path / "s2.png").stat().st_size > 1000
    # the active half (tau_c = 2) is clearly more active than the rest (tau_c = 10)
    assert result[:, :16].mean() > 1.15 * result[:, 16:].mean()
    assert "S2 from frames 4..33" in capsys.readouterr().out


@pytest.mark.parametrize("target", ["stack.tif", "seq/%04d.png"])
def test_simulate_image_outputs_round_trip(tmp_path, scene_file, target):
    out = tmp_path / target
    assert main(["simulate", str(scene_file), "-o", str(out), "--frames", "6", "--no-progress"]) == 0
    npy = tmp_path / "ref.npy"
    main(["simulate", str(scene_file), "-o", str(npy), "--frames", "6", "--no-progress"])
    source = out if "%" not in target else out.parent
    map_path = tmp_path / "m.npy"
    assert main(["analyze", str(source), "--lag", "2", "-o", str(map_path)]) == 0
    ref = tmp_path / "ref_map.npy"
    main(["analyze", str(npy), "--lag", "2", "-o", str(ref)])
    assert np.array_equal(np.load(map_path), np.load(ref))


def test_bad_scene_exits_78_with_key_path(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[activity]\ntau_c = 5\ncolour = 'red'\n")
    assert main(["simulate", str(bad), "-o", str(tmp_path / "x.npy")]) == 78
    assert "activity.colour: unknown key" in capsys.readouterr().err


def test_analyze_refuses_lag_that_does_not_fit(tmp_path, scene_file, capsys):
    frames = tmp_path / "frames.npy"
    main(["simulate", str(scene_file), "-o", str(frames), "--frames", "5", "--no-progress"])
    assert main(["analyze", str(frames), "--lag", "5", "-o", str(tmp_path / "m.npy")]) == 1
    assert "does not fit a window of N=5" in capsys.readouterr().err
    assert main(["analyze", str(tmp_path / "nope.npy"), "-o", str(tmp_path / "m.npy")]) == 66  # EX_NOINPUT
    assert "no such file" in capsys.readouterr().err


def test_demo_writes_maps_and_summary(tmp_path, scene_file, capsys):
    assert main(["demo", "--scene", str(scene_file), "-o", str(tmp_path / "demo"), "--lag", "5",
                 "--no-progress", "--no-daemon"]) == 0
    out = capsys.readouterr().out
    for name in ("s1", "s2", "s3"):
        assert (tmp_path / "demo" / f"{name}.npy").exists()
        assert (tmp_path / "demo" / f"{name}.png").exists()
    line = next(row for row in out.splitlines() if row.startswith("s1 "))
    region, background, beta = (float(v) for v in line.split()[1:])
    assert region > background and 0.2 < beta < 0.9


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    for command in ("demo", "simulate", "analyze"):
        assert command in text


def test_openmp_threads_sleep_between_passes(tmp_path):
    """The CLI's process starts numba's OpenMP threads with OMP_WAIT_POLICY = PASSIVE: no spin
    after a parallel pass (libgomp's default, also reported as 'PASSIVE', spins 300,000 times,
    holding a core the daemon's other threads need). libgomp reports what it started with."""
    frames = np.random.default_rng(1).integers(0, 256, (48, 512, 512), np.uint8)
    np.save(tmp_path / "frames.npy", frames)
    env = {key: value for key, value in os.environ.items() if not key.startswith(("OMP_", "GOMP_"))}
    env["OMP_DISPLAY_ENV"] = "VERBOSE"
    done = subprocess.run([sys.executable, "-m", "edgedsm", "analyze", str(tmp_path / "frames.npy"),
                           "--timeline", str(tmp_path / "out"), "--window", "30", "--lag", "2"],
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "OMP_WAIT_POLICY = 'PASSIVE'" in done.stderr
    assert "GOMP_SPINCOUNT = '0'" in done.stderr


def test_openmp_wait_policy_set_outside_is_kept(monkeypatch):
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    configure_threading()
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"
    monkeypatch.delenv("OMP_WAIT_POLICY")
    configure_threading()
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"


def test_a_command_imports_only_its_own_module() -> None:
    """`edgedsm cmd` (scripts, SCADA) does not pay for the simulator, numba, the configuration
    models and the reports: a fresh interpreter parsing its command line has imported none of them."""
    probe = ("import sys; from edgedsm import cli; args = cli.build_parser(cli.command_named(sys.argv[1:]))"
             ".parse_args(sys.argv[1:]); heavy = ('numba', 'scipy', 'edgedsm.config', 'edgedsm.sim', "
             "'edgedsm_lab.report'); print(args.handler.__module__, "
             "[m for m in heavy if m in sys.modules])")
    light = subprocess.run([sys.executable, "-c", probe, "-v", "cmd", "publish_maps", "--broker", "127.0.0.1:1"],
                           capture_output=True, text=True, timeout=60, check=True)
    assert light.stdout.split(None, 1) == ["edgedsm.commands.cmd", "[]\n"], light.stdout
    whole = subprocess.run([sys.executable, "-c", probe, "demo"], capture_output=True, text=True, timeout=60,
                           check=True)
    # the probe does see imports: the demo needs the configuration models
    assert whole.stdout.startswith("edgedsm.commands.demo [") and "'edgedsm.config'" in whole.stdout
