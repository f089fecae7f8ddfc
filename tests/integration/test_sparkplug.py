"""The Sparkplug B edge node against a REAL mosquitto, its messages decoded by an independent
wire reader (tests/sparkplug_decoder.py), each spec rule checked by name (the tck-id list in
docs/sparkplug.md). The sink runs in-process where a test feeds it messages, in a child process
where the broker must deliver its will after a SIGKILL, and inside `edgedsm run` end to end."""

from __future__ import annotations

import itertools
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers_mqtt import WAIT_S, Broker, child_env, wait_until
from helpers_sparkplug import SparkplugHost, SpMessage
from sparkplug_decoder import DATATYPES, command

from edgedsm.estimators import ESTIMATORS
from edgedsm.messages import MapStats, RegionState, StateReport, Stats
from edgedsm.publish.settings import MqttSettings
from edgedsm.publish.sparkplug.node import SparkplugSink
from edgedsm.publish.sparkplug.session import BDSEQ_FILE
from edgedsm.publish.sparkplug.settings import SparkplugSettings

pytestmark = [pytest.mark.integration]

GROUP, NODE, DEVICE = "line1", "cam-a", "camera"
NBIRTH = f"spBv1.0/{GROUP}/NBIRTH/{NODE}"
NCMD = f"spBv1.0/{GROUP}/NCMD/{NODE}"
DBIRTH = f"spBv1.0/{GROUP}/DBIRTH/{NODE}/{DEVICE}"
REBIRTH = "Node Control/Rebirth"


def mqtt_settings(port: int, **overrides: Any) -> MqttSettings:
    return MqttSettings(host="127.0.0.1", port=port, device=NODE, keepalive_s=5, connect_timeout_s=2.0,
                        reconnect_min_s=0.1, reconnect_max_s=0.5, **overrides)


def stats(frames: int, *, fps: float = 20.0, s2: float = 0.4, drops: dict[str, int] | None = None,
          t: float | None = None) -> Stats:
    region = {name: MapStats(pixels=100, mean=value, std=0.0, p05=value, median=value, p95=value)
              for name, value in (("s1", 12.0), ("s2", s2), ("s3", 0.8))}
    return Stats(t=time.time() if t is None else t, frames=frames, ready=True, fps=fps, laser="on",
                 estimator="s2", drops=drops or {}, regions={"plate": region}, state={"plate": "wet"})


def report(state: str = "wet", activity: float = 0.4) -> StateReport:
    now = time.time()
    region = RegionState(region="plate", state=state, since=now - 5, activity=activity, time_to_dry_s=None)
    return StateReport(t=now, estimator="s2", laser="on", regions={"plate": region})


@pytest.fixture
def host(broker: Broker) -> Iterator[SparkplugHost]:
    made = SparkplugHost(broker.port).start()
    yield made
    made.stop()


@pytest.fixture
def make_node(broker: Broker, tmp_path: Path) -> Iterator[Callable[..., SparkplugSink]]:
    nodes: list[SparkplugSink] = []

    def make(protocol: str = "5", **settings: Any) -> SparkplugSink:
        config = SparkplugSettings(group_id=GROUP, edge_node_id=NODE, device_id=DEVICE, **settings)
        node = SparkplugSink(config, mqtt_settings(broker.port, protocol=protocol), tmp_path / "state",
                             regions=["plate"], maps=ESTIMATORS, password=None)
        nodes.append(node)
        return node.start()

    yield make
    for node in nodes:
        node.close(2.0)


def births(host: SparkplugHost, count: int = 1) -> tuple[SpMessage, SpMessage]:
    nbirth = host.wait_for("NBIRTH", f"{count} NBIRTH", count=count)[count - 1]
    dbirth = host.wait_for("DBIRTH", f"{count} DBIRTH", count=count)[count - 1]
    return nbirth, dbirth


def bdseq_of(message: SpMessage) -> int:
    metric = message.payload.by_name()["bdSeq"]
    assert metric.datatype_name == "Int64"
    return metric.value()


def test_births_carry_every_metric_with_name_alias_datatype_and_bdseq(make_node, host: SparkplugHost) -> None:
    before_ms = int(time.time() * 1000)
    make_node()
    nbirth, dbirth = births(host)
    after_ms = int(time.time() * 1000)
    # tck-id-topics-nbirth-topic, tck-id-topics-dbirth-topic
    assert (nbirth.topic, dbirth.topic) == (NBIRTH, DBIRTH)
    # tck-id-topics-nbirth-mqtt, tck-id-topics-dbirth-mqtt: QoS 0, not retained
    assert [(m.qos, m.retain) for m in (nbirth, dbirth)] == [(0, False), (0, False)]
    node, device = nbirth.payload, dbirth.payload
    # tck-id-topics-nbirth-seq-num (0), tck-id-topics-dbirth-seq (one more)
    assert (node.seq, device.seq) == (0, 1)
    # tck-id-topics-nbirth-timestamp, tck-id-payloads-timestamp-in-UTC: ms since the epoch, now
    for payload in (node, device):
        assert payload.timestamp is not None and before_ms - 1000 <= payload.timestamp <= after_ms + 1000
    # tck-id-topics-nbirth-bdseq-included, tck-id-topics-nbirth-bdseq-increment: first CONNECT = 0
    assert bdseq_of(nbirth) == 0
    # tck-id-topics-nbirth-rebirth-metric, tck-id-operational-behavior-data-commands-rebirth-name-aliases
    rebirth = node.by_name()[REBIRTH]
    assert (rebirth.datatype_name, rebirth.value(), rebirth.alias) == ("Boolean", False, None)
    aliases = []
    for payload in (node, device):
        for metric in payload.metrics:
            # tck-id-topics-nbirth-metrics / dbirth-metrics: name, datatype, (null or) value
            assert metric.name and metric.datatype in DATATYPES, metric
            assert metric.timestamp is not None  # tck-id-payloads-name-birth-data-requirement
            # tck-id-operational-behavior-data-publish-nbirth-values: a null has no value
            assert (metric.value_field is None) == metric.is_null, metric
            if metric.name != REBIRTH:
                aliases.append(metric.alias)  # tck-id-payloads-alias-birth-requirement
        # tck-id-operational-behavior-data-publish-dbirth-order: chronological order
        stamps = [metric.timestamp for metric in payload.metrics]
        assert stamps == sorted(stamps)
    assert None not in aliases and len(set(aliases)) == len(aliases)  # tck-id-payloads-alias-uniqueness
    names = set(device.by_name())
    assert {"regions/plate/state", "regions/plate/time_to_dry_s", "fps", "laser", "frames_dropped",
            "ambient_level"} <= names
    assert {f"regions/plate/{name}/mean" for name in ESTIMATORS} <= names
    assert device.by_name()["fps"].properties == {"engUnit": "frames/s"}


def test_data_reports_by_exception_by_alias_with_a_deadband(make_node, host: SparkplugHost) -> None:
    node = make_node(deadband_rel=0.05)
    _, dbirth = births(host)
    alias = {metric.name: metric.alias for metric in dbirth.payload.metrics}
    datatype = {metric.alias: metric.datatype for metric in dbirth.payload.metrics}
    node.publish_stats(stats(100, fps=20.0, s2=0.40))
    first = host.wait_for("DDATA", "the first DDATA")[0]
    assert (first.topic, first.qos, first.retain) == (f"spBv1.0/{GROUP}/DDATA/{NODE}/{DEVICE}", 0, False)
    assert first.payload.seq == 2  # tck-id-topics-ddata-seq-num: one more than the DBIRTH
    for metric in first.payload.metrics:
        # tck-id-payloads-alias-data-cmd-requirement, tck-id-payloads-metric-datatype-not-req
        assert (metric.name, metric.datatype) == (None, None) and metric.alias in datatype
        assert metric.timestamp is not None
    sent = {metric.alias: metric.value(datatype[metric.alias]) for metric in first.payload.metrics}
    assert sent[alias["fps"]] == 20.0 and sent[alias["frames"]] == 100
    assert sent[alias["regions/plate/s2/mean"]] == pytest.approx(0.40)
    # the same values again: nothing to report (tck-id-operational-behavior-data-publish-dbirth-change)
    node.publish_stats(stats(100, fps=20.0, s2=0.40))
    # fps moves 2 % (inside the 5 % deadband), s2 moves 10 %: only s2 goes out
    node.publish_stats(stats(100, fps=20.4, s2=0.44))
    second = host.wait_for("DDATA", "the second DDATA", count=2)[1]
    time.sleep(0.3)
    assert len(host.of("DDATA")) == 2
    assert second.payload.seq == 3
    assert {metric.alias for metric in second.payload.metrics} == {alias["regions/plate/s2/mean"]}
    assert second.payload.metrics[0].value(datatype[alias["regions/plate/s2/mean"]]) == pytest.approx(0.44)
    # a state report: its own metrics, strings by alias
    node.publish_state(report("drying", 0.3))
    third = host.wait_for("DDATA", "the state DDATA", count=3)[2]
    values = {metric.alias: metric.value(datatype[metric.alias]) for metric in third.payload.metrics}
    assert values[alias["regions/plate/state"]] == "drying"
    assert values[alias["regions/plate/activity"]] == pytest.approx(0.3)


def test_seq_wraps_from_255_to_0_across_births_and_data(make_node, host: SparkplugHost) -> None:
    node = make_node()
    births(host)
    for frames in range(1, 301):
        node.publish_stats(stats(frames))
    host.wait_for("DDATA", "300 DDATA", count=300)
    sequence = [m.payload.seq for m in host.all() if m.kind in ("NBIRTH", "DBIRTH", "DDATA", "NDATA")]
    # tck-id-payloads-sequence-num-incrementing: +1 each, 255 followed by 0
    assert sequence[:3] == [0, 1, 2]
    assert all(b == (a + 1) % 256 for a, b in itertools.pairwise(sequence)), sequence
    assert sequence.index(255) + 1 < len(sequence) and sequence[sequence.index(255) + 1] == 0
    assert len(sequence) == 302


def test_rebirth_request_answered_with_the_same_bdseq_and_a_flood_rate_limited(make_node, host: SparkplugHost) -> None:
    node = make_node(rebirth_min_interval_s=1.0)
    nbirth, _ = births(host)
    time.sleep(1.1)
    host.send(NCMD, command([{"name": REBIRTH, "datatype": 11, "boolean_value": True}]))
    second, dbirth = births(host, count=2)
    # tck-id-operational-behavior-data-commands-rebirth-action-2/-3: full birth, same bdSeq, seq 0
    assert bdseq_of(second) == bdseq_of(nbirth) and second.payload.seq == 0 and dbirth.payload.seq == 1
    # a flood: 30 requests in well under a second are answered by one birth per interval
    started = time.monotonic()
    for _ in range(30):
        host.send(NCMD, command([{"name": REBIRTH, "boolean_value": True}]))
    flood_s = time.monotonic() - started
    births(host, count=3)
    time.sleep(1.5)
    count = len(host.of("NBIRTH"))
    assert 3 <= count <= 2 + int(flood_s / 1.0) + 2, (count, flood_s)
    assert node.counters()["rebirth_requests"] == 31
    node.publish_stats(stats(7))  # data goes on after the births
    host.wait_for("DDATA", "data after the rebirths")


def test_bad_commands_are_refused_counted_and_measuring_goes_on(make_node, host: SparkplugHost) -> None:
    # a retained rebirth request would rebirth the node after every reconnection: refused
    host.send(NCMD, command([{"name": REBIRTH, "boolean_value": True}]), qos=1, retain=True)
    node = make_node()
    _, dbirth = births(host)
    wait_until(lambda: node.counters()["commands_refused"] == 1, WAIT_S, "the retained command refused")
    fps_alias = next(m.alias for m in dbirth.payload.metrics if m.name == "fps")
    bad = [b"\xff\x00 not protobuf", b"",
           command([{"name": "Node Control/Reboot", "boolean_value": True}]),  # unknown metric
           command([{"name": "fps", "datatype": 10, "long_value": 5}]),  # read-only
           command([{"alias": 99999, "boolean_value": True}]),  # unknown alias
           command([{"alias": fps_alias, "boolean_value": True}]),  # read-only, by alias
           command([{"name": REBIRTH, "int_value": 1}])]  # wrong type
    for payload in bad:
        host.send(NCMD, payload)
    wait_until(lambda: node.counters()["commands_refused"] >= 8, WAIT_S, "8 refusals")
    time.sleep(0.3)
    assert node.counters()["commands_refused"] == 8
    assert len(host.of("NBIRTH")) == 1
    node.publish_stats(stats(50))
    ndata = host.wait_for("NDATA", "the refusal counter")[0]
    nbirth = host.of("NBIRTH")[0].payload
    counter_alias = next(m.alias for m in nbirth.metrics if m.name == "Node Info/commands_refused")
    assert {m.alias: m.value(8) for m in ndata.payload.metrics}[counter_alias] == 8
    host.wait_for("DDATA", "data goes on")


def test_ndeath_will_matches_the_nbirth_through_a_sigkill_and_bdseq_survives_restarts(
        broker: Broker, host: SparkplugHost, tmp_path: Path) -> None:
    script = (
        "import sys, time\n"
        "from edgedsm.publish.settings import MqttSettings\n"
        "from edgedsm.publish.sparkplug.node import SparkplugSink\n"
        "from edgedsm.publish.sparkplug.settings import SparkplugSettings\n"
        f"node = SparkplugSink(SparkplugSettings(group_id={GROUP!r}, edge_node_id={NODE!r}),\n"
        f"    MqttSettings(host='127.0.0.1', port={broker.port}, keepalive_s=5), {str(tmp_path / 'state')!r},\n"
        "    regions=['plate'], password=None).start()\n"
        "time.sleep(60)\n")

    def run_and_kill(expected_births: int) -> int:
        child = subprocess.Popen([sys.executable, "-c", script], env=child_env(), stderr=subprocess.DEVNULL)
        try:
            nbirth = host.wait_for("NBIRTH", "the child's NBIRTH", count=expected_births)[-1]
            child.kill()  # SIGKILL: no NDEATH of its own, the broker must deliver the will
            child.wait(10)
        finally:
            if child.poll() is None:
                child.kill()
                child.wait(10)
        ndeath = host.wait_for("NDEATH", "the will", count=expected_births)[-1]
        assert ndeath.topic == f"spBv1.0/{GROUP}/NDEATH/{NODE}"  # tck-id-topics-ndeath-topic
        # tck-id-payloads-ndeath-will-message-qos (1) and -retain (false)
        assert (ndeath.qos, ndeath.retain) == (1, False)
        death = ndeath.payload
        # tck-id-topics-ndeath-payload: only bdSeq; tck-id-topics-ndeath-seq: no seq
        assert [m.name for m in death.metrics] == ["bdSeq"] and death.seq is None
        # tck-id-topics-nbirth-bdseq-matching, tck-id-payloads-ndeath-bdseq
        assert bdseq_of(ndeath) == bdseq_of(nbirth)
        return bdseq_of(nbirth)

    first = run_and_kill(1)
    second = run_and_kill(2)
    assert second == (first + 1) % 256  # persisted: a new process goes on counting
    assert (tmp_path / "state" / BDSEQ_FILE).read_text().strip() == str(second)


def test_broker_restart_gives_a_new_session_with_the_next_bdseq(make_node, host: SparkplugHost,
                                                                broker: Broker) -> None:
    node = make_node(rebirth_min_interval_s=0.0)
    first, _ = births(host)
    host.expect_resubscribe()
    broker.restart()
    wait_until(lambda: node.born and node.session_bdseq == bdseq_of(first) + 1, WAIT_S,
               "the node born again with the next bdSeq after the broker restart")
    host.wait_subscribed()
    host.clear()
    host.send(NCMD, command([{"name": REBIRTH, "boolean_value": True}]))  # to see the new session's birth
    second, dbirth = births(host)
    assert bdseq_of(second) == bdseq_of(first) + 1  # tck-id-payloads-ndeath-bdseq: new CONNECT, +1
    assert (second.payload.seq, dbirth.payload.seq) == (0, 1)


def test_a_node_started_with_the_broker_down_births_later_with_the_latest_values(
        make_node, host: SparkplugHost, broker: Broker) -> None:
    host.expect_resubscribe()
    broker.stop()
    node = make_node(rebirth_min_interval_s=0.0)
    node.publish_stats(stats(42))  # measuring goes on while the broker is away
    time.sleep(1.0)
    assert not node.connected and not node.born
    broker.start()
    host.wait_subscribed()
    wait_until(lambda: node.born, WAIT_S, "the node born once the broker is up")
    host.send(NCMD, command([{"name": REBIRTH, "boolean_value": True}]))
    nbirth, dbirth = births(host)
    assert dbirth.payload.by_name()["frames"].value() == 42
    assert bdseq_of(nbirth) == 0  # attempts that never reached a broker used no number


def test_primary_host_state_gates_births_and_offline_restarts_the_session(make_node, host: SparkplugHost) -> None:
    node = make_node(primary_host_id="scada")
    wait_until(lambda: node.connected, WAIT_S, "connected")
    time.sleep(0.5)
    assert host.of("NBIRTH") == []  # tck-id-message-flow-edge-node-birth-publish-phid-wait
    host.state("other-host", True, 5_000)  # not ours: tck-id-...-phid-wait-id
    time.sleep(0.3)
    assert host.of("NBIRTH") == []
    host.state("scada", True, 1_000)  # tck-id-...-phid-wait-online
    first, _ = births(host)
    bdseq = bdseq_of(first)
    host.state("scada", False, 500)  # older than the online one: ignored (...-host-offline-timestamp)
    time.sleep(0.5)
    assert host.of("NDEATH") == [] and node.born
    host.state("scada", False, 2_000)  # valid offline: NDEATH, disconnect, connect again, wait
    ndeath = host.wait_for("NDEATH", "the NDEATH on host offline")[0]
    assert bdseq_of(ndeath) == bdseq
    wait_until(lambda: node.connected and node.session_bdseq == bdseq + 1, WAIT_S, "a new session")
    time.sleep(0.5)
    assert len(host.of("NBIRTH")) == 1  # waiting for the host
    host.state("scada", True, 3_000)
    second, _ = births(host, count=2)
    assert bdseq_of(second) == bdseq + 1


@pytest.mark.parametrize(("protocol", "deaths"), [("3.1.1", 1), ("5", 2)])
def test_clean_close_publishes_ndeath_before_disconnecting(make_node, host: SparkplugHost, protocol: str,
                                                           deaths: int) -> None:
    node = make_node(protocol=protocol)
    nbirth, _ = births(host)
    node.close(2.0)
    # tck-id-operational-behavior-edge-node-intentional-disconnect-ndeath; with MQTT 5 the DISCONNECT
    # says 'with will message' (tck-id-payloads-ndeath-will-message-publisher-disconnect-mqtt50), so the
    # broker sends the will too: the same bdSeq twice, which hosts ignore
    host.wait_for("NDEATH", f"{deaths} NDEATH on a clean stop", count=deaths)
    time.sleep(0.5)
    ndeaths = host.of("NDEATH")
    assert len(ndeaths) == deaths
    assert all(bdseq_of(m) == bdseq_of(nbirth) and m.payload.seq is None for m in ndeaths)


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_the_daemon_end_to_end_publishes_the_drying_plate_as_sparkplug(
        broker: Broker, host: SparkplugHost, tmp_path: Path) -> None:
    from helpers_daemon import Daemon, base_config, write_config

    config = base_config(tmp_path, port=broker.port, device="spb")
    config["sparkplug"] = {"group_id": "plant", "rebirth_min_interval_s": 0.5}  # edge node id: the device
    daemon = Daemon(write_config(tmp_path / "daemon.toml", config))
    try:
        nbirth = host.wait_for("NBIRTH", "the daemon's NBIRTH", timeout=30)[0]
        dbirth = host.wait_for("DBIRTH", "the daemon's DBIRTH", timeout=30)[0]
        assert (nbirth.topic, dbirth.topic) == ("spBv1.0/plant/NBIRTH/spb", "spBv1.0/plant/DBIRTH/spb/camera")
        known = {metric.name: metric for metric in dbirth.payload.metrics}
        assert {f"regions/plate/{name}/mean" for name in ESTIMATORS} <= set(known)
        state_alias, s2_alias = known["regions/plate/state"].alias, known["regions/plate/s2/mean"].alias
        known_types = {metric.alias: metric.datatype for metric in dbirth.payload.metrics}

        def values_of(alias: int) -> list[Any]:
            """The metric's values in births (a new metric, e.g. a drop cause, brings one) and data."""
            return [metric.value(known_types[alias]) for message in host.all() if message.kind in ("DBIRTH", "DDATA")
                    for metric in message.payload.metrics if metric.alias == alias]

        def states() -> list[str]:
            return [value for value, _ in itertools.groupby(values_of(state_alias)) if value is not None]

        # the demo plate dries: wet -> drying -> dry, each reported once by exception
        wait_until(lambda: "dry" in states(), 90, f"the plate reported dry over Sparkplug (so far {states()})")
        # every transition the daemon logged, and nothing else, in order (on a loaded machine the
        # window may fill when the plate is already drying: warming_up -> drying is legitimate)
        daemon.wait_log(r"region plate: \w+ -> dry", 10)  # stderr is read on its own thread: it may lag
        logged = re.findall(r"region plate: (\w+) -> (\w+)", daemon.log)
        assert logged and states() == ["warming_up", *(to for _, to in logged)], (states(), logged)
        assert states()[-1] == "dry"
        s2 = [value for value in values_of(s2_alias) if value is not None]
        assert s2 and all(value > 0 for value in s2) and s2[0] > s2[-1]  # activity falls as it dries
        # a host asks for a rebirth: the same session's bdSeq
        births_before = len(host.of("NBIRTH"))
        host.send("spBv1.0/plant/NCMD/spb", command([{"name": REBIRTH, "boolean_value": True}]))
        again = host.wait_for("NBIRTH", "the NBIRTH answering the rebirth", count=births_before + 1)[-1]
        assert bdseq_of(again) == bdseq_of(nbirth)
        daemon.process.kill()  # SIGKILL: the broker delivers the will
        ndeath = host.wait_for("NDEATH", "the daemon's NDEATH after SIGKILL", timeout=20)[0]
        assert bdseq_of(ndeath) == bdseq_of(nbirth)
    finally:
        daemon.kill()
    # restarted: the next bdSeq; SIGTERM: its own NDEATH before the process exits
    host.clear()
    daemon = Daemon(write_config(tmp_path / "daemon.toml", config))
    try:
        restarted = host.wait_for("NBIRTH", "the restarted daemon's NBIRTH", timeout=30)[0]
        assert bdseq_of(restarted) == bdseq_of(nbirth) + 1
        code, _ = daemon.terminate()  # the 2 s bound is test_daemon_e2e's (timing is not asserted here)
        assert code == 0
        ndeath = host.wait_for("NDEATH", "the NDEATH of a SIGTERM", timeout=5)[0]
        assert bdseq_of(ndeath) == bdseq_of(restarted)
    finally:
        daemon.kill()
