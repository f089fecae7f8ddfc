"""`edgedsm laser off --config FILE`: what the unit's ExecStopPost= runs after any end of the
service. Real relay drivers against the emulated boards on socat PTY pairs (helpers_relay),
byte for byte; exit 0 off (confirmed where the board can), 69 unreachable, 78 bad config.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers_daemon import base_config
from helpers_daemon import write_config as write_daemon_config
from helpers_relay import OFF, ON, READ, KmtronicBoard, LcusBoard, ModbusBoard, NumatoBoard, PtyPair, open_pty_pair

from edgedsm.cli import main

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

QUERIES = {
    "lcus": (LcusBoard, "protocol=lcus&channel=2", {"channel": 2}),
    "numato": (NumatoBoard, "protocol=numato&channel=11", {"channel": 11}),
    "kmtronic": (KmtronicBoard, "protocol=kmtronic&channel=3&relays=4", {"channel": 3, "relays": 4}),
    "modbus": (ModbusBoard, "protocol=modbus&slave=7&channel=5", {"channel": 5, "slave": 7}),
}


@pytest.fixture
def pty_pair(tmp_path: Path) -> Iterator[PtyPair]:
    with open_pty_pair(tmp_path) as pair:
        yield pair


def write_config(directory: Path, relay_uri: str | None, extra: str = "") -> Path:
    laser = f'[laser]\nuri = "{relay_uri}"\n' if relay_uri is not None else ""
    path = directory / "line3.toml"
    path.write_text(f'[device]\nname = "line3"\n\n[camera]\nuri = "sim:default"\n{extra}\n{laser}')
    return path


def start_board(name: str, pair: PtyPair, mode: str = "normal"):
    cls, query, kwargs = QUERIES[name]
    board = cls(pair.board, **kwargs)
    board.mode = mode
    board.is_on = True  # the daemon died with the laser on
    board.start()
    return board, f"serial:{pair.app}?{query}"


@pytest.mark.parametrize("name", list(QUERIES))
def test_switches_off_the_configured_relay_byte_exact(name: str, pty_pair: PtyPair, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    board, uri = start_board(name, pty_pair)
    try:
        config = write_config(tmp_path, uri)
        assert main(["laser", "off", "--config", str(config)]) == 0
        # off() with its readback, then close() switches off once more (and reads back again)
        expected = [OFF[name], READ[name]] * 2 if name in READ else [OFF[name]] * 2
        assert board.wait_frames(len(expected)) == expected
        deadline = time.monotonic() + 2
        while board.is_on and time.monotonic() < deadline:  # LCUS never answers: let it settle
            time.sleep(0.01)
        assert board.is_on is False
    finally:
        board.stop()
    assert board.errors == []
    out = capsys.readouterr().out
    if name in READ:
        assert out.splitlines() == ["laser: off (readback confirmed)"]
    else:
        assert out.splitlines() == ["laser: off (as commanded; this board has no readback)"]


def test_readback_even_when_the_uri_says_verify_false(pty_pair: PtyPair, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    board, uri = start_board("numato", pty_pair)
    try:
        assert main(["laser", "off", "--config", str(write_config(tmp_path, uri + "&verify=false"))]) == 0
        assert board.wait_frames(3)[:2] == [OFF["numato"], READ["numato"]]
    finally:
        board.stop()
    assert capsys.readouterr().out.splitlines() == ["laser: off (readback confirmed)"]


@pytest.mark.parametrize("name", ["numato", "kmtronic", "modbus"])
def test_silent_board_exits_69_with_a_clear_message(name: str, pty_pair: PtyPair, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    board, uri = start_board(name, pty_pair, mode="silent")
    try:
        started = time.monotonic()
        assert main(["laser", "off", "--config", str(write_config(tmp_path, uri + "&timeout=0.2"))]) == 69
        took = time.monotonic() - started
        # three attempts, each: off (0.2 s timeout) and close()'s second off (0.2 s), 0.5 s apart
        assert took < 5.0
        frames = board.frames()
    finally:
        board.stop()
    assert frames[0] == OFF[name] and frames.count(OFF[name]) == 6
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("edgedsm: error: the laser may still be ON: 3 attempts to switch it off failed")
    assert "no answer within 0.2 s" in err[-1]
    assert [line for line in err if "attempt" in line and "failed:" in line][:2] == err[:2]


def test_stuck_relay_exits_69(pty_pair: PtyPair, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    board, uri = start_board("modbus", pty_pair, mode="stuck")
    try:
        assert main(["laser", "off", "--config", str(write_config(tmp_path, uri))]) == 69
    finally:
        board.stop()
    assert board.is_on is True
    assert "commanded off but the board reports on" in capsys.readouterr().err


def test_missing_port_exits_69(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path, f"serial:{tmp_path}/ttyUSB-gone?protocol=lcus")
    assert main(["laser", "off", "--config", str(config)]) == 69
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the laser may still be ON" in err and "cannot open relay port" in err


def test_config_without_laser_is_nothing_to_switch(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path, None)
    assert main(["laser", "off", "--config", str(config)]) == 0
    assert capsys.readouterr().out.strip() == f"laser: {config} has no [laser] table: no relay to switch"


def test_bad_config_exits_78(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "absent.toml"
    assert main(["laser", "off", "--config", str(missing)]) == 78
    assert f"{missing}: file not found" in capsys.readouterr().err
    broken = tmp_path / "broken.toml"
    broken.write_text("[laser\nuri = 1\n")
    assert main(["laser", "off", "--config", str(broken)]) == 78
    assert "not valid TOML" in capsys.readouterr().err
    bad_uri = write_config(tmp_path, "serial:/dev/ttyUSB0?protocol=lcus&chanel=1")
    assert main(["laser", "off", "--config", str(bad_uri)]) == 78
    assert "unknown option 'chanel'" in capsys.readouterr().err


def test_invalid_config_elsewhere_still_switches_off_then_exits_78(
        pty_pair: PtyPair, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    board, uri = start_board("kmtronic", pty_pair)
    try:
        config = write_config(tmp_path, uri, extra="[estimator]\nwindwo = 100\n")
        assert main(["laser", "off", "--config", str(config)]) == 78
        assert board.wait_frames(2)[:2] == [OFF["kmtronic"], READ["kmtronic"]]
        assert board.is_on is False
    finally:
        board.stop()
    captured = capsys.readouterr()
    assert captured.out.splitlines() == ["laser: off (readback confirmed)"]
    assert "the laser was switched off all the same" in captured.err
    assert "estimator.windwo: unknown key" in captured.err


def test_relay_uri_and_config_are_exclusive(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["laser", "off", "sim:", "--config", str(write_config(tmp_path, "sim:"))]) == 78
    assert main(["laser", "off"]) == 78
    assert "give either RELAY_URI or --config FILE" in capsys.readouterr().err


def test_as_the_unit_runs_it(pty_pair: PtyPair, tmp_path: Path) -> None:
    """A separate process, as ExecStopPost= starts it after the daemon is gone."""
    board, uri = start_board("numato", pty_pair)
    try:
        config = write_config(tmp_path, uri)
        env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
        done = subprocess.run([sys.executable, "-m", "edgedsm", "laser", "off", "--config", str(config)],
                              capture_output=True, text=True, timeout=30, env=env)
        assert (done.returncode, done.stdout, done.stderr) == (0, "laser: off (readback confirmed)\n", "")
        assert board.is_on is False
    finally:
        board.stop()


# -- a stopped process holding the port's lock (issue 34) -------------------------------------

#: Holds the relay as the daemon does (open_relay: the port's exclusive lock), switches it on,
#: says so and waits: SIGSTOPped by the test, it is a hung daemon with the laser on.
HOLDER = """
import sys, time
from edgedsm.devices.laser import open_relay
relay = open_relay(sys.argv[1])
relay.on()
print("on", flush=True)
time.sleep(600)
"""
#: `laser off --config` against a stopped holder: a process start (about 1 s of imports) and
#: one exchange; well within the "few seconds" a technician waits, far from the 60 s watchdog.
OVERRIDE_WITHIN_S = 5.0


def _child_env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}


def _stopped(pid: int) -> bool:
    """The process is stopped (state T in /proc/PID/stat)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    return stat.rpartition(")")[2].split()[0] in ("T", "t")


@contextlib.contextmanager
def _stopped_holder(uri: str) -> Iterator[subprocess.Popen[str]]:
    """A process holding ``uri``'s port locked with the relay on, SIGSTOPped; continued and
    killed on the way out."""
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, uri], stdout=subprocess.PIPE, text=True,
                              env=_child_env(), stdin=subprocess.DEVNULL)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "on\n"
        holder.send_signal(signal.SIGSTOP)
        deadline = time.monotonic() + 5
        while not _stopped(holder.pid):
            assert time.monotonic() < deadline, "the holder did not stop"
            time.sleep(0.01)
        yield holder
    finally:
        holder.send_signal(signal.SIGCONT)
        holder.kill()
        holder.wait(10)
        if holder.stdout is not None:
            holder.stdout.close()


def _laser(action: str, config: Path) -> tuple[subprocess.CompletedProcess[str], float]:
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "edgedsm", "laser", action, "--config", str(config)],
                          capture_output=True, text=True, timeout=30, env=_child_env(), stdin=subprocess.DEVNULL)
    return done, time.monotonic() - started


@pytest.mark.parametrize("name", ["numato", "modbus"])
def test_off_overrides_the_lock_of_a_stopped_holder(name: str, pty_pair: PtyPair, tmp_path: Path) -> None:
    cls, query, kwargs = QUERIES[name]
    board = cls(pty_pair.board, **kwargs)
    board.start()
    uri = f"serial:{pty_pair.app}?{query}"
    try:
        with _stopped_holder(uri) as holder:
            assert board.is_on is True and board.frames() == [ON[name], READ[name]]
            done, took = _laser("off", write_config(tmp_path, uri))
            print(f"laser off under a lock held by a stopped process: {took:.2f} s")
            assert done.returncode == 0, done.stderr
            assert took < OVERRIDE_WITHIN_S
            assert board.is_on is False
            # off with its readback, then close()'s off with its readback: nothing else
            assert board.frames() == [ON[name], READ[name]] + [OFF[name], READ[name]] * 2
            assert done.stdout == "laser: off (readback confirmed)\n"
            assert done.stderr == (f"edgedsm: warning: relay port {pty_pair.app} is locked by process "
                                   f"{holder.pid}: overriding the lock to switch the laser off (off only)\n")
    finally:
        board.stop()
    assert board.errors == []


@pytest.mark.parametrize("action", ["on", "status"])
def test_on_and_status_still_refuse_a_locked_port(action: str, pty_pair: PtyPair, tmp_path: Path) -> None:
    board, uri = start_board("numato", pty_pair)
    board.is_on = False
    try:
        with _stopped_holder(uri) as holder:
            before = board.frames()
            done, _ = _laser(action, write_config(tmp_path, uri))
            assert done.returncode == 69
            assert f"locked by process {holder.pid}" in done.stderr and "overriding" not in done.stderr
            time.sleep(0.3)  # anything sent would have arrived by now
            assert board.frames() == before  # not a byte
            assert board.is_on is True  # as the holder left it
    finally:
        board.stop()


@pytest.mark.timeout(90)
def test_off_overrides_a_stopped_daemon(pty_pair: PtyPair, tmp_path: Path, daemons) -> None:
    """The issue's case: the real daemon measuring with the laser on, SIGSTOPped (hung) while it
    holds the relay's port."""
    board = ModbusBoard(pty_pair.board, channel=5, slave=7)
    board.start()
    uri = f"serial:{pty_pair.app}?protocol=modbus&slave=7&channel=5"
    try:
        config = write_daemon_config(tmp_path / "daemon.toml", base_config(tmp_path, laser=uri))
        daemon = daemons(config)
        daemon.wait_log(r"laser on \(measuring\)", 60)
        assert board.is_on is True
        daemon.signal(signal.SIGSTOP)
        daemon.wait_until(lambda: _stopped(daemon.process.pid), 5, "the daemon stopped")
        sent = len(board.frames())
        done, took = _laser("off", config)
        print(f"laser off under a stopped daemon's lock: {took:.2f} s")
        assert done.returncode == 0, done.stderr
        assert took < OVERRIDE_WITHIN_S
        assert f"locked by process {daemon.process.pid}: overriding the lock" in done.stderr
        assert board.is_on is False
        assert board.frames()[sent:] == [OFF["modbus"], READ["modbus"]] * 2
        # continued, it finds the relay off under it (its readback, at the latest after its 5 s
        # check interval): a fault, the laser state unknown until its own off is confirmed; then it
        # measures again, laser on, as its plan wants. The override is for a hung daemon, not a way
        # to overrule a running one (docs/laser-safety.md).
        resumed = time.monotonic()
        daemon.signal(signal.SIGCONT)
        daemon.wait_log(r"laser relay (reports off|did not report its state|failed while switching)", 15)
        daemon.wait_log(r"laser confirmed off after the relay error", 15)
        daemon.wait_until(lambda: board.is_on, 15, "the continued daemon's laser on again")
        print(f"the continued daemon: fault, off confirmed, on again in {time.monotonic() - resumed:.1f} s")
        code, _ = daemon.terminate()
        assert board.is_on is False
        print(f"daemon exit after SIGCONT and SIGTERM: {code}")
        assert code == 0, daemon.log  # its own off at stop confirmed
    finally:
        board.stop()
    assert board.errors == []
