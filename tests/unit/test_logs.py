"""Daemon log lines: journald priorities when stderr is the journal, tracebacks kept in JSON mode."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from edgedsm.commands.run import configure_logging


class Stderr:
    """What the handler wrote to stderr (pytest's capture replaces sys.stderr per test)."""

    def __init__(self, capsys: pytest.CaptureFixture[str]) -> None:
        self.capsys = capsys

    def getvalue(self) -> str:
        return self.capsys.readouterr().err


@pytest.fixture
def stream(capsys: pytest.CaptureFixture[str]) -> Iterator[Stderr]:
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
    assert stream.getvalue() == "WARNING edgedsm.test: hello\n"
