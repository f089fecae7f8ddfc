"""Log lines of the daemon: plain (journald priorities when stderr is the journal) or JSON lines.

- When systemd connects stderr to the journal it sets ``JOURNAL_STREAM=<device>:<inode>`` of that
  stream; if it matches our stderr, records go to the journal's native socket
  (systemd.journal-fields(7)): ``PRIORITY``, ``MESSAGE`` (a traceback kept in the same entry),
  ``LOGGER``, ``CODE_*`` and, on transitions, ``REGION`` and ``STATE`` (``journalctl
  REGION=panel``). A record the socket refuses, or no socket, falls back to stderr lines that
  start with ``<N>`` (sd-daemon(3) priorities), every line of a traceback included, so
  ``journalctl -p warning`` finds warnings, errors and transitions either way.
- ``json_lines``: one JSON object per record; an exception's traceback is kept under
  ``exception``; ``extra={"region": ..., "state": ...}`` fields are kept under their names.
- Anywhere else (a terminal, a file, a pipe): ``2026-12-05 17:03:12.345 WARNING logger: message``,
  the local time to the millisecond first (the journal adds its own, so its lines stay short).
"""

from __future__ import annotations

import json
import logging
import os
import socket
import struct
import sys

#: sd-daemon(3) priorities by logging level.
_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}
#: ``extra`` fields a record may carry into a JSON line or a journal entry (transitions name the
#: region and the state entered).
STRUCTURED_FIELDS = ("region", "state")
#: journald's native protocol socket (systemd.journal-fields(7), sd_journal_sendv(3)).
JOURNAL_SOCKET = "/run/systemd/journal/socket"


def priority(levelno: int) -> int:
    """The sd-daemon priority of a logging level (levels in between take the next more severe)."""
    for level in sorted(_PRIORITY, reverse=True):
        if levelno >= level:
            return _PRIORITY[level]
    return 7


def stderr_identity() -> str | None:
    """``<device>:<inode>`` of stderr, as systemd writes it in ``JOURNAL_STREAM``."""
    try:
        info = os.fstat(sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):
        return None
    return f"{info.st_dev}:{info.st_ino}"


def stderr_is_journal() -> bool:
    expected = os.environ.get("JOURNAL_STREAM")
    return bool(expected) and expected == stderr_identity()


class JournalFormatter(logging.Formatter):
    """``<N>LEVEL logger: message``, the prefix on every line (tracebacks included)."""

    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{priority(record.levelno)}>"
        return "\n".join(prefix + line for line in super().format(record).splitlines())


#: A log line outside the journal: local time to the millisecond, level, logger, message.
TIMESTAMPED = "%(asctime)s %(levelname)s %(name)s: %(message)s"


class TimestampFormatter(logging.Formatter):
    """``%(asctime)s`` as ``2026-12-05 17:03:12.345`` (logging's default has a comma)."""

    default_msec_format = "%s.%03d"


class JsonFormatter(logging.Formatter):
    """One JSON object per record: t, level, logger, message, [exception], [region, state]."""

    def format(self, record: logging.LogRecord) -> str:
        line = {"t": record.created, "level": record.levelname.lower(), "logger": record.name,
                "message": record.getMessage()}
        for name in STRUCTURED_FIELDS:
            if hasattr(record, name):
                line[name] = getattr(record, name)
        if record.exc_info:
            line["exception"] = self.formatException(record.exc_info)
        elif record.exc_text:
            line["exception"] = record.exc_text
        if record.stack_info:
            line["stack"] = record.stack_info
        return json.dumps(line, default=str)


def journal_field(name: str, value: object) -> bytes:
    """One field of the native protocol: ``NAME=value\\n``, or the length-prefixed form for a
    value with a newline (a traceback)."""
    data = str(value).encode("utf-8", "replace")
    if b"\n" not in data:
        return name.encode() + b"=" + data + b"\n"
    return name.encode() + b"\n" + struct.pack("<Q", len(data)) + data + b"\n"


class JournalHandler(logging.Handler):
    """Sends each record to journald as one entry with fields; ``fallback`` takes it when the
    socket refuses (too large, journald restarting)."""

    def __init__(self, path: str, fallback: logging.Handler, identifier: str = "edgedsm") -> None:
        super().__init__()
        self.path = path
        self.fallback = fallback
        self.identifier = identifier
        self.socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)

    def entry(self, record: logging.LogRecord) -> bytes:
        message = record.getMessage()
        if record.exc_info:
            message += "\n" + logging.Formatter().formatException(record.exc_info)
        fields = [journal_field("MESSAGE", message), journal_field("PRIORITY", priority(record.levelno)),
                  journal_field("SYSLOG_IDENTIFIER", self.identifier), journal_field("LOGGER", record.name),
                  journal_field("CODE_FILE", record.pathname), journal_field("CODE_LINE", record.lineno),
                  journal_field("CODE_FUNC", record.funcName)]
        fields += [journal_field(name.upper(), getattr(record, name)) for name in STRUCTURED_FIELDS
                   if hasattr(record, name)]
        return b"".join(fields)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.socket.sendto(self.entry(record), self.path)
        except OSError:
            self.fallback.handle(record)
        except Exception:
            self.handleError(record)

    def close(self) -> None:
        self.socket.close()
        super().close()


def configure_logging(level: str, json_lines: bool) -> None:
    """Route the root logger to stderr in the configured format (replacing earlier handlers)."""
    handler: logging.Handler = logging.StreamHandler(sys.stderr)
    # journald adds its own timestamps; keep lines short
    plain = "%(levelname)s %(name)s: %(message)s"
    if json_lines:
        handler.setFormatter(JsonFormatter())
    elif stderr_is_journal():
        handler.setFormatter(JournalFormatter(plain))
        if os.path.exists(JOURNAL_SOCKET):
            handler = JournalHandler(JOURNAL_SOCKET, fallback=handler)
    else:
        handler.setFormatter(TimestampFormatter(TIMESTAMPED))
    root = logging.getLogger()
    for old in root.handlers:
        if isinstance(old, JournalHandler):
            old.close()  # its socket
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
