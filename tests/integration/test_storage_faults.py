"""The state directory failing under the MQTT sink: a real full tmpfs, a real read-only mount.

Each test mounts its own small tmpfs (root here; skipped with the reason when mount is refused)
and unmounts it in the fixture's finalizer. Alerts go through a real mosquitto and are read
back as typed messages, deduplicated on (stream, seq).
"""

from __future__ import annotations

import errno
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers_mqtt import WAIT_S, wait_until

from edgedsm.errors import ConfigError
from edgedsm.messages import Alert, AlertKind, Stats
from edgedsm.publish import AlertQueue, AlertStore, MqttSettings, MqttSink, StorageError, Topics
from edgedsm.publish.counters import Counters

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]

TOPICS = Topics.of("edgedsm", "cam0")


def _mount(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["mount", *args], capture_output=True, text=True, timeout=30)


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Callable[..., Path]]:
    """Mount small tmpfs file systems (``options`` as for ``mount -o``); all unmounted after."""
    mounted: list[Path] = []

    def make(options: str = "size=512k") -> Path:
        point = tmp_path / f"tmpfs{len(mounted)}"
        point.mkdir()
        result = _mount("-t", "tmpfs", "-o", options, "tmpfs", str(point))
        if result.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here (needs root or CAP_SYS_ADMIN): {result.stderr.strip()}")
        mounted.append(point)
        return point

    yield make
    for point in reversed(mounted):
        subprocess.run(["umount", "-l", str(point)], capture_output=True, timeout=30)


def _fill(directory: Path) -> Path:
    """Write a file until the file system says it is full."""
    filler = directory / "filler"
    with open(filler, "wb", buffering=0) as out:
        try:
            while True:
                out.write(b"\0" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC, exc
    return filler


def _settings(port: int) -> MqttSettings:
    return MqttSettings.model_validate({"host": "127.0.0.1", "port": port, "device": "cam0", "keepalive_s": 5,
                                        "reconnect_min_s": 0.05, "reconnect_max_s": 0.3,
                                        "connect_timeout_s": 2.0, "shutdown_timeout_s": 1.0})


def _alert(reason: str) -> Alert:
    return Alert(kind=AlertKind.TRANSITION, t=time.time(), region="A", from_state="wet", to_state="drying",
                 reason=reason)


def _received(subscriber: Any) -> dict[int, Alert]:
    alerts = [Alert.model_validate_json(m.payload) for m in subscriber.on(TOPICS.alerts)]
    assert len({a.stream for a in alerts}) <= 1
    return {a.seq: a for a in alerts if a.seq is not None}


def _stats(sink: MqttSink, subscriber: Any) -> dict[str, Any]:
    before = len(subscriber.on(TOPICS.stats))
    sink.publish_stats(Stats(t=time.time(), frames=1, ready=True, fps=30.0, laser="on", estimator="s2"))
    wait_until(lambda: len(subscriber.on(TOPICS.stats)) > before, WAIT_S, "stats")
    mqtt = Stats.model_validate_json(subscriber.on(TOPICS.stats)[-1].payload).mqtt
    assert mqtt is not None
    return mqtt


def test_full_disk_reports_the_real_cause(tmpfs):
    """The issue's first symptom: 'cannot rollback - no transaction is active' hid the cause."""
    state = tmpfs()
    with AlertQueue(state / "q.sqlite3") as queue:
        assert queue.put({"type": "fault"}).seq == 1
        _fill(state)
        with pytest.raises(StorageError, match="database or disk is full") as error:
            for i in range(50):  # SQLite's page cache absorbs a few before a write reaches the disk
                queue.put({"type": "fault", "reason": "x" * 2000, "i": i})
        assert "cannot rollback" not in str(error.value)


def test_memory_is_bounded_and_the_numbering_survives_write_back(tmpfs):
    state = tmpfs()
    counters = Counters()
    now = [0.0]
    store = AlertStore(AlertQueue(state / "q.sqlite3"), counters, memory_max=5, retry_s=1.0, clock=lambda: now[0])
    assert store.put({"type": "transition", "n": 0}).seq == 1
    filler = _fill(state)
    seqs = [store.put({"type": "transition", "n": n, "pad": "x" * 2000}).seq for n in range(1, 40)]
    assert store.fault is not None and "disk is full" in store.fault
    assert seqs == sorted(seqs) and len(set(seqs)) == 39
    on_disk = len(store.queue)  # 1, or a few more if the page cache took some before the disk refused
    held = store.pending(limit=1000)[on_disk:]
    assert len(held) == 5 == store.in_memory  # the oldest were dropped, counted
    assert counters.snapshot()["alerts_memory_dropped"] == seqs[-1] - on_disk - 5
    assert counters.snapshot()["storage_faults"] == 1
    assert not store.retry()  # not yet time, and still full
    filler.unlink()
    assert not store.retry()  # space is back, but the retry waits for its interval
    now[0] = 1.0
    assert store.retry() and store.fault is None and store.in_memory == 0
    assert [item.seq for item in store.pending(after_seq=0, limit=1000)][-5:] == [item.seq for item in held]
    assert store.put({"type": "after"}).seq == seqs[-1] + 1  # on disk, numbering moved past memory
    store.queue.close()
    with AlertQueue(state / "q.sqlite3") as reopened:
        assert reopened.last_seq == seqs[-1] + 1 and len(reopened) == on_disk + 5 + 1


def test_full_then_freed_state_dir_loses_no_alert(tmpfs, make_broker, subscribers):
    broker = make_broker()
    state = tmpfs() / "state"
    subscriber = subscribers(broker.port, [TOPICS.alerts, TOPICS.stats])
    sink = MqttSink(_settings(broker.port), state).start()
    try:
        sink.wait_connected(WAIT_S)
        assert sink.publish_alert(_alert("before")) == 1
        assert sink.flush_alerts(WAIT_S)

        filler = _fill(state.parent)
        seqs = [sink.publish_alert(_alert(f"full {i}")) for i in range(20)]  # never raises
        wait_until(lambda: len(_received(subscriber)) >= 22, WAIT_S, "the alerts and the storage fault")
        received = _received(subscriber)
        fault = [a for a in received.values() if a.kind == AlertKind.FAULT]
        assert len(fault) == 1 and fault[0].reason.startswith("storage: ")
        assert "database or disk is full" in fault[0].reason
        assert sorted(received) == list(range(1, 23)) and seqs == sorted(seqs) and seqs[-1] == 22
        mqtt = _stats(sink, subscriber)
        assert mqtt["storage_faults"] == 1 and "disk is full" in mqtt["storage_error"]

        broker.stop()  # now the memory-held alerts cannot be acknowledged either
        waiting = [sink.publish_alert(_alert(f"offline {i}")) for i in range(3)]
        assert waiting == [23, 24, 25]
        filler.unlink()  # space returns: the store writes them back
        wait_until(lambda: sink.counters()["storage_error"] is None, WAIT_S, "the store to use the disk again")
        assert sink.counters()["alerts_in_memory"] == 0
    finally:
        sink.close(2.0)

    with AlertQueue(state / "mqtt-alerts-cam0.sqlite3") as queue:  # what a restart finds
        assert [item.seq for item in queue.pending()] == [23, 24, 25]
        assert queue.last_seq == 25

    broker.start()
    later = subscribers(broker.port, [TOPICS.alerts])  # subscribed before the daemon comes back
    restarted = MqttSink(_settings(broker.port), state).start()
    try:
        restarted.wait_connected(WAIT_S)
        assert restarted.publish_alert(_alert("after")) == 26  # no seq given twice
        assert restarted.flush_alerts(WAIT_S)
        wait_until(lambda: len(_received(later)) >= 4, WAIT_S, "every alert after the restart")
        received = _received(later)
        assert sorted(received) == [23, 24, 25, 26]
        assert sorted({**_received(subscriber), **received}) == list(range(1, 27))  # none lost
        assert [received[seq].reason for seq in (23, 24, 25, 26)] == ["offline 0", "offline 1", "offline 2",
                                                                      "after"]
    finally:
        restarted.close(2.0)


def test_restart_on_a_full_disk_degrades(tmpfs, make_broker, subscribers):
    """The issue's third symptom: the daemon crashed again after a restart on the full disk."""
    broker = make_broker()
    state = tmpfs() / "state"
    first = MqttSink(_settings(broker.port), state).start()
    try:
        first.wait_connected(WAIT_S)
        assert first.publish_alert(_alert("before")) == 1
        assert first.flush_alerts(WAIT_S)
    finally:
        first.close(2.0)
    _fill(state.parent)
    subscriber = subscribers(broker.port, [TOPICS.alerts])
    second = MqttSink(_settings(broker.port), state).start()  # opens on the full disk
    try:
        second.wait_connected(WAIT_S)
        seqs = [second.publish_alert(_alert(f"full {i}")) for i in range(20)]
        assert seqs == list(range(3, 23))  # 2 is the storage fault, raised by the first refusal
        wait_until(lambda: len(_received(subscriber)) >= 21, WAIT_S, "the alerts and the storage fault")
        received = _received(subscriber)
        assert sorted(received) == list(range(2, 23))
        assert [a.reason.split(":")[0] for a in received.values() if a.kind == AlertKind.FAULT] == ["storage"]
    finally:
        second.close(2.0)


# A mount cannot be made read-only under an open database (EBUSY), so "read-only" is tested
# where it happens in practice: at start (a full disk mid-run is the test above).
def test_unusable_state_dir_at_start_is_a_config_error(tmpfs):
    read_only = tmpfs("size=64k,ro")
    with pytest.raises(ConfigError, match=r"device\.state_dir: .*tmpfs0/state.*Read-only file system"):
        MqttSink(_settings(1883), read_only / "state")
    existing = tmpfs("size=512k")
    AlertQueue(existing / "state" / "mqtt-alerts-cam0.sqlite3").close()
    assert _mount("-o", "remount,ro", str(existing)).returncode == 0
    with pytest.raises(ConfigError, match=r"device\.state_dir: .*tmpfs1/state.*Read-only file system"):
        MqttSink(_settings(1883), existing / "state")
    not_a_dir = existing / "state" / "mqtt-alerts-cam0.sqlite3"
    with pytest.raises(ConfigError, match=r"device\.state_dir: .*Not a directory"):
        MqttSink(_settings(1883), not_a_dir)
