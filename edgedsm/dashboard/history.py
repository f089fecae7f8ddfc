"""Per-region activity, states, kinetics and alerts in SQLite, so curves survive a dashboard restart.

One writer thread owns the writing connection (WAL: readers never block it) and commits in
batches, at most every ``COMMIT_EVERY_S``; readers open their own short-lived connections.
Rows older than the retention are deleted hourly. Indexed by (device, region, t).
"""

from __future__ import annotations

import logging
import queue
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

COMMIT_EVERY_S = 0.5
PRUNE_EVERY_S = 3600.0
WARN_EVERY_S = 60.0  # a disk that refuses writes is logged at most this often
QUEUE_LIMIT = 100_000  # pending rows; beyond that new rows are dropped (and counted)
MAX_POINTS = 5000  # a history answer holds at most this many points (averaged into time buckets)

SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (
    device TEXT NOT NULL, region TEXT NOT NULL, t REAL NOT NULL, activity REAL, state TEXT,
    kinetics_tau_s REAL, kinetics_status TEXT, kinetics_bound_s REAL);
CREATE INDEX IF NOT EXISTS samples_by_region ON samples (device, region, t);
CREATE TABLE IF NOT EXISTS alerts (
    device TEXT NOT NULL, t REAL NOT NULL, kind TEXT NOT NULL, region TEXT, from_state TEXT, to_state TEXT,
    reason TEXT, activity REAL, stream TEXT, seq INTEGER);
CREATE INDEX IF NOT EXISTS alerts_by_device ON alerts (device, t);
CREATE UNIQUE INDEX IF NOT EXISTS alerts_identity ON alerts (device, stream, seq) WHERE seq IS NOT NULL;
"""
#: Columns a database written before the kinetics lacks (added in place: its history is kept).
KINETICS_COLUMNS = {"kinetics_tau_s": "REAL", "kinetics_status": "TEXT", "kinetics_bound_s": "REAL"}


@dataclass(frozen=True)
class Sample:
    device: str
    region: str
    t: float
    activity: float | None
    state: str | None
    # the region's kinetics ([kinetics] on): τ in s (status ok), its status, the bound of above/below;
    # the rate is 1/τ, not stored twice
    kinetics_tau_s: float | None = None
    kinetics_status: str | None = None
    kinetics_bound_s: float | None = None


@dataclass(frozen=True)
class AlertRow:
    device: str
    t: float
    kind: str
    region: str | None
    from_state: str | None
    to_state: str | None
    reason: str
    activity: float | None
    stream: str | None
    seq: int | None


class History:
    """The history database at ``path`` (created if missing), keeping ``retention_s`` seconds."""

    def __init__(self, path: Path, retention_s: float) -> None:
        self.path = Path(path)
        self.retention_s = retention_s
        self.dropped = 0
        self._last_warning = -WARN_EVERY_S
        self._queue: queue.Queue[Sample | AlertRow | None] = queue.Queue(QUEUE_LIMIT)
        self._flushed = threading.Condition()
        self._written = 0
        self._accepted = 0
        connection = self._connect()
        connection.executescript(SCHEMA)
        have = {row[1] for row in connection.execute("PRAGMA table_info(samples)")}
        for name, kind in KINETICS_COLUMNS.items():
            if name not in have:
                connection.execute(f"ALTER TABLE samples ADD COLUMN {name} {kind}")
        connection.commit()
        connection.close()
        self._thread = threading.Thread(target=self._write_loop, name="dashboard-history", daemon=True)
        self._thread.start()

    def _connect(self) -> sqlite3.Connection:
        connection = sqlite3.connect(self.path, timeout=10.0, check_same_thread=False)
        connection.execute("PRAGMA journal_mode=WAL")
        connection.execute("PRAGMA synchronous=NORMAL")  # WAL + NORMAL: durable across a crash of this process
        return connection

    def add(self, row: Sample | AlertRow) -> None:
        """Queue a row for writing (never blocks the MQTT thread)."""
        try:
            self._queue.put_nowait(row)
            self._accepted += 1
        except queue.Full:
            self.dropped += 1

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait until every row queued so far is committed."""
        target = self._accepted
        with self._flushed:
            return self._flushed.wait_for(lambda: self._written >= target, timeout_s)

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=10)

    def _write_loop(self) -> None:
        connection = self._connect()
        last_prune = 0.0
        stopping = False
        while not stopping:
            batch: list[Sample | AlertRow] = []
            deadline = time.monotonic() + COMMIT_EVERY_S
            while len(batch) < 5000:
                try:
                    item = self._queue.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    break
                if item is None:
                    stopping = True
                    break
                batch.append(item)
            if batch:
                self._write(connection, batch)
            if time.monotonic() - last_prune > PRUNE_EVERY_S:
                self.prune(connection)
                last_prune = time.monotonic()
        connection.close()

    def _write(self, connection: sqlite3.Connection, batch: list[Sample | AlertRow]) -> None:
        samples = [(r.device, r.region, r.t, r.activity, r.state, r.kinetics_tau_s, r.kinetics_status,
                    r.kinetics_bound_s) for r in batch if isinstance(r, Sample)]
        alerts = [(r.device, r.t, r.kind, r.region, r.from_state, r.to_state, r.reason, r.activity, r.stream, r.seq)
                  for r in batch if isinstance(r, AlertRow)]
        try:
            with connection:
                connection.executemany("INSERT INTO samples (device, region, t, activity, state, kinetics_tau_s, "
                                       "kinetics_status, kinetics_bound_s) VALUES (?, ?, ?, ?, ?, ?, ?, ?)", samples)
                connection.executemany("INSERT OR IGNORE INTO alerts VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", alerts)
        except sqlite3.Error as exc:  # a full disk must not stop the live view
            self.dropped += len(batch)
            if time.monotonic() - self._last_warning > WARN_EVERY_S:
                self._last_warning = time.monotonic()
                log.warning("history: rows not written (%d so far): %s", self.dropped, exc)
        with self._flushed:
            self._written += len(batch)
            self._flushed.notify_all()

    def prune(self, connection: sqlite3.Connection | None = None) -> None:
        """Delete rows older than the retention."""
        own = connection is None
        connection = connection or self._connect()
        cutoff = time.time() - self.retention_s
        try:
            with connection:
                connection.execute("DELETE FROM samples WHERE t < ?", (cutoff,))
                connection.execute("DELETE FROM alerts WHERE t < ?", (cutoff,))
        except sqlite3.Error as exc:
            log.warning("history: pruning failed: %s", exc)
        finally:
            if own:
                connection.close()

    def samples(self, device: str, region: str, start: float, end: float) -> list[tuple[float, float | None, str]]:
        """(t, activity, state) of one region in [start, end], at most ``MAX_POINTS`` (time-bucket means
        when there are more; the state is the bucket's last)."""
        connection = self._connect()
        try:
            where = "FROM samples WHERE device = ? AND region = ? AND t BETWEEN ? AND ?"
            rows = _downsampled(connection, where, (device, region, start, end), "activity, state",
                                "AVG(activity), state")
        finally:
            connection.close()
        return [(float(t), None if a is None else float(a), s or "") for t, a, s in rows]

    def kinetics(self, device: str, region: str, start: float,
                 end: float) -> list[tuple[float, float | None, str, float | None]]:
        """(t, τ in s, status, bound in s) of one region's kinetics in [start, end] (samples without
        any: none), at most ``MAX_POINTS``; when there are more, each time bucket's last reading (a
        mean of τ with a status that has none would be a number where there is none)."""
        connection = self._connect()
        try:
            where = ("FROM samples WHERE device = ? AND region = ? AND t BETWEEN ? AND ? "
                     "AND kinetics_status IS NOT NULL")
            columns = "kinetics_tau_s, kinetics_status, kinetics_bound_s"
            # bare columns per bucket: SQLite takes them from the row of MAX(t), the bucket's last reading
            rows = _downsampled(connection, where, (device, region, start, end), columns, columns)
        finally:
            connection.close()
        return [(float(t), None if tau is None else float(tau), str(status), None if bound is None else float(bound))
                for t, tau, status, bound in rows]

    def alerts(self, device: str, region: str | None, start: float, end: float,
               limit: int = 1000) -> list[dict[str, Any]]:
        """Alerts of a device (of one region and the whole device, when ``region`` is given), newest last."""
        connection = self._connect()
        try:
            sql = ("SELECT t, kind, region, from_state, to_state, reason, activity, stream, seq FROM alerts "
                   "WHERE device = ? AND t BETWEEN ? AND ?")
            args: tuple[Any, ...] = (device, start, end)
            if region is not None:
                sql += " AND (region = ? OR region IS NULL)"
                args += (region,)
            rows = connection.execute(sql + " ORDER BY t DESC LIMIT ?", (*args, limit)).fetchall()
        finally:
            connection.close()
        keys = ("t", "type", "region", "from", "to", "reason", "activity", "stream", "seq")
        return [dict(zip(keys, row, strict=True)) for row in reversed(rows)]


def _downsampled(connection: sqlite3.Connection, where: str, args: tuple[str, str, float, float], columns: str,
                 bucketed: str) -> list[tuple[Any, ...]]:
    """``SELECT t, columns where`` in time order (``args``: device, region, start, end), or, when more
    than ``MAX_POINTS`` rows match, one row per time bucket: ``MAX(t)`` and ``bucketed``."""
    (count,) = connection.execute(f"SELECT COUNT(*) {where}", args).fetchone()
    if count <= MAX_POINTS:
        return connection.execute(f"SELECT t, {columns} {where} ORDER BY t", args).fetchall()
    start, end = args[2], args[3]
    bucket = (end - start) / MAX_POINTS
    return connection.execute(
        f"SELECT MAX(t), {bucketed} {where} GROUP BY CAST((t - ?) / ? AS INTEGER) ORDER BY 1",
        (*args, start, bucket)).fetchall()
