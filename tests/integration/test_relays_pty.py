"""Relay drivers against emulated boards on the far end of a real socat PTY pair.

Each emulated board runs in a thread on one end of the pair, checks every byte it receives
against the real board's protocol, records the frames, and answers (echo, readback, status)
the way the real board does. The driver opens the other end through open_relay(), as the
daemon and the `edgedsm laser` tool do. The same contract tests run against the simulated
relay and every emulated board.

socat is required: without it these tests FAIL (the README's test command installs it).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from helpers_relay import (
    OFF,
    ON,
    READ,
    START_TIMEOUT_S,
    EmulatedBoard,
    KmtronicBoard,
    LcusBoard,
    ModbusBoard,
    NumatoBoard,
    PtyPair,
    open_pty_pair,
    socat,
    stop_process,
    wait_for,
)

from edgedsm.cli import main
from edgedsm.devices.laser import (
    forget_simulated_boards,
    open_relay,
    simulated_board,
)
from edgedsm.errors import DeviceError, DeviceLost, DeviceTimeout
from edgedsm.testing import RELAY_CHECKS, RelayRig
from tests.ports import free_port

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

SHORT_TIMEOUT_S = 0.2   # driver timeout for tests that expect silence
BOUND_S = 2.0           # generous upper bound on how long a timeout may take in total


# -- socat PTY pairs and emulated boards (helpers_relay) ----------------------------------

@pytest.fixture
def pty_pair(tmp_path: Path) -> Iterator[PtyPair]:
    """A fresh socat PTY pair: ``app`` for the driver, ``board`` for the emulator."""
    with open_pty_pair(tmp_path) as pair:
        yield pair


# Channels off the defaults, so that a driver ignoring channel= is caught.
BOARDS: dict[str, tuple[type[EmulatedBoard], str, dict[str, int]]] = {
    "lcus": (LcusBoard, "protocol=lcus&channel=2", {"channel": 2}),
    "numato": (NumatoBoard, "protocol=numato&channel=11", {"channel": 11}),
    "kmtronic": (KmtronicBoard, "protocol=kmtronic&channel=3&relays=4",
                 {"channel": 3, "relays": 4}),
    "modbus": (ModbusBoard, "protocol=modbus&slave=7&channel=5", {"channel": 5, "slave": 7}),
}

READBACK = ("numato", "kmtronic", "modbus")


@dataclass
class Rig:
    """A relay URI and a way to look at the physical contact behind it."""

    name: str
    uri: str
    board: EmulatedBoard | None = None
    sim_name: str = ""

    def settled(self, on: bool, timeout: float = 2.0) -> bool:
        """Whether the contact reaches ``on`` within ``timeout`` (boards that never answer
        switch after the driver has returned)."""
        deadline = time.monotonic() + timeout
        while self.is_on != on and time.monotonic() < deadline:
            time.sleep(0.005)
        return self.is_on == on

    def uri_with(self, extra: str) -> str:
        return f"{self.uri}{'&' if '?' in self.uri else '?'}{extra}"

    @property
    def is_on(self) -> bool:
        if self.board is not None:
            return self.board.is_on
        return simulated_board(self.sim_name).is_on

    def force(self, on: bool) -> None:
        """Set the contact behind the driver's back (someone else left the laser on)."""
        if self.board is not None:
            self.board.is_on = on
        else:
            simulated_board(self.sim_name).apply(on)

    @property
    def readback(self) -> bool:
        return self.board.readback if self.board is not None else True


@contextlib.contextmanager
def emulated(name: str, pair: PtyPair, **overrides: int) -> Iterator[Rig]:
    cls, query, kwargs = BOARDS[name]
    board = cls(pair.board, **{**kwargs, **overrides})
    board.start()
    try:
        yield Rig(name, f"serial:{pair.app}?{query}", board=board)
    finally:
        board.stop()
    assert board.errors == [], f"the emulated {name} board saw protocol errors"


@pytest.fixture(params=list(BOARDS))
def board_rig(request: pytest.FixtureRequest, pty_pair: PtyPair) -> Iterator[Rig]:
    """Each emulated board behind a PTY."""
    with emulated(request.param, pty_pair) as rig:
        yield rig


@pytest.fixture(params=[name for name in BOARDS if name in READBACK])
def readback_rig(request: pytest.FixtureRequest, pty_pair: PtyPair) -> Iterator[Rig]:
    """Each emulated board that can report its relay's state."""
    with emulated(request.param, pty_pair) as rig:
        yield rig


@pytest.fixture(params=["sim", *BOARDS])
def any_rig(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Rig]:
    """The simulated relay and every emulated board: for the shared contract tests."""
    if request.param == "sim":
        forget_simulated_boards()
        name = f"contract-{uuid.uuid4().hex[:8]}"
        yield Rig("sim", f"sim:{name}", sim_name=name)
        forget_simulated_boards()
        return
    pair = request.getfixturevalue("pty_pair")
    with emulated(request.param, pair) as rig:
        yield rig


# -- exact bytes ---------------------------------------------------------------------------

def test_switching_sends_exact_bytes(board_rig: Rig) -> None:
    name, board = board_rig.name, board_rig.board
    assert board is not None
    relay = open_relay(board_rig.uri)
    status = relay.on()
    assert board_rig.settled(True)
    assert (status.on, status.confirmed) == (True, name in READBACK)
    status = relay.off()
    assert board_rig.settled(False)
    assert (status.on, status.confirmed) == (False, name in READBACK)
    relay.close()
    if name in READBACK:
        expected = [ON[name], READ[name], OFF[name], READ[name], OFF[name], READ[name]]
    else:
        expected = [ON[name], OFF[name], OFF[name]]
    assert board.wait_frames(len(expected)) == expected
    time.sleep(0.05)
    assert board.frames() == expected  # and nothing more


def test_status_reads_the_board(readback_rig: Rig) -> None:
    relay = open_relay(readback_rig.uri)
    try:
        assert relay.state().on is False
        readback_rig.force(True)  # switched behind the driver's back
        status = relay.state()
        assert (status.on, status.confirmed) == (True, True)
        assert status.describe() == "on (readback confirmed)"
    finally:
        relay.detach()
    assert readback_rig.settled(True)  # detach() changed nothing
    name = readback_rig.name
    assert readback_rig.board is not None
    assert readback_rig.board.frames() == [READ[name], READ[name]]


def test_lcus_state_is_what_was_commanded(pty_pair: PtyPair) -> None:
    with emulated("lcus", pty_pair) as rig:
        relay = open_relay(rig.uri)
        assert relay.state().on is None
        relay.on()
        assert (relay.state().on, relay.state().confirmed) == (True, False)
        relay.close()
        assert rig.board is not None and rig.board.wait_frames(2)


# -- faulty boards -------------------------------------------------------------------------

def test_silent_board_times_out_in_bounded_time(readback_rig: Rig) -> None:
    assert readback_rig.board is not None
    readback_rig.board.mode = "silent"
    relay = open_relay(readback_rig.uri_with(f"timeout={SHORT_TIMEOUT_S}"))
    for operation in (relay.on, relay.state, relay.close):
        started = time.monotonic()
        with pytest.raises(DeviceTimeout, match=r"no answer within 0\.2 s"):
            operation()
        assert SHORT_TIMEOUT_S * 0.9 <= time.monotonic() - started < BOUND_S
    assert relay.closed


def test_silent_lcus_board_goes_unnoticed(pty_pair: PtyPair) -> None:
    # The LCUS protocol has no answer at all, so a dead board cannot be detected: the
    # status says so ("as commanded"), and the technician checks the laser by eye.
    with emulated("lcus", pty_pair) as rig:
        assert rig.board is not None
        rig.board.mode = "silent"
        with open_relay(rig.uri) as relay:
            assert relay.on().confirmed is False
        assert rig.settled(False)


def test_garbage_answer_is_device_error(readback_rig: Rig) -> None:
    assert readback_rig.board is not None
    readback_rig.board.mode = "garbage"
    relay = open_relay(readback_rig.uri_with(f"timeout={SHORT_TIMEOUT_S}"))
    started = time.monotonic()
    with pytest.raises(DeviceError) as info:
        relay.on()
    assert time.monotonic() - started < BOUND_S
    assert not isinstance(info.value, DeviceLost)
    relay.detach()


def test_stuck_relay_fails_the_readback_check(readback_rig: Rig) -> None:
    assert readback_rig.board is not None
    readback_rig.board.mode = "stuck"
    relay = open_relay(readback_rig.uri)
    with pytest.raises(DeviceError, match="commanded on but the board reports off"):
        relay.on()
    relay.close()  # off is what the stuck contact shows, so closing succeeds


def test_verify_false_skips_readback(pty_pair: PtyPair) -> None:
    with emulated("modbus", pty_pair) as rig:
        with open_relay(rig.uri_with("verify=false")) as relay:
            status = relay.on()
            assert (status.on, status.confirmed) == (True, False)
        assert rig.board is not None
        assert rig.board.frames() == [ON["modbus"], OFF["modbus"]]


def test_modbus_exception_answer(pty_pair: PtyPair) -> None:
    with emulated("modbus", pty_pair, channel=40) as rig:  # the slave has coils 0..15 only
        relay = open_relay(rig.uri.replace("channel=5", "channel=40"))
        with pytest.raises(DeviceError, match=r"exception 02 \(illegal data address"):
            relay.on()
        relay.detach()


def test_kmtronic_relay_count_mismatch_is_explained(pty_pair: PtyPair) -> None:
    with emulated("kmtronic", pty_pair) as rig:  # a 4-relay board, told relays=8
        relay = open_relay(rig.uri.replace("relays=4", "relays=8") + f"&timeout={SHORT_TIMEOUT_S}")
        with pytest.raises(DeviceError, match=r"incomplete answer.*set relays= to match"):
            relay.on()
        relay.detach()


def test_unplugged_board_is_device_lost(pty_pair: PtyPair) -> None:
    with emulated("numato", pty_pair) as rig:
        relay = open_relay(rig.uri)
        relay.on()
        stop_process(pty_pair.process)  # the USB cable is pulled
        started = time.monotonic()
        with pytest.raises(DeviceLost):
            relay.off()
        assert time.monotonic() - started < BOUND_S
        relay.detach()
        assert rig.board is not None
        rig.board.join(BOUND_S)  # its port died too, as it should: let it notice, then
        rig.board.errors.clear()  # drop that expected report


def test_port_is_locked_against_a_second_user(pty_pair: PtyPair) -> None:
    with (emulated("numato", pty_pair) as rig, open_relay(rig.uri),
          pytest.raises(DeviceError, match="cannot open relay port")):
        open_relay(rig.uri)


def _listening(tcp_port: int) -> bool:
    """Whether something listens on 127.0.0.1:tcp_port (read from /proc: a probe connection
    would use up socat's only connection)."""
    wanted = f"0100007F:{tcp_port:04X}"
    with open("/proc/net/tcp") as table:
        return any(fields[1] == wanted and fields[3] == "0A"  # 0A = LISTEN
                   for fields in (line.split() for line in list(table)[1:]))


def test_modbus_over_socket_url(tmp_path: Path) -> None:
    # A serial-over-TCP converter: socat bridges a PTY (the board) to a TCP listener.
    tcp_port = free_port()
    link = tmp_path / "board"
    # The PTY first: socat opens its addresses in order and the listener blocks in accept().
    process = subprocess.Popen(
        [socat(), "-d", "-d", f"pty,raw,echo=0,link={link}",
         f"tcp-listen:{tcp_port},bind=127.0.0.1,reuseaddr"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        wait_for(lambda: link.exists() and _listening(tcp_port), START_TIMEOUT_S,
                  "socat's PTY link and TCP listener", process)
        pair = PtyPair(app=f"socket://127.0.0.1:{tcp_port}", board=str(link), process=process)
        with emulated("modbus", pair) as rig:
            with open_relay(rig.uri) as relay:
                assert relay.on().confirmed
                assert rig.settled(True)
            assert rig.settled(False)
            assert rig.board is not None
            assert rig.board.frames()[:2] == [ON["modbus"], READ["modbus"]]
    finally:
        stop_process(process)


# -- the contract (edgedsm.testing), shared by the simulated relay and every emulated board --

@pytest.mark.parametrize("contract_check", list(RELAY_CHECKS.values()), ids=list(RELAY_CHECKS))
def test_contract(any_rig: Rig, contract_check: Callable[[RelayRig], None]) -> None:
    contract_check(RelayRig(open=lambda: open_relay(any_rig.uri), is_on=lambda: any_rig.is_on,
                            readback=any_rig.readback, force=any_rig.force))


def test_contract_catches_a_board_left_on(any_rig: Rig) -> None:
    """The checks watch the contact, not the driver: a relay that never switches off fails."""
    class LeftOn:
        def __init__(self) -> None:
            self.relay = open_relay(any_rig.uri)

        def __getattr__(self, name: str) -> object:
            return getattr(self.relay, name)

        def close(self) -> None:
            self.relay.detach()  # releases the port WITHOUT switching off

        def __enter__(self) -> LeftOn:
            return self

        def __exit__(self, *exc: object) -> None:
            self.close()

    rig = RelayRig(open=LeftOn, is_on=lambda: any_rig.is_on,  # type: ignore[arg-type]
                   readback=any_rig.readback, settle_s=0.3)
    with pytest.raises(AssertionError, match=r"the contact is ON after close\(\)"):
        RELAY_CHECKS["close_leaves_it_off"](rig)
    any_rig.force(False)


# -- the field tool, end to end ------------------------------------------------------------

def test_cli_laser_on_holds_then_switches_off(readback_rig: Rig,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["laser", "on", readback_rig.uri, "--for", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "laser: on (readback confirmed)" in out
    assert "laser: holding on for 0.3 s" in out
    assert out.rstrip().endswith("laser: off (readback confirmed)")
    assert readback_rig.settled(False)
    name = readback_rig.name
    assert readback_rig.board is not None
    assert readback_rig.board.frames()[:4] == [OFF[name], READ[name], ON[name], READ[name]]


def test_cli_status_off_and_leave_on(readback_rig: Rig,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    uri = readback_rig.uri
    assert main(["laser", "status", uri]) == 0
    assert capsys.readouterr().out == "laser: off (readback confirmed)\n"
    assert main(["laser", "on", uri, "--leave-on"]) == 0
    assert "left ON as asked" in capsys.readouterr().out
    assert readback_rig.settled(True)
    assert main(["laser", "status", uri]) == 0
    assert capsys.readouterr().out == "laser: on (readback confirmed)\n"
    assert readback_rig.settled(True)  # status changed nothing
    assert main(["laser", "off", uri]) == 0
    assert capsys.readouterr().out == "laser: off (readback confirmed)\n"
    assert readback_rig.settled(False)


def test_cli_lcus_says_it_cannot_confirm(pty_pair: PtyPair,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    with emulated("lcus", pty_pair) as rig:
        assert main(["laser", "on", rig.uri, "--for", "0"]) == 0
        out = capsys.readouterr().out
        assert "laser: on (as commanded; this board has no readback)" in out
        assert main(["laser", "status", rig.uri]) == 0
        assert "unknown" in capsys.readouterr().out
        assert rig.board is not None
        assert rig.board.wait_frames(4)[:2] == [OFF["lcus"], ON["lcus"]]
        assert rig.settled(False)


def test_cli_reports_a_dead_board(pty_pair: PtyPair, capsys: pytest.CaptureFixture[str]) -> None:
    with emulated("numato", pty_pair) as rig:
        assert rig.board is not None
        rig.board.mode = "silent"
        started = time.monotonic()
        assert main(["laser", "on", rig.uri_with("timeout=0.2"), "--for", "5"]) == 69
        assert time.monotonic() - started < 3 * BOUND_S
        err = capsys.readouterr().err
        assert "edgedsm: error:" in err and "no answer within 0.2 s" in err


@pytest.mark.alone
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
# the kernel may hand a process-directed signal to any thread: "another thread" sends it to the
# sender's own thread, where Python only flags it for the main thread (asleep in the hold)
@pytest.mark.parametrize("taken_by", ["the process", "another thread"])
def test_cli_hold_ends_on_signal_with_laser_off(signum: int, taken_by: str, pty_pair: PtyPair,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    with emulated("numato", pty_pair) as rig:
        done = threading.Event()
        signalled: list[float] = []

        def signal_once_on() -> None:
            # Not a fixed delay: building the CLI parser imports every command and may be slow
            # on a loaded machine, so the bound is measured from the signal, not from the start.
            if rig.settled(True, timeout=60) and not done.is_set():
                signalled.append(time.monotonic())
                if taken_by == "the process":
                    os.kill(os.getpid(), signum)
                else:
                    signal.pthread_kill(threading.get_ident(), signum)

        sender = threading.Thread(target=signal_once_on, daemon=True)
        # a shell without job control starts background commands with SIGINT ignored (and Python
        # then installs no KeyboardInterrupt handler): Ctrl-C as a terminal delivers it
        interrupt = signal.signal(signal.SIGINT, signal.default_int_handler)
        sender.start()
        try:
            assert main(["laser", "on", rig.uri, "--for", "120"]) == 0
        finally:
            done.set()
            sender.join(BOUND_S)
            signal.signal(signal.SIGINT, interrupt)
        assert signalled, "the laser never went on"
        assert time.monotonic() - signalled[0] < 3 * BOUND_S
        out = capsys.readouterr().out
        why = "stopped by SIGTERM" if signum == signal.SIGTERM else "Ctrl-C"
        assert out.splitlines()[-1] == f"laser: off ({why}; switched off on the way out)"
        assert rig.settled(False)
        assert signal.getsignal(signal.SIGTERM) is not None  # handlers were restored


def test_cli_bad_uri_exits_78(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["laser", "status", "serial:/dev/ttyUSB0?protocol=lcus&chanel=1"]) == 78
    assert "unknown option 'chanel'" in capsys.readouterr().err
