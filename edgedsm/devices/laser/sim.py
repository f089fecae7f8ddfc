"""Simulated laser relay: a first-class device for the simulated camera, demos and tests.

Two parts, as with a real board and its driver:

``SimulatedBoard``
    The physical relay: its state, the history of every switching it executed, listeners
    (the simulated camera delivers speckle only while the laser is on) and an injectable
    fault. Boards can be shared by name within a process (``sim:NAME``), so a test can
    inspect the board a daemon opened from its config.
``SimulatedRelay``
    The driver, a ``LaserRelay`` like the real ones, so the same contract tests run on it.

Faults (``fault=`` in the URI or ``SimulatedBoard.fault``), each like its real counterpart:

``none``        the board works.
``no-answer``   the board is dead: commands have no effect; with readback, every exchange
                waits ``timeout`` seconds and raises ``DeviceTimeout``. Without readback the
                command is silently lost, exactly as with a dead LCUS board.
``garbage``     the board answers nonsense: commands have no effect; with readback they
                raise ``DeviceError``.
``stuck``       the contact is welded/stuck: commands are acknowledged but the state does not
                change; the readback check raises ``DeviceError``.
``lost``        the port is gone (cable pulled): everything raises ``DeviceLost``.

A fault can also be transient: ``SimulatedBoard.fail_next(n, fault)`` makes only the next ``n``
exchanges (switchings and readbacks) fail that way (``no-answer``, ``garbage`` or ``lost``);
the board then works again.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from edgedsm.devices.laser.base import LaserRelay
from edgedsm.devices.uri import DEFAULT_SIM_TIMEOUT, SIM_FAULTS, RelaySpec
from edgedsm.errors import DeviceError, DeviceLost, DeviceTimeout


@dataclass(frozen=True)
class Switching:
    """One switching command the board executed: when (time.monotonic_ns) and to what."""

    t_ns: int
    on: bool


class SimulatedBoard:
    """The physical side of a simulated relay (thread-safe)."""

    def __init__(self, name: str = "", *, readback: bool = True, fault: str = "none") -> None:
        self.name = name
        self.readback = readback
        self._lock = threading.Lock()
        self._on = False
        self._fault = "none"
        self.fault = fault
        self._history: list[Switching] = []
        self._listeners: list[Callable[[bool], None]] = []
        self._transient: list[str] = []  # faults of the next exchanges, first one first

    @property
    def is_on(self) -> bool:
        """The true state of the contact, whatever any driver believes."""
        with self._lock:
            return self._on

    @property
    def history(self) -> list[Switching]:
        """Every switching the board executed, oldest first (a copy)."""
        with self._lock:
            return list(self._history)

    @property
    def fault(self) -> str:
        """The injected fault (see the module docstring)."""
        return self._fault

    @fault.setter
    def fault(self, value: str) -> None:
        if value not in SIM_FAULTS:
            raise ValueError(f"unknown fault {value!r}; one of {', '.join(SIM_FAULTS)}")
        self._fault = value

    def fail_next(self, exchanges: int, fault: str = "no-answer") -> None:
        """Make the next ``exchanges`` driver exchanges fail as ``fault`` would, then work again."""
        if fault not in ("no-answer", "garbage", "lost"):
            raise ValueError(f"a transient fault is 'no-answer', 'garbage' or 'lost', not {fault!r}")
        with self._lock:
            self._transient = [fault] * exchanges

    def next_fault(self) -> str:
        """The fault of the exchange about to happen (a transient one is used up)."""
        with self._lock:
            return self._transient.pop(0) if self._transient else self._fault

    def add_listener(self, callback: Callable[[bool], None]) -> None:
        """Call ``callback(on)`` whenever the contact changes state."""
        with self._lock:
            self._listeners.append(callback)

    def apply(self, on: bool) -> None:
        """Execute a switching command that reached the board intact."""
        with self._lock:
            self._history.append(Switching(time.monotonic_ns(), on))
            if self._fault == "stuck":
                return
            changed, self._on = self._on != on, on
            listeners = list(self._listeners) if changed else []
        for callback in listeners:  # outside the lock: a listener may read is_on
            callback(on)


_boards: dict[str, SimulatedBoard] = {}
_boards_lock = threading.Lock()


def simulated_board(name: str) -> SimulatedBoard:
    """The process-wide simulated board called ``name`` (created on first use)."""
    with _boards_lock:
        board = _boards.get(name)
        if board is None:
            board = _boards[name] = SimulatedBoard(name)
        return board


def forget_simulated_boards() -> None:
    """Drop every named board (tests start from a clean slate)."""
    with _boards_lock:
        _boards.clear()


class SimulatedRelay(LaserRelay):
    """Driver of a ``SimulatedBoard``: the same contract as the real relay drivers."""

    def __init__(self, board: SimulatedBoard | None = None, *, timeout: float = DEFAULT_SIM_TIMEOUT,
                 verify: bool = True) -> None:
        self.board = board if board is not None else SimulatedBoard()
        name = f" {self.board.name!r}" if self.board.name else ""
        super().__init__(verify=verify, description=f"simulated relay{name}")
        self.timeout = timeout

    @classmethod
    def from_spec(cls, spec: RelaySpec) -> SimulatedRelay:
        """Build from a parsed ``sim:`` URI; options set the (possibly shared) board."""
        board = simulated_board(spec.port) if spec.port else SimulatedBoard()
        if "readback" in spec.options:
            board.readback = bool(spec.options["readback"])
        if "fault" in spec.options:
            board.fault = str(spec.options["fault"])
        return cls(board, timeout=spec.timeout, verify=spec.verify)

    @property
    def readback(self) -> bool:
        return self.board.readback

    def _fail_if_faulty(self) -> bool:
        """Raise as the faulty board would; return False when the command is lost."""
        fault = self.board.next_fault()
        if fault == "lost":
            raise DeviceLost(f"{self.description}: port failed (simulated cable pulled)")
        if fault == "no-answer":
            if not self.board.readback:
                return False
            time.sleep(self.timeout)  # a real driver waits this long too
            raise DeviceTimeout(f"{self.description}: no answer within {self.timeout} s")
        if fault == "garbage":
            if not self.board.readback:
                return False
            raise DeviceError(f"{self.description}: unexpected answer 5A A5 FF (simulated)")
        return True

    def _do_switch(self, on: bool) -> None:
        if self._fail_if_faulty():
            self.board.apply(on)

    def _do_read_state(self) -> bool:
        self._fail_if_faulty()
        return self.board.is_on

    def _do_close(self) -> None:
        pass  # nothing to release
