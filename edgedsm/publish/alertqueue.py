"""Durable, bounded queue of alerts waiting for the broker's acknowledgement (PUBACK).

Storage is one SQLite file in the state directory (stdlib ``sqlite3``), chosen over a JSON-lines
log because SQLite's journal makes every ``put`` and ``ack`` atomic: a crash or power loss in
mid-write leaves either the old or the new state, never a torn record, with no recovery code of
ours. ``journal_mode=WAL`` with ``synchronous=FULL`` fsyncs every commit, so an alert whose
``put`` returned survives a kill -9 or a power cut.

Sequence numbers come from an ``AUTOINCREMENT`` key: strictly increasing for the life of the
file, never reused, even after the rows are acknowledged and deleted or the daemon restarts.
Each file also has a random ``stream`` id written into every alert; a subscriber deduplicates
on ``(stream, seq)`` (or ``seq`` alone while the state directory is kept), which stays correct
if the state directory is ever wiped and the numbering starts again.

When the queue holds ``max_alerts`` alerts (the broker unreachable for a long time), each new
alert drops the oldest one; drops are counted (persisted) and logged.

A file that SQLite cannot read (disk corruption) is renamed aside with a logged error and a new
queue is started, so the daemon keeps running and publishing new alerts. A disk that refuses
writes (full, read-only) is not corruption: it raises :class:`StorageError` with SQLite's own
words, and :class:`edgedsm.publish.alertstore.AlertStore` keeps alerts in memory meanwhile.
"""

from __future__ import annotations

import errno
import logging
import os
import sqlite3
import threading
import time
import uuid
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from edgedsm import _json
from edgedsm.publish.errors import PublishError, StorageError

log = logging.getLogger(__name__)

MAX_ALERT_BYTES = 64 * 1024  # an alert is a small event; anything bigger is a bug upstream

_SCHEMA = """
CREATE TABLE IF NOT EXISTS alerts (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    payload BLOB NOT NULL,
    created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


@dataclass(frozen=True)
class QueuedAlert:
    """One stored alert: its sequence number and the exact JSON bytes to publish."""

    seq: int
    payload: bytes


class AlertQueue:
    """Alerts stored durably until acknowledged. Thread-safe; every method returns quickly
    (one small SQLite transaction, fsync included)."""

    def __init__(self, path: str | Path, max_alerts: int = 10_000) -> None:
        if max_alerts < 1:
            raise ValueError(f"max_alerts must be >= 1, got {max_alerts}")
        self.path = Path(path)
        self.max_alerts = max_alerts
        self._lock = threading.Lock()
        try:
            if self.path.parent.exists() and not self.path.parent.is_dir():
                raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(self.path.parent))
            self.path.parent.mkdir(parents=True, exist_ok=True)
            _probe_writable(self.path.parent)  # SQLite would only say "unable to open database file"
            try:
                self._db = self._open()
            except sqlite3.OperationalError:
                raise  # cannot open, read-only, full: not the file's fault, keep it
            except sqlite3.DatabaseError as exc:
                self._set_aside(exc)
                self._db = self._open()
            self._stream = self._meta("stream") or self._init_stream()
            self._count = int(self._db.execute("SELECT COUNT(*) FROM alerts").fetchone()[0])
        except (sqlite3.Error, OSError) as exc:
            raise StorageError(f"{self.path}: {_cause(exc)}") from None
        self._trim()

    # -- public ---------------------------------------------------------------------------

    @property
    def stream(self) -> str:
        """Random id of this queue file, written into every alert as ``stream``."""
        return self._stream

    @property
    def dropped(self) -> int:
        """Alerts dropped because the bound was hit, over the life of the file."""
        with self._lock:
            return int(self._meta("dropped") or 0)

    @property
    def last_seq(self) -> int:
        """The highest sequence number ever given out (0 for a new queue)."""
        with self._lock:
            row = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'alerts'").fetchone()
            return int(row[0]) if row else 0

    def __len__(self) -> int:
        with self._lock:
            return self._count

    def encode(self, alert: Mapping[str, Any], seq: int) -> bytes:
        """The JSON to publish: ``alert`` with ``seq`` and this queue's ``stream`` (replacing any
        keys of those names). PublishError when it is not JSON or bigger than MAX_ALERT_BYTES."""
        body = {key: value for key, value in alert.items() if key not in ("seq", "stream")}
        try:
            payload = _json.dumps({**body, "seq": seq, "stream": self._stream})
        except (TypeError, ValueError) as exc:
            raise PublishError(f"alert cannot be written as JSON: {exc}") from None
        if len(payload) > MAX_ALERT_BYTES:
            raise PublishError(f"alert of {len(payload)} bytes exceeds the {MAX_ALERT_BYTES}-byte limit")
        return payload

    def put(self, alert: Mapping[str, Any]) -> QueuedAlert:
        """Store an alert durably and give it the next ``seq``; returns what to publish.

        Raises PublishError for an alert that is not JSON or too big, StorageError when the disk
        refuses it (full, read-only...); either way nothing was stored.
        """
        self.encode(alert, 0)  # refuse a bad alert before touching the file
        with self._lock:
            try:
                self._db.execute("BEGIN IMMEDIATE")
                try:
                    seq = int(self._db.execute("INSERT INTO alerts (payload, created) VALUES (x'', ?)",
                                               (time.time(),)).lastrowid)
                    payload = self.encode(alert, seq)
                    self._db.execute("UPDATE alerts SET payload = ? WHERE seq = ?", (payload, seq))
                    self._db.execute("COMMIT")
                except BaseException:
                    self._rollback()
                    raise
            except sqlite3.Error as exc:
                raise StorageError(f"{self.path}: alert could not be stored durably: {_cause(exc)}") from None
            self._count += 1
            self._trim()
        return QueuedAlert(seq, payload)

    def restore(self, items: list[QueuedAlert], last_seq: int) -> None:
        """Store alerts numbered elsewhere (kept in memory while the disk refused writes), in one
        transaction, and move the numbering past ``last_seq`` so no seq is ever given twice.
        StorageError (nothing stored) when the disk still refuses."""
        with self._lock:
            try:
                self._db.execute("BEGIN IMMEDIATE")
                try:
                    now = time.time()
                    self._db.executemany("INSERT OR REPLACE INTO alerts (seq, payload, created) VALUES (?, ?, ?)",
                                         [(item.seq, item.payload, now) for item in items])
                    if self._db.execute("SELECT 1 FROM sqlite_sequence WHERE name = 'alerts'").fetchone():
                        self._db.execute("UPDATE sqlite_sequence SET seq = MAX(seq, ?) WHERE name = 'alerts'",
                                         (last_seq,))
                    else:
                        self._db.execute("INSERT INTO sqlite_sequence (name, seq) VALUES ('alerts', ?)", (last_seq,))
                    self._db.execute("COMMIT")
                except BaseException:
                    self._rollback()
                    raise
            except sqlite3.Error as exc:
                raise StorageError(f"{self.path}: alerts could not be written back: {_cause(exc)}") from None
            self._count = int(self._db.execute("SELECT COUNT(*) FROM alerts").fetchone()[0])
            self._trim()

    def pending(self, after_seq: int = 0, limit: int = 100) -> list[QueuedAlert]:
        """Unacknowledged alerts with ``seq > after_seq``, oldest first, at most ``limit``."""
        with self._lock:
            rows = self._db.execute("SELECT seq, payload FROM alerts WHERE seq > ? ORDER BY seq LIMIT ?",
                                    (after_seq, limit)).fetchall()
        return [QueuedAlert(int(seq), bytes(payload)) for seq, payload in rows]

    def ack(self, seq: int) -> bool:
        """Remove an acknowledged alert; False when it was not there (already acked or dropped).
        StorageError when the disk refuses (the alert stays and would be sent once more)."""
        with self._lock:
            try:
                removed = self._db.execute("DELETE FROM alerts WHERE seq = ?", (seq,)).rowcount
            except sqlite3.Error as exc:
                self._rollback()
                raise StorageError(f"{self.path}: acknowledged alert {seq} could not be removed: "
                                   f"{_cause(exc)}") from None
            self._count -= removed
            return removed > 0

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> AlertQueue:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- private --------------------------------------------------------------------------

    def _open(self) -> sqlite3.Connection:
        # isolation_level=None: we write BEGIN/COMMIT ourselves; check_same_thread=False: the
        # pipeline thread puts, the MQTT worker acks, our lock serialises them.
        db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False, timeout=5.0)
        try:
            # Exclusive: one daemon per queue file, and WAL then keeps its index in memory instead
            # of a -shm file, which a full disk cannot create (the reopen failed with "disk I/O error").
            db.execute("PRAGMA locking_mode=EXCLUSIVE")
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=FULL")
            db.executescript(_SCHEMA)
            if db.execute("PRAGMA quick_check").fetchone()[0] != "ok":
                raise sqlite3.DatabaseError("integrity check failed")
        except sqlite3.DatabaseError:
            db.close()
            raise
        return db

    def _rollback(self) -> None:
        # SQLite has already rolled back after some errors (SQLITE_FULL): a second ROLLBACK would
        # replace the real cause with "cannot rollback - no transaction is active".
        if self._db.in_transaction:
            try:
                self._db.execute("ROLLBACK")
            except sqlite3.Error as exc:
                log.error("%s: rollback failed: %s", self.path, exc)

    def _set_aside(self, exc: sqlite3.DatabaseError) -> None:
        stamp = time.strftime("%Y%m%dT%H%M%S")
        for suffix in ("", "-wal", "-shm"):
            source = Path(f"{self.path}{suffix}")
            if source.exists():
                source.replace(Path(f"{self.path}.corrupt-{stamp}{suffix}"))
        log.error("%s: alert queue unreadable (%s); moved aside as %s.corrupt-%s and started a new "
                  "queue: unacknowledged alerts in it are lost", self.path, exc, self.path.name, stamp)

    def _meta(self, key: str) -> str | None:
        row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def _init_stream(self) -> str:
        stream = uuid.uuid4().hex[:16]
        self._db.execute("INSERT OR IGNORE INTO meta (key, value) VALUES ('stream', ?)", (stream,))
        return self._meta("stream") or stream

    def _trim(self) -> None:
        """Drop the oldest alerts beyond the bound (caller holds the lock or is __init__)."""
        excess = self._count - self.max_alerts
        if excess <= 0:
            return
        try:
            self._db.execute("BEGIN IMMEDIATE")
            removed = self._db.execute(
                "DELETE FROM alerts WHERE seq IN (SELECT seq FROM alerts ORDER BY seq LIMIT ?)",
                (excess,)).rowcount
            total = int(self._meta("dropped") or 0) + removed
            self._db.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('dropped', ?)", (str(total),))
            self._db.execute("COMMIT")
        except sqlite3.Error as exc:
            self._rollback()
            log.error("%s: could not drop old alerts beyond the bound: %s", self.path, _cause(exc))
            return
        self._count -= removed
        log.warning("alert queue full (%d unacknowledged): dropped the %d oldest alert(s); %d dropped "
                    "so far. Is the broker reachable?", self.max_alerts, removed, total)


def _probe_writable(directory: Path) -> None:
    """OSError (read-only file system, permission denied...) unless a file can be created in
    ``directory``; an empty file needs no space, so a full disk passes (and degrades later)."""
    probe = directory / f".edgedsm-probe-{uuid.uuid4().hex[:8]}"
    os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
    probe.unlink()


def _cause(exc: BaseException) -> str:
    """SQLite's or the OS's own words, e.g. 'database or disk is full'."""
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.strerror}" + (f": {exc.filename}" if exc.filename else "")
    return str(exc) or type(exc).__name__
