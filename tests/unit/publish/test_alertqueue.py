"""Durable alert queue: survives reopening and kill -9, bounded, seq strictly increasing for ever."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from edgedsm.publish import AlertQueue, PublishError


def _alert(i: int) -> dict:
    return {"type": "transition", "region": "A", "from": "wet", "to": "drying", "activity": 0.1 * i, "t": i}


def test_put_assigns_seq_and_stream(tmp_path):
    with AlertQueue(tmp_path / "q.sqlite3") as queue:
        first, second = queue.put(_alert(1)), queue.put({**_alert(2), "seq": 999, "stream": "forged"})
        assert (first.seq, second.seq) == (1, 2)
        body = json.loads(second.payload)
        assert body["seq"] == 2 and body["stream"] == queue.stream and body["region"] == "A"
        assert len(queue) == 2 and queue.last_seq == 2


def test_pending_ack_and_persistence_across_reopen(tmp_path):
    path = tmp_path / "q.sqlite3"
    with AlertQueue(path) as queue:
        for i in range(5):
            queue.put(_alert(i))
        stream = queue.stream
        assert [a.seq for a in queue.pending(after_seq=2, limit=2)] == [3, 4]
        assert queue.ack(1) and queue.ack(3)
        assert not queue.ack(3)  # already acknowledged
    with AlertQueue(path) as queue:
        assert queue.stream == stream
        assert [a.seq for a in queue.pending()] == [2, 4, 5]
        assert json.loads(queue.pending()[0].payload)["activity"] == pytest.approx(0.1)


def test_seq_keeps_increasing_after_everything_was_acked_and_reopened(tmp_path):
    path = tmp_path / "q.sqlite3"
    with AlertQueue(path) as queue:
        for i in range(3):
            queue.ack(queue.put(_alert(i)).seq)
        assert len(queue) == 0
    with AlertQueue(path) as queue:
        assert queue.put(_alert(9)).seq == 4  # never reused, even with an empty table
        assert queue.last_seq == 4


def test_bound_drops_oldest_counts_and_warns(tmp_path, caplog):
    path = tmp_path / "q.sqlite3"
    with caplog.at_level(logging.WARNING, logger="edgedsm.publish.alertqueue"), AlertQueue(path, max_alerts=3) as queue:
        for i in range(5):
            queue.put(_alert(i))
        assert [a.seq for a in queue.pending()] == [3, 4, 5]
        assert queue.dropped == 2 and len(queue) == 3
    assert "dropped the 1 oldest" in caplog.text
    with AlertQueue(path, max_alerts=2) as queue:  # a smaller bound applies on reopening
        assert [a.seq for a in queue.pending()] == [4, 5]
        assert queue.dropped == 3


def test_refuses_what_cannot_be_json_or_is_huge(tmp_path):
    with AlertQueue(tmp_path / "q.sqlite3") as queue:
        with pytest.raises(PublishError, match="JSON"):
            queue.put({"when": object()})
        with pytest.raises(PublishError, match="limit"):
            queue.put({"blob": "x" * 70_000})
        assert len(queue) == 0 and queue.put(_alert(1)).seq == 1


def test_non_finite_values_become_null(tmp_path):
    with AlertQueue(tmp_path / "q.sqlite3") as queue:
        assert json.loads(queue.put({"activity": float("nan")}).payload)["activity"] is None


def test_unreadable_file_is_set_aside(tmp_path, caplog):
    path = tmp_path / "q.sqlite3"
    path.write_bytes(b"this is not an sqlite database at all" * 100)
    with caplog.at_level(logging.ERROR), AlertQueue(path) as queue:
        assert queue.put(_alert(1)).seq == 1
    assert list(tmp_path.glob("q.sqlite3.corrupt-*"))
    assert "moved aside" in caplog.text


WRITER = textwrap.dedent("""
    import sys
    from edgedsm.publish import AlertQueue
    queue = AlertQueue(sys.argv[1])
    i = 0
    while True:
        item = queue.put({"type": "test", "i": i})
        if i % 3 == 0:
            queue.ack(item.seq)
        print(item.seq, flush=True)   # printed only after put() returned: it must survive
        i += 1
""")


def test_kill_9_in_mid_write_loses_nothing_that_was_stored(tmp_path, repo):
    path = tmp_path / "q.sqlite3"
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(repo), os.environ.get("PYTHONPATH")]))}
    process = subprocess.Popen([sys.executable, str(script), str(path)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        seen: list[int] = []
        deadline = time.monotonic() + 30
        while len(seen) < 60 and time.monotonic() < deadline:
            line = process.stdout.readline()
            if not line:
                break
            seen.append(int(line))
        assert len(seen) >= 60, "writer did not get going"
        os.kill(process.pid, signal.SIGKILL)  # lands in the middle of some put() or ack()
    finally:
        process.kill()
        process.wait(timeout=10)
        process.stdout.close()
    with AlertQueue(path) as queue:
        stored = {a.seq: json.loads(a.payload) for a in queue.pending(limit=100_000)}
        acked = {seq for seq in seen if (seq - 1) % 3 == 0}
        for seq in seen:
            if seq not in acked:
                assert seq in stored, f"alert {seq} was stored before the kill but is gone"
                assert stored[seq]["i"] == seq - 1
        last = queue.last_seq
        assert last >= max(seen)
        assert queue.put({"type": "after"}).seq == last + 1
