"""Log lines of the daemon: plain (journald priorities when stderr is the journal) or JSON lines.

- When systemd connects stderr to the journal it sets ``JOURNAL_STREAM=<device>:<inode>`` of that
  stream; if it matches our stderr, every line starts with ``<N>`` (sd-daemon(3) priorities), so
  ``journalctl -p warning`` finds warnings, errors and transitions. A traceback's every line
  carries the prefix: journald reads each line as its own entry.
- ``json_lines``: one JSON object per record; an exception's traceback is kept under
  ``exception``; ``extra={"region": ..., "state": ...}`` fields are kept under their names.
"""

from __future__ import annotations

import json
import logging
import os
import sys

#: sd-daemon(3) priorities by logging level.
_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}
#: ``extra`` fields a record may carry into a JSON line (transitions name the region and state).
STRUCTURED_FIELDS = ("region", "state")


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


def configure_logging(level: str, json_lines: bool) -> None:
    """Route the root logger to stderr in the configured format (replacing earlier handlers)."""
    handler = logging.StreamHandler(sys.stderr)
    # journald adds its own timestamps; keep lines short
    plain = "%(levelname)s %(name)s: %(message)s"
    if json_lines:
        handler.setFormatter(JsonFormatter())
    elif stderr_is_journal():
        handler.setFormatter(JournalFormatter(plain))
    else:
        handler.setFormatter(logging.Formatter(plain))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
