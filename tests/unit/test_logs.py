"""Daemon log lines: journald priorities when stderr is the journal, tracebacks kept in JSON mode."""

from __future__ import annotations

import json
import logging
import os
import re
import socket
import struct
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path

import pytest

from edgedsm.commands.run import configure_logging
from edgedsm.logs import JournalHandler


class Stderr:
    """What the handler wrote to stderr (pytest's capture replaces sys.stderr per test)."""

    def __init__(self, capsys: pytest.CaptureFixture[str]) -> None:
        self.capsys = capsys

    def getvalue(self) -> str:
        return self.capsys.readouterr().err


@pytest.fixture
def stream(capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Stderr]:
    monkeypatch.setattr("edgedsm.logs.JOURNAL_SOCKET", str(tmp_path / "no-journal-here"))
    yield Stderr(capsys)
    logging.getLogger().handlers.clear()


def _journal_stream_of(path: Path) -> str:
    info = os.stat(path)
    return f"{info.st_dev}:{info.st_ino}"


def test_json_lines_keep_the_traceback_of_an_exception(stream: Stderr) -> None:
    configure_logging("info", json_lines=True)
    try:
        raise RuntimeError("boom")
    except RuntimeError:
        logging.getLogger("edgedsm.test").exception("evaluation failed")
    record = json.loads(stream.getvalue().strip())
    assert record["message"] == "evaluation failed"
    assert record["level"] == "error"
    assert "Traceback (most recent call last)" in record["exception"]
    assert "RuntimeError: boom" in record["exception"]


def test_json_lines_carry_region_and_state_given_as_extras(stream: Stderr) -> None:
    configure_logging("info", json_lines=True)
    logging.getLogger("edgedsm.test").warning("region panel: wet -> drying", extra={"region": "panel",
                                                                                    "state": "drying"})
    record = json.loads(stream.getvalue().strip())
    assert (record["region"], record["state"]) == ("panel", "drying")


@pytest.mark.parametrize(("level", "prefix"), [(logging.DEBUG, "<7>"), (logging.INFO, "<6>"),
                                               (logging.WARNING, "<4>"), (logging.ERROR, "<3>"),
                                               (logging.CRITICAL, "<2>")])
def test_priority_prefixes_when_stderr_is_the_journal(stream: Stderr, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch, level: int,
                                                      prefix: str) -> None:
    stderr_file = tmp_path / "stderr"
    stderr_file.write_text("")
    monkeypatch.setenv("JOURNAL_STREAM", _journal_stream_of(stderr_file))
    monkeypatch.setattr("edgedsm.logs.stderr_identity", lambda: _journal_stream_of(stderr_file))
    configure_logging("debug", json_lines=False)
    logging.getLogger("edgedsm.test").log(level, "hello")
    assert stream.getvalue() == f"{prefix}{logging.getLevelName(level)} edgedsm.test: hello\n"


def test_every_line_of_a_traceback_carries_the_priority_in_the_journal(stream: Stderr, tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    identity = "8:42"
    monkeypatch.setenv("JOURNAL_STREAM", identity)
    monkeypatch.setattr("edgedsm.logs.stderr_identity", lambda: identity)
    configure_logging("info", json_lines=False)
    try:
        raise ValueError("bad")
    except ValueError:
        logging.getLogger("edgedsm.test").exception("failed")
    lines = stream.getvalue().splitlines()
    assert len(lines) >= 4
    assert all(line.startswith("<3>") for line in lines)
    assert lines[-1] == "<3>ValueError: bad"


@pytest.mark.parametrize("journal_stream", [None, "1:2", "garbage"])
def test_no_prefix_when_stderr_is_not_the_journal(stream: Stderr, monkeypatch: pytest.MonkeyPatch,
                                                  journal_stream: str | None) -> None:
    if journal_stream is None:
        monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    else:
        monkeypatch.setenv("JOURNAL_STREAM", journal_stream)
    monkeypatch.setattr("edgedsm.logs.stderr_identity", lambda: "8:42")
    configure_logging("info", json_lines=False)
    logging.getLogger("edgedsm.test").warning("hello")
    # a terminal (or a file) gets the time of each line; the journal adds its own
    line = stream.getvalue()
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3} WARNING edgedsm.test: hello\n", line), line
    stamp = datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S.%f")
    assert abs((datetime.now() - stamp).total_seconds()) < 60


def _fields(datagram: bytes) -> dict[str, str]:
    """Parse the journal's native protocol (both field forms)."""
    fields: dict[str, str] = {}
    rest = datagram
    while rest:
        line, _, after = rest.partition(b"\n")
        if b"=" in line:
            name, _, value = line.partition(b"=")
            fields[name.decode()] = value.decode()
            rest = after
        else:
            size = struct.unpack("<Q", after[:8])[0]
            fields[line.decode()] = after[8:8 + size].decode()
            rest = after[8 + size + 1:]
    return fields


@pytest.fixture
def journal(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[socket.socket]:
    path = tmp_path / "journal.socket"
    receiver = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    receiver.bind(str(path))
    receiver.settimeout(5)
    monkeypatch.setattr("edgedsm.logs.JOURNAL_SOCKET", str(path))
    monkeypatch.setenv("JOURNAL_STREAM", "8:42")
    monkeypatch.setattr("edgedsm.logs.stderr_identity", lambda: "8:42")
    yield receiver
    receiver.close()
    for handler in logging.getLogger().handlers:
        if isinstance(handler, JournalHandler):
            handler.close()
    logging.getLogger().handlers.clear()


def test_the_journal_gets_one_entry_with_priority_region_and_state(journal: socket.socket) -> None:
    configure_logging("info", json_lines=False)
    logging.getLogger("edgedsm.daemon.evaluator").warning("region %s: wet -> drying", "panel",
                                                           extra={"region": "panel", "state": "drying"})
    fields = _fields(journal.recv(65536))
    assert fields["MESSAGE"] == "region panel: wet -> drying"
    assert (fields["PRIORITY"], fields["REGION"], fields["STATE"]) == ("4", "panel", "drying")
    assert fields["LOGGER"] == "edgedsm.daemon.evaluator" and fields["SYSLOG_IDENTIFIER"] == "edgedsm"


def test_a_traceback_stays_in_its_journal_entry(journal: socket.socket) -> None:
    configure_logging("info", json_lines=False)
    try:
        raise KeyError("lost")
    except KeyError:
        logging.getLogger("edgedsm.test").exception("failed")
    fields = _fields(journal.recv(65536))
    assert fields["PRIORITY"] == "3"
    assert fields["MESSAGE"].startswith("failed\nTraceback (most recent call last)")
    assert fields["MESSAGE"].endswith("KeyError: 'lost'")


def test_a_journal_that_refuses_falls_back_to_prefixed_stderr(journal: socket.socket,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    configure_logging("info", json_lines=False)
    journal.close()  # the path is still there, nobody reads: sendto fails
    logging.getLogger("edgedsm.test").error("still logged")
    assert capsys.readouterr().err == "<3>ERROR edgedsm.test: still logged\n"
