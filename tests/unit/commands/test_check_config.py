"""`check-config` refuses what `run` refuses at its start, by the same rules
(edgedsm.daemon.preflight): each case through both commands, the same exit code (78) and a
message naming the key. `check-config` runs in process; `run` as the real process systemd starts
(it must refuse before any sink, camera or relay is opened: within seconds, nothing measured).
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from edgedsm.cli import main

pytestmark = pytest.mark.timeout(120)

#: `run` refuses before anything starts: well within this (it imports, reads, checks).
RUN_REFUSES_WITHIN_S = 60


def _config(directory: Path, extra: str, *, camera: str = 'uri = "sim:default"', estimator: str = "",
            state_dir: Path | str | None = None) -> Path:
    state = directory / "state" if state_dir is None else state_dir
    path = directory / "line3.toml"
    path.write_text(f'[device]\nname = "line3"\nstate_dir = "{state}"\n\n[camera]\n{camera}\n\n'
                    f'[laser]\nuri = "sim:line3"\n\n[estimator]\n{estimator}\n\n{extra}\n')
    return path


def _broker(extra: str = "") -> str:
    # port 1: nothing listens; a refusal must come before any connection is tried
    return f'[mqtt]\nhost = "127.0.0.1"\nport = 1\n{extra}\n'


def _big_scene(directory: Path) -> str:
    scene = directory / "big.toml"
    scene.write_text("[scene]\nsize = 4096\nframes = 100\ndt = 0.05\n\n[activity]\ntau_c = 3.0\n\n"
                     "[detector]\nn_max = 1000\nbits = 8\n")
    return f'uri = "sim:{scene}"'


def _environment() -> dict[str, str]:
    env = {key: value for key, value in os.environ.items()
           if key not in ("EDGEDSM_COMMAND_KEY", "CREDENTIALS_DIRECTORY", "EDGEDSM_MQTT_PASSWORD")}
    env["PYTHONUNBUFFERED"] = "1"
    return env


def both(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[tuple[int, str], tuple[int, str]]:
    """(exit code, stderr) of `check-config PATH` (in process) and of `run -c PATH` (a process)."""
    checked = main(["check-config", str(path)])
    check_err = capsys.readouterr().err
    done = subprocess.run([sys.executable, "-m", "edgedsm", "run", "-c", str(path)], capture_output=True,
                          text=True, timeout=RUN_REFUSES_WITHIN_S, env=_environment(), stdin=subprocess.DEVNULL)
    return (checked, check_err), (done.returncode, done.stderr)


def refused_alike(path: Path, key: str, capsys: pytest.CaptureFixture[str]) -> str:
    """Both commands exit 78 with one line naming ``key`` (the same line); returns it."""
    (checked, check_err), (ran, run_err) = both(path, capsys)
    assert (checked, ran) == (78, 78), (check_err, run_err[-2000:])
    lines = [line for line in check_err.splitlines() if f": {key}: " in line]
    assert lines, check_err
    said = lines[0].partition("; this machine has")[0]  # the memory available moves between the two
    assert said in run_err  # the same rule said it, word for word
    assert "Traceback" not in run_err and "switched on" not in run_err
    return lines[0]


def test_an_engine_larger_than_the_machine(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    # 4096x4096 frames, N = 100000: the ring alone is 1.6 TB, beyond any machine this runs on
    path = _config(tmp_path, "", camera=_big_scene(tmp_path), estimator="window = 100000\nlag = 5")
    (checked, check_err), (ran, run_err) = both(path, capsys)
    assert (checked, ran) == (78, 78), run_err[-2000:]
    for err in (check_err, run_err):
        found = re.search(r"estimator\.window: the estimator for 4096x4096 frames needs ([\d.]+) GiB", err)
        assert found is not None, err[-2000:]
        # a byte per pixel and frame (100000), the sums, their copy and the maps: 1564-1600 GiB
        assert 1564 <= float(found.group(1)) <= 1600
    assert "simulated camera 4096x4096: open" not in run_err  # refused before the camera


def test_a_camera_queue_larger_than_the_machine(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 10000 frames of 16 MiB = 156 GiB: the queue, not the estimator (about 2 GiB), is named
    path = _config(tmp_path, "[acquisition]\nqueue_frames = 10000\n", camera=_big_scene(tmp_path),
                   estimator="window = 20\nlag = 5")
    line = refused_alike(path, "acquisition.queue_frames", capsys)
    assert re.search(r"\(estimator [12]\.\d GiB, acquisition\.queue_frames 156\.\d GiB\)", line), line
    assert line.endswith("(lower acquisition.queue_frames)")


@pytest.mark.parametrize(("state_dir", "said"), [
    ("/proc", "on a proc file system"),
    ("/proc/edgedsm/line3", "on a proc file system"),
    ("/dev/null", "on a devtmpfs file system"),
    ("/sys/kernel", "on a sysfs file system"),
])
def test_a_state_dir_that_keeps_nothing(state_dir: str, said: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    line = refused_alike(_config(tmp_path, _broker(), state_dir=state_dir), "device.state_dir", capsys)
    assert said in line


def test_a_state_dir_below_a_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    line = refused_alike(_config(tmp_path, _broker(), state_dir=blocker / "state"), "device.state_dir", capsys)
    assert f"{blocker} is not a directory" in line


def test_a_recording_dir_that_keeps_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = refused_alike(_config(tmp_path, '[recording]\ndir = "/proc/recordings"\n'), "recording.dir", capsys)
    assert "on a proc file system" in line


@pytest.mark.parametrize(("listen", "said"), [
    ("no-such-host.invalid:9108", "'no-such-host.invalid' does not resolve"),
    ("192.0.2.1:9108", "cannot listen there (192.0.2.1: Cannot assign requested address)"),  # TEST-NET-1
])
def test_a_listen_address_that_cannot_be_listened_on(listen: str, said: str, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    line = refused_alike(_config(tmp_path, f'[http]\nlisten = "{listen}"\n'), "http.listen", capsys)
    assert said in line


@pytest.mark.parametrize(("extra", "key"), [
    (_broker('topic_prefix = "$SYS"'), "mqtt.topic_prefix"),
    (_broker() + '\n[homeassistant]\ndiscovery_prefix = "$SYS/ha"\n', "homeassistant.discovery_prefix"),
])
def test_a_topic_prefix_of_the_broker(extra: str, key: str, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert "must not start with '$'" in refused_alike(_config(tmp_path, extra), key, capsys)


def test_a_ca_file_that_is_not_pem(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ca = tmp_path / "ca.pem"
    ca.write_text("not a certificate\n")
    path = _config(tmp_path, _broker() + f'\n[mqtt.tls]\nca_file = "{ca}"\n')
    assert "not a usable PEM CA file" in refused_alike(path, "mqtt.tls.ca_file", capsys)


def test_a_command_key_file_with_no_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    keys = tmp_path / "command-key"
    keys.write_text("")
    path = _config(tmp_path, _broker(f'command_key_file = "{keys}"'))
    assert "holds no key" in refused_alike(path, "mqtt.command_key_file", capsys)


@pytest.mark.parametrize(("camera", "key", "said"), [
    # once a device fault at the start (exit 69, restarted every 10 s), now a configuration error
    ('uri = "sim:default"\npixel_format = "Mono99"', "camera.pixel_format", "'Mono99' is not a pixel format"),
    ('uri = "sim:default"\npixel_format = "Mono16"', "camera.pixel_format",
     "Mono16: the scene's 8-bit detector delivers Mono8"),
])
def test_a_pixel_format_the_camera_cannot_deliver(camera: str, key: str, said: str, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    assert said in refused_alike(_config(tmp_path, "", camera=camera), key, capsys)


def test_a_relay_url_pyserial_does_not_know(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _config(tmp_path, "")
    path.write_text(path.read_text().replace('uri = "sim:line3"', 'uri = "serial:xyz://relay?protocol=modbus"'))
    assert "invalid URL, protocol 'xyz' not known" in refused_alike(path, "laser.uri", capsys)


def test_every_problem_is_said_at_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _config(tmp_path, _broker() + '\n[http]\nlisten = "no-such-host.invalid:9108"\n', state_dir="/proc")
    assert main(["check-config", str(path)]) == 78
    err = capsys.readouterr().err
    assert f"{path}: device.state_dir: /proc:" in err and f"{path}: http.listen:" in err


def test_a_good_config_passes_and_a_taken_port_is_left_to_the_start(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    # the port a running daemon holds while check-config runs: not refused here, only by the start
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        path = _config(tmp_path, _broker() + f'\n[http]\nlisten = "127.0.0.1:{port}"\n'
                                             '\n[recording]\nmode = "alerts"\n')
        assert main(["check-config", str(path)]) == 0
        assert not (tmp_path / "state").exists()  # checked, not created
        done = subprocess.run([sys.executable, "-m", "edgedsm", "run", "-c", str(path)], capture_output=True,
                              text=True, timeout=RUN_REFUSES_WITHIN_S, env=_environment())
    assert done.returncode == 78
    assert f"http.listen: cannot listen on 127.0.0.1:{port}" in done.stderr
