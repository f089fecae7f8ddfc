"""A stopped daemon names the threads that would hold its exit, with their stacks."""

from __future__ import annotations

import logging
import threading

import pytest

from edgedsm.commands.run import _name_threads_holding_exit


def test_a_non_daemon_thread_still_running_is_named_with_its_stack(capfd: pytest.CaptureFixture[str],
                                                                    caplog: pytest.LogCaptureFixture) -> None:
    gate = threading.Event()
    holder = threading.Thread(target=gate.wait, name="stuck-evaluation", daemon=False)
    holder.start()
    try:
        with caplog.at_level(logging.ERROR):
            _name_threads_holding_exit()
    finally:
        gate.set()
        holder.join(5)
    assert "stuck-evaluation" in caplog.text
    assert "in wait" in capfd.readouterr().err  # the held thread's stack: waiting on the event


def test_nothing_is_said_when_only_daemon_threads_remain(caplog: pytest.LogCaptureFixture) -> None:
    gate = threading.Event()
    helper = threading.Thread(target=gate.wait, name="daemon-helper", daemon=True)
    helper.start()
    try:
        with caplog.at_level(logging.ERROR):
            _name_threads_holding_exit()
    finally:
        gate.set()
    assert "daemon-helper" not in caplog.text
