"""sd_notify over a real unix datagram socket."""

from __future__ import annotations

import os
import socket

import pytest

from edgedsm.daemon.notify import Notifier


@pytest.fixture
def notify_socket(tmp_path):
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2.0)
    yield path, sock
    sock.close()


def test_messages_reach_the_socket(notify_socket, monkeypatch):
    path, sock = notify_socket
    monkeypatch.setenv("WATCHDOG_USEC", "4000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    notifier = Notifier(path)
    assert notifier.enabled and notifier.watchdog_s == 2.0
    assert notifier.ready(status="measuring")
    assert sock.recv(256) == b"READY=1\nSTATUS=measuring"
    notifier.status("12.0 frames/s; plate wet")
    assert sock.recv(256) == b"STATUS=12.0 frames/s; plate wet"
    notifier.watchdog()
    assert sock.recv(256) == b"WATCHDOG=1"
    notifier.stopping()
    assert sock.recv(256) == b"STOPPING=1"


def test_without_systemd_everything_is_a_no_op(monkeypatch):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    monkeypatch.delenv("WATCHDOG_USEC", raising=False)
    notifier = Notifier()
    assert not notifier.enabled and notifier.watchdog_s is None
    assert notifier.ready() is False and notifier.watchdog() is False


def test_watchdog_meant_for_another_process_is_ignored(monkeypatch, tmp_path):
    monkeypatch.setenv("WATCHDOG_USEC", "4000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid() + 1))
    assert Notifier(str(tmp_path / "x.sock")).watchdog_s is None


def test_a_vanished_socket_is_logged_not_raised(tmp_path, caplog):
    notifier = Notifier(str(tmp_path / "gone.sock"))
    assert notifier.status("x") is False
    assert "sd_notify" in caplog.text
