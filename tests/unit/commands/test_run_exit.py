"""A stopped daemon names the threads that would hold its exit, with their stacks."""

from __future__ import annotations

import logging
import threading

import pytest

from edgedsm.commands.run import _name_threads_holding_exit


def _said_with_a_thread_waiting(name: str, daemon: bool, caplog: pytest.LogCaptureFixture) -> str:
    """What the exit check logs while a thread named ``name`` waits on an event."""
    gate = threading.Event()
    waiting = threading.Thread(target=gate.wait, name=name, daemon=daemon)
    waiting.start()
    try:
        with caplog.at_level(logging.ERROR):
            _name_threads_holding_exit()
    finally:
        gate.set()
        waiting.join(5)
    return caplog.text


def test_a_non_daemon_thread_still_running_is_named_with_its_stack(capfd: pytest.CaptureFixture[str],
                                                                    caplog: pytest.LogCaptureFixture) -> None:
    assert "stuck-evaluation" in _said_with_a_thread_waiting("stuck-evaluation", False, caplog)
    assert "in wait" in capfd.readouterr().err  # the held thread's stack: waiting on the event


def test_nothing_is_said_when_only_daemon_threads_remain(caplog: pytest.LogCaptureFixture) -> None:
    assert "daemon-helper" not in _said_with_a_thread_waiting("daemon-helper", True, caplog)
