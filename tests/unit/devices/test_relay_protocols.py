"""Relay protocols byte by byte, the URI scheme, the relay contract on the simulator, safety.

Nothing here talks to an external program; the PTY tests with emulated boards are in
tests/integration/test_relays_pty.py.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from edgedsm.devices.laser import (
    LaserSafety,
    LcusRelay,
    SignalExit,
    SimulatedBoard,
    SimulatedRelay,
    forget_simulated_boards,
    kmtronic,
    lcus,
    modbus,
    numato,
    open_relay,
    simulated_board,
)
from edgedsm.devices.uri import parse_relay_uri
from edgedsm.errors import ConfigError, DeviceError, DeviceLost, DeviceTimeout

pytestmark = pytest.mark.timeout(30)

H = bytes.fromhex


# -- LCUS ----------------------------------------------------------------------------------

@pytest.mark.parametrize(("channel", "on", "expected"), [
    (1, True, "A0 01 01 A2"),   # the boards' documented "open" example
    (1, False, "A0 01 00 A1"),  # documented "close" example
    (2, True, "A0 02 01 A3"),
    (2, False, "A0 02 00 A2"),
    (0x5F, True, "A0 5F 01 00"),  # checksum wraps at 0x100
])
def test_lcus_encoding(channel: int, on: bool, expected: str) -> None:
    assert lcus.encode_switch(channel, on) == H(expected)


@pytest.mark.parametrize("channel", [0, 256, -1])
def test_lcus_refuses_bad_channel(channel: int) -> None:
    with pytest.raises(ValueError, match=r"1\.\.255"):
        lcus.encode_switch(channel, True)


# -- Numato --------------------------------------------------------------------------------

@pytest.mark.parametrize(("channel", "token"), [(0, "0"), (9, "9"), (10, "A"), (15, "F"),
                                                (16, "G"), (31, "V")])
def test_numato_channel_tokens_run_past_f(channel: int, token: str) -> None:
    assert numato.channel_token(channel) == token


def test_numato_commands() -> None:
    assert numato.encode_command("on", 0) == b"relay on 0\r"
    assert numato.encode_command("off", 0) == b"relay off 0\r"
    assert numato.encode_command("read", 11) == b"relay read B\r"
    with pytest.raises(ValueError):
        numato.encode_command("toggle", 0)
    with pytest.raises(ValueError):
        numato.channel_token(32)


@pytest.mark.parametrize(("reply", "answer"), [
    (b"relay read 0\n\ron\n\r>", "on"),
    (b"relay read 0\n\roff\n\r>", "off"),
    (b"relay read 0\r\non\r\n>", "on"),  # line ends the other way round
])
def test_numato_reply_parsing(reply: bytes, answer: str) -> None:
    assert numato.parse_reply("relay read 0", reply) == answer


def test_numato_switch_reply_has_no_answer_although_echo_says_on() -> None:
    # A naive "'on' in reply" would read this echo as the relay being on.
    assert numato.parse_reply("relay on 0", b"relay on 0\n\r>") == ""
    assert numato.parse_reply("relay off 0", b"relay off 0\n\r>") == ""


@pytest.mark.parametrize(("reply", "reason"), [
    (b"relay read 1\n\ron\n\r>", "did not echo"),
    (b"relay read 0\n\ron\n\r", "no prompt"),
    (b"\xfe\xff\x13>", "non-ASCII"),
    (b"relay read 0\n\ron\n\roff\n\r>", "several answers"),
    (b"relay read 07\n\ron\n\r>", "runs on"),
])
def test_numato_bad_replies(reply: bytes, reason: str) -> None:
    with pytest.raises(DeviceError, match=reason):
        numato.parse_reply("relay read 0", reply)


def test_numato_state_words() -> None:
    assert numato.parse_state("on") is True
    assert numato.parse_state("off") is False
    with pytest.raises(DeviceError, match="'maybe'"):
        numato.parse_state("maybe")


# -- KMTronic ------------------------------------------------------------------------------

def test_kmtronic_encoding() -> None:
    assert kmtronic.encode_switch(1, True) == H("FF 01 01")
    assert kmtronic.encode_switch(8, False) == H("FF 08 00")
    assert kmtronic.encode_status(3, 8) == H("FF 09 00")
    assert kmtronic.encode_status(3, 4) == H("FF 09 00")
    assert kmtronic.encode_status(2, 2) == H("FF 02 03")
    with pytest.raises(ValueError):
        kmtronic.encode_switch(9, True)
    with pytest.raises(ValueError):
        kmtronic.encode_status(1, 3)


def test_kmtronic_status_decoding() -> None:
    answer = H("00 00 01 00 00 00 00 01")
    assert [kmtronic.decode_status(answer, ch, 8) for ch in range(1, 9)] == \
        [False, False, True, False, False, False, False, True]
    assert kmtronic.decode_status(H("FF 02 01"), 2, 2) is True
    assert kmtronic.decode_status(H("FF 01 00"), 1, 1) is False


@pytest.mark.parametrize(("answer", "channel", "relays", "reason"), [
    ("00 01 00 00", 1, 8, "has 4 bytes, expected 8"),
    ("00 02 00 00", 1, 4, "0x02"),
    ("FF 01 01", 2, 2, "should start FF 02"),
    ("FE 01 01", 1, 1, "should start FF 01"),
])
def test_kmtronic_bad_status(answer: str, channel: int, relays: int, reason: str) -> None:
    with pytest.raises(DeviceError, match=reason):
        kmtronic.decode_status(H(answer), channel, relays)


# -- Modbus RTU ----------------------------------------------------------------------------

@pytest.mark.parametrize(("body", "crc"), [
    ("01 05 00 00 FF 00", "8C 3A"),  # write coil 0 on: the vector from the brief and manuals
    ("01 05 00 00 00 00", "CD CA"),
    ("01 01 00 00 00 08", "3D CC"),  # read 8 coils (IO-Box manual)
    ("01 01 01 41", "91 B8"),        # its answer (IO-Box manual)
    ("31 32 33 34 35 36 37 38 39", "37 4B"),  # "123456789": the catalogue check 0x4B37
])
def test_modbus_crc_known_vectors(body: str, crc: str) -> None:
    assert modbus.crc16(H(body)).to_bytes(2, "little") == H(crc)
    assert modbus.frame(H(body)) == H(body) + H(crc)


def test_modbus_requests() -> None:
    assert modbus.encode_write_coil(1, 0, True) == H("01 05 00 00 FF 00 8C 3A")
    assert modbus.encode_write_coil(1, 0, False) == H("01 05 00 00 00 00 CD CA")
    assert modbus.encode_read_coils(1, 0, 8) == H("01 01 00 00 00 08 3D CC")
    assert modbus.encode_write_coil(7, 5, True) == H("07 05 00 05 FF 00 9C 5D")
    assert modbus.encode_read_coils(7, 5) == H("07 01 00 05 00 01 ED AD")
    for bad in [(0, 0), (248, 0), (1, 0x10000)]:
        with pytest.raises(ValueError):
            modbus.encode_write_coil(*bad, True)


def test_modbus_read_coils_answer() -> None:
    assert modbus.decode_read_coils(H("01 01 01 41 91 B8"), 1, 8) == \
        [True, False, False, False, False, False, True, False]
    assert modbus.decode_read_coils(H("07 01 01 01 90 C0"), 7) == [True]
    assert modbus.decode_read_coils(H("07 01 01 00 51 00"), 7) == [False]


def test_modbus_write_coil_answer_must_echo() -> None:
    request = modbus.encode_write_coil(7, 5, True)
    modbus.decode_write_coil(request, request)  # the echo is the normal answer
    with pytest.raises(DeviceError, match="does not echo"):
        modbus.decode_write_coil(modbus.encode_write_coil(7, 5, False), request)


@pytest.mark.parametrize(("answer", "reason"), [
    ("07 81 02 21 90", "refused function 01 with exception 02 \\(illegal data address"),
    ("07 85 02 23 50", "answer for function 85, expected 01"),
    ("07 01 01 01 90 C1", "bad CRC"),
    ("01 01 01 41 91 B8", "from slave 1, expected 7"),
    ("07 01", "too short"),
])
def test_modbus_bad_answers(answer: str, reason: str) -> None:
    with pytest.raises(DeviceError, match=reason):
        modbus.decode_read_coils(H(answer), 7)


def test_modbus_wrong_byte_count() -> None:
    with pytest.raises(DeviceError, match="carries 2 data bytes, expected 1"):
        modbus.decode_read_coils(modbus.frame(H("07 01 02 01 00")), 7)


def test_modbus_exception_answer_to_write() -> None:
    exception = modbus.frame(H("07 85 02"))
    assert exception == H("07 85 02 23 50")
    with pytest.raises(DeviceError, match="illegal data address"):
        modbus.decode_write_coil(exception, modbus.encode_write_coil(7, 5, True))


def test_modbus_answer_length() -> None:
    assert modbus.answer_length(H("07 05 00")) == 8
    assert modbus.answer_length(H("07 01 01")) == 6
    assert modbus.answer_length(H("07 01 02")) == 7
    assert modbus.answer_length(H("07 85 02")) == 5
    with pytest.raises(DeviceError, match="unexpected function"):
        modbus.answer_length(H("07 2A 00"))


def test_modbus_silent_interval() -> None:
    assert modbus.silent_interval(9600) == pytest.approx(3.5 * 11 / 9600)  # ~4.0 ms
    assert modbus.silent_interval(115200) == pytest.approx(1.75e-3)


# -- URI scheme ----------------------------------------------------------------------------

def test_uri_defaults_per_protocol() -> None:
    spec = parse_relay_uri("serial:/dev/ttyUSB0?protocol=lcus")
    assert (spec.kind, spec.port, spec.protocol, spec.channel, spec.baud, spec.timeout,
            spec.verify) == ("serial", "/dev/ttyUSB0", "lcus", 1, 9600, 0.5, True)
    assert not spec.is_url
    assert parse_relay_uri("serial:/dev/ttyACM0?protocol=numato").channel == 0
    assert parse_relay_uri("serial:/dev/ttyACM0?protocol=numato").baud == 19200
    spec = parse_relay_uri("serial:COM3?protocol=modbus")
    assert spec.options == {"slave": 1, "parity": "N"} and spec.channel == 0
    assert parse_relay_uri("serial:/dev/x?protocol=kmtronic").options == {"relays": 8}


def test_uri_full_and_pyserial_urls() -> None:
    spec = parse_relay_uri("serial:/dev/ttyUSB0?protocol=lcus&channel=1&baud=9600&timeout=0.5")
    assert (spec.channel, spec.baud, spec.timeout) == (1, 9600, 0.5)
    spec = parse_relay_uri("serial:socket://127.0.0.1:5000?protocol=modbus&slave=3&channel=17"
                           "&parity=e&verify=false")
    assert spec.port == "socket://127.0.0.1:5000" and spec.is_url
    assert (spec.channel, spec.verify, spec.options) == (17, False, {"slave": 3, "parity": "E"})
    spec = parse_relay_uri("serial:loop://?protocol=numato&channel=12")
    assert (spec.port, spec.protocol, spec.channel) == ("loop://", "numato", 12)
    spec = parse_relay_uri("  SERIAL:/dev/ttyUSB1?protocol=KMTRONIC&channel=4&relays=4 ")
    assert (spec.protocol, spec.channel, spec.options) == ("kmtronic", 4, {"relays": 4})


def test_uri_sim() -> None:
    spec = parse_relay_uri("sim:")
    assert (spec.kind, spec.port, spec.options) == ("sim", "", {})
    spec = parse_relay_uri("sim:bench-1?fault=no-answer&readback=false&timeout=0.2")
    assert (spec.port, spec.timeout) == ("bench-1", 0.2)
    assert spec.options == {"fault": "no-answer", "readback": False}


@pytest.mark.parametrize(("uri", "reason"), [
    ("", "empty"),
    ("/dev/ttyUSB0", "no scheme"),
    ("usb:/dev/ttyUSB0?protocol=lcus", "unknown scheme 'usb'"),
    ("serial:?protocol=lcus", "no serial port"),
    ("serial:/dev/ttyUSB0", "missing protocol"),
    ("serial:/dev/ttyUSB0?protocol=hid", "'hid' is not one of"),
    ("serial:/dev/ttyUSB0?protocol=lcus&chanel=1", "unknown option 'chanel'"),
    ("serial:/dev/ttyUSB0?protocol=lcus&slave=2", "unknown option 'slave'"),
    ("serial:/dev/ttyUSB0?protocol=lcus&channel=0", "channel=0 is out of range 1..255"),
    ("serial:/dev/ttyUSB0?protocol=numato&channel=32", "out of range 0..31"),
    ("serial:/dev/ttyUSB0?protocol=lcus&channel=one", "not a whole number"),
    ("serial:/dev/ttyUSB0?protocol=lcus&channel=1&channel=2", "given twice"),
    ("serial:/dev/ttyUSB0?protocol=lcus&channel=", "has no value"),
    ("serial:/dev/ttyUSB0?protocol=lcus&&channel=1", "cannot read the options"),
    ("serial:/dev/ttyUSB0?protocol=lcus&timeout=0", "timeout=0 must be >= 0.01 and <= 30 seconds"),
    ("serial:/dev/ttyUSB0?protocol=lcus&timeout=nan", "timeout=nan must be >= 0.01 and <= 30 seconds"),
    ("serial:/dev/ttyUSB0?protocol=lcus&timeout=120", "timeout=120 must be >= 0.01 and <= 30 seconds"),
    ("serial:/dev/ttyUSB0?protocol=lcus&baud=12", "out of range"),
    ("serial:/dev/ttyUSB0?protocol=lcus&verify=maybe", "true or false"),
    ("serial:/dev/ttyUSB0?protocol=modbus&slave=0", "out of range 1..247"),
    ("serial:/dev/ttyUSB0?protocol=modbus&parity=X", "N, E or O"),
    ("serial:/dev/ttyUSB0?protocol=kmtronic&relays=3", "1, 2, 4 or 8"),
    ("serial:/dev/ttyUSB0?protocol=kmtronic&relays=2&channel=3", "only relays=2"),
    ("serial:/dev/tty USB0?protocol=lcus", "white space"),
    ("sim:?fault=fire", "not one of"),
    ("sim:a/b", "may hold only"),
    ("sim:?protocol=lcus", "unknown option 'protocol'"),
])
def test_bad_uris_are_config_errors(uri: str, reason: str) -> None:
    with pytest.raises(ConfigError, match=reason):
        parse_relay_uri(uri)


def test_open_relay_bad_uri_and_missing_port() -> None:
    with pytest.raises(ConfigError):
        open_relay("serial:/dev/ttyUSB0?protocol=nope")
    with pytest.raises(DeviceError, match="cannot open relay port /dev/edgedsm-no-such-tty"):
        open_relay("serial:/dev/edgedsm-no-such-tty?protocol=lcus")
    with pytest.raises(ConfigError):
        open_relay("serial:nosuchscheme://x?protocol=lcus")


def test_lcus_over_pyserial_loop_url() -> None:
    # loop:// hands back what was written: the exact bytes on the wire, with no PTY needed.
    with open_relay("serial:loop://?protocol=lcus&channel=3") as relay:
        assert isinstance(relay, LcusRelay)
        assert relay.state().on is None  # nothing switched yet, nothing to read back
        status = relay.on()
        assert (status.on, status.confirmed) == (True, False)
        assert relay._port.read(4) == H("A0 03 01 A4")  # type: ignore[attr-defined]


# -- The relay contract on the simulator ---------------------------------------------------

@pytest.fixture(autouse=True)
def _clean_boards() -> None:
    forget_simulated_boards()


def test_sim_switches_and_records_history() -> None:
    relay = SimulatedRelay()
    assert relay.state().on is False and relay.state().confirmed
    assert relay.on().describe() == "on (readback confirmed)"
    assert relay.board.is_on
    assert relay.off().on is False
    relay.close()
    assert [s.on for s in relay.board.history] == [True, False, False]  # close() switched off
    times = [s.t_ns for s in relay.board.history]
    assert times == sorted(times)


def test_sim_without_readback_reports_commands_only() -> None:
    relay = open_relay("sim:?readback=false")
    assert relay.state().describe().startswith("unknown")
    assert relay.on().describe() == "on (as commanded; this board has no readback)"
    assert relay.state().on is True and not relay.state().confirmed
    relay.close()


def test_named_sim_boards_are_shared() -> None:
    relay = open_relay("sim:bench")
    relay.on()
    assert simulated_board("bench").is_on
    relay.detach()  # leaves it on
    assert simulated_board("bench").is_on
    with open_relay("sim:bench") as again:
        assert again.state().on is True
    assert not simulated_board("bench").is_on


def test_sim_listener_sees_changes_only() -> None:
    seen: list[bool] = []
    board = SimulatedBoard()
    board.add_listener(seen.append)
    relay = SimulatedRelay(board)
    relay.off()
    relay.on()
    relay.on()
    relay.off()
    assert seen == [True, False]


def test_sim_no_answer_times_out_within_bound() -> None:
    relay = open_relay("sim:?fault=no-answer&timeout=0.1")
    started = time.monotonic()
    with pytest.raises(DeviceTimeout, match=r"no answer within 0\.1 s"):
        relay.on()
    assert time.monotonic() - started < 1.0
    assert not relay.board.is_on  # type: ignore[attr-defined]
    with pytest.raises(DeviceTimeout):
        relay.close()
    assert relay.closed  # released even though switching off failed


def test_sim_dead_board_without_readback_goes_unnoticed() -> None:
    # Like a dead LCUS board: the command is lost and nothing can tell.
    relay = open_relay("sim:?fault=no-answer&readback=false")
    assert relay.on().on is True
    assert not relay.board.is_on  # type: ignore[attr-defined]
    relay.close()


def test_sim_faults_garbage_stuck_lost() -> None:
    with pytest.raises(DeviceError, match="unexpected answer"):
        open_relay("sim:?fault=garbage").on()
    stuck = open_relay("sim:?fault=stuck")
    with pytest.raises(DeviceError, match="commanded on but the board reports off"):
        stuck.on()
    assert stuck.state().on is False
    stuck.close()
    with pytest.raises(DeviceLost):
        open_relay("sim:?fault=lost").state()


def test_closed_relay_refuses_and_close_is_idempotent() -> None:
    relay = SimulatedRelay()
    relay.close()
    relay.close()
    relay.detach()
    for method in (relay.on, relay.off, relay.state):
        with pytest.raises(DeviceError, match="closed"):
            method()


def test_exit_on_exception_switches_off_and_notes_failure() -> None:
    board = SimulatedBoard()
    with pytest.raises(RuntimeError), SimulatedRelay(board) as relay:
        relay.on()
        raise RuntimeError("camera lost")
    assert not board.is_on
    # When switching off fails too, the original error stays in charge, with a note.
    with pytest.raises(RuntimeError) as info, SimulatedRelay(board, timeout=0.01) as relay:
        relay.on()
        board.fault = "lost"
        raise RuntimeError("camera lost")
    assert any("could not be switched off" in note for note in info.value.__notes__)


# -- Laser safety --------------------------------------------------------------------------

def test_safety_switches_off_at_start_and_at_exit() -> None:
    board = SimulatedBoard()
    board.apply(True)  # left on by someone else
    with LaserSafety(SimulatedRelay(board)) as relay:
        assert not board.is_on
        relay.on()
        assert board.is_on
    assert not board.is_on and relay.closed


def test_safety_on_exception_and_keyboard_interrupt() -> None:
    for error in (ValueError("bad frame"), KeyboardInterrupt()):
        board = SimulatedBoard()
        with pytest.raises(type(error)), LaserSafety(SimulatedRelay(board)) as relay:
            relay.on()
            raise error
        assert not board.is_on


def test_safety_retries_then_reports() -> None:
    board = SimulatedBoard()
    safety = LaserSafety(SimulatedRelay(board, timeout=0.01), attempts=2)
    with pytest.raises(DeviceTimeout), safety as relay:
        relay.on()
        board.fault = "no-answer"
    assert safety.off_error is not None and board.is_on
    assert [s.on for s in board.history] == [False, True]  # no attempt reached the board


def test_safety_refuses_to_start_when_off_fails() -> None:
    board = SimulatedBoard(fault="lost")
    ran = False
    with pytest.raises(DeviceLost), LaserSafety(SimulatedRelay(board)):
        ran = True
    assert not ran


def test_safety_sigterm_switches_off_and_restores_handler() -> None:
    board = SimulatedBoard()
    before = signal.getsignal(signal.SIGTERM)
    safety = LaserSafety(SimulatedRelay(board), signals=(signal.SIGTERM,))
    with pytest.raises(SignalExit) as info, safety as relay:
        relay.on()
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler interrupts this
    assert info.value.code == 128 + signal.SIGTERM and "SIGTERM" in str(info.value)
    assert not board.is_on
    assert safety.signalled == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) == before


def test_safety_signal_during_switch_off_does_not_cut_it_short() -> None:
    board = SimulatedBoard()

    class SlowOff(SimulatedRelay):
        def _do_switch(self, on: bool) -> None:
            if not on and board.is_on:
                os.kill(os.getpid(), signal.SIGTERM)  # arrives while switching off
            super()._do_switch(on)

    safety = LaserSafety(SlowOff(board), signals=(signal.SIGTERM,))
    with safety as relay:
        relay.on()
    assert not board.is_on and safety.signalled == signal.SIGTERM


def test_safety_signals_only_from_main_thread() -> None:
    errors: list[BaseException] = []

    def worker() -> None:
        try:
            with LaserSafety(SimulatedRelay(), signals=(signal.SIGTERM,)):
                pass
        except RuntimeError as exc:
            errors.append(exc)

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join(5)
    assert errors and "main thread" in str(errors[0])


class _LateAnswerPort:
    """A port whose board was still answering a readback cut short by a signal: its tail arrives
    after the input is flushed, before the answer to the next request."""

    portstr = "late"

    def __init__(self, tail: bytes, answer: bytes) -> None:
        self.tail, self.answer, self.pending, self.written = tail, answer, b"", b""
        self.by_prompt = False

    def reset_input_buffer(self) -> None:
        self.pending = b""

    def write(self, data: bytes) -> int:
        self.written += data
        self.pending += self.tail + self.answer
        return len(data)

    def flush(self) -> None:
        pass

    @property
    def in_waiting(self) -> int:
        return len(self.pending)

    def read(self, size: int) -> bytes:
        if self.by_prompt and b">" in self.pending[:size]:
            size = self.pending.index(b">") + 1  # the tail comes in a read of its own
        chunk, self.pending = self.pending[:size], self.pending[size:]
        return chunk

    def close(self) -> None:
        pass


@pytest.mark.parametrize("by_prompt", [False, True])
@pytest.mark.parametrize("tail", [b"relay read B\n\ron\n\r>", b"on\n\r>", b">"])
def test_numato_switch_off_skips_the_tail_of_a_readback_cut_short(tail: bytes, by_prompt: bool) -> None:
    from edgedsm.devices.laser.numato import NumatoRelay

    port = _LateAnswerPort(tail, b"relay off B\n\r>")
    port.by_prompt = by_prompt
    relay = NumatoRelay(port, channel=11, timeout=0.5, verify=False)  # type: ignore[arg-type]
    relay._do_switch(False)  # no error: the late tail is not taken for the answer to 'relay off'
    assert port.written == b"relay off B\r"


def test_numato_a_foreign_answer_is_still_refused() -> None:
    from edgedsm.devices.laser.numato import NumatoRelay

    port = _LateAnswerPort(b"", b"garbage\n\r>")
    relay = NumatoRelay(port, channel=11, timeout=0.5, verify=False)  # type: ignore[arg-type]
    with pytest.raises(DeviceError, match="did not echo"):
        relay._do_switch(False)
