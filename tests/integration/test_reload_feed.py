"""A feed SCADA can trust across `systemctl reload` (issue 10 §1), against a real mosquitto and
`python -m edgedsm run`.

- A reload that changes only publishing, logging or thresholds keeps the MQTT session (no
  ``offline``), the estimator window (the frame count goes on) and the drying states (no region
  goes back to ``warming_up``, no alert).
- A reload that must restart measurement (the estimator's window) publishes one ``reset`` alert
  naming what changed, then every region's ``warming_up``, then the states start again.
- Per-region retained ``state/<region>`` topics; a removed region's topic is cleared.
- ``[mqtt] laser_command = false``: ``cmd/laser`` refused, saying so.
"""

from __future__ import annotations

import contextlib
import json
import signal
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from helpers_commands import signed
from helpers_daemon import (
    DRYING_SCENE,
    Daemon,
    base_config,
    collapse,
    distinct_alerts,
    frames_published,
    region_states,
    wait_frames_beyond,
    write_config,
)
from helpers_mqtt import WAIT_S, Broker, Subscriber, wait_until
from helpers_relay import NumatoBoard, open_pty_pair

from edgedsm.publish import Topics

pytestmark = [pytest.mark.integration, pytest.mark.slow]

#: The demo plate at 100 frames/s.
SLOW_CAMERA = f"sim:{DRYING_SCENE}?time_scale=0.2"


def _feed(tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
          daemons: Callable[..., Daemon], **extra: Any) -> tuple[dict[str, Any], Path, Topics, Subscriber, Daemon]:
    config = base_config(tmp_path, port=broker.port, camera=SLOW_CAMERA)
    for section, values in extra.items():
        config.setdefault(section, {}).update(values)
    path = write_config(tmp_path / "daemon.toml", config)
    topics = Topics.of("edgedsm", "e2e")
    scada = subscribers(broker.port, [f"{topics.base}/#"], client_id=f"scada-{uuid.uuid4().hex[:6]}")
    daemon = daemons(path)
    scada.wait_for(topics.availability, lambda m: m.payload == b"online", "availability online", timeout=30)
    try:
        wait_until(lambda: any(a.get("from") == "warming_up" for a in distinct_alerts(scada, topics)), 60,
                   "the first alert out of warming_up")
    except BaseException:
        print(daemon.log)
        raise
    return config, path, topics, scada, daemon


def _availability(scada: Subscriber, topics: Topics) -> list[bytes]:
    return collapse([m.payload for m in scada.on(topics.availability)])  # type: ignore[arg-type]


@pytest.mark.timeout(150)
def test_a_publishing_and_thresholds_reload_keeps_session_window_and_states(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    config, path, topics, scada, daemon = _feed(tmp_path, broker, subscribers, daemons)
    frames_before = wait_frames_beyond(scada, topics, 0)
    alerts_before = len(distinct_alerts(scada, topics))
    states_before = len(scada.on(topics.state))

    config["cadence"]["stats_interval_s"] = 0.4          # publishing
    config["cadence"]["maps_interval_s"] = 30.0
    config["logging"]["level"] = "debug"               # logging
    config["regions"][0]["min_dwell_s"] = 1.5          # thresholds
    write_config(path, config)
    daemon.signal(signal.SIGHUP)
    daemon.wait_log(r"configuration reloaded", WAIT_S)
    after = wait_frames_beyond(scada, topics, frames_before + 60)

    assert "Traceback" not in daemon.log
    assert _availability(scada, topics) == [b"online"], "the session was dropped across the reload"
    new_alerts = distinct_alerts(scada, topics)[alerts_before:]
    assert [a["type"] for a in new_alerts if a["type"] != "transition"] == []
    assert all(a["to"] != "warming_up" for a in new_alerts), new_alerts
    states = region_states(scada.on(topics.state)[states_before:], "plate")
    assert "warming_up" not in states, states
    # the frame count went on: the same window, not a new pipeline counting from zero
    stats_frames = [m.json()["frames"] for m in scada.on(topics.stats)]
    assert stats_frames == sorted(stats_frames) and after > frames_before + 60
    assert "measurement kept" in daemon.log
    # between transitions the report is republished as activity and time to dry move
    def republished_within_a_state() -> bool:
        reports = [m.json()["regions"]["plate"] for m in scada.on(topics.state)]
        within_a_state = [r for r in reports if r["since"] == reports[-1]["since"]]
        return len({(r["activity"], r["time_to_dry_s"]) for r in within_a_state}) >= 2

    wait_until(republished_within_a_state, 30, "a state report republished within one state as activity moved")
    # each combined report is followed by its per-region one: read between the two, the
    # per-region topic is one behind, so wait (bounded) for it to catch up with the snapshot
    reports = [m.json()["regions"]["plate"] for m in scada.on(topics.state)]

    def per_region() -> list[dict[str, Any]]:
        return [m.json() for m in scada.on(f"{topics.state}/plate")]

    wait_until(lambda: len(per_region()) >= len(reports), WAIT_S, "the per-region report after the combined one")
    assert per_region()[:len(reports)] == reports


@pytest.mark.timeout(150)
@pytest.mark.parametrize("relay", ["sim", "numato"])
def test_a_reload_of_the_unchanged_file_keeps_window_states_and_laser(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon], relay: str) -> None:
    # The running config has read its relay URI (its parsed spec is cached); the file read
    # again must still count as unchanged, whatever the relay.
    with contextlib.ExitStack() as stack:
        board = None
        if relay == "sim":
            uri = f"sim:reload-{uuid.uuid4().hex[:6]}"
        else:
            pair = stack.enter_context(open_pty_pair(tmp_path))
            board = NumatoBoard(pair.board, channel=11)
            board.start()
            stack.callback(board.stop)
            uri = f"serial:{pair.app}?protocol=numato&channel=11"
        _, _, topics, scada, daemon = _feed(tmp_path, broker, subscribers, daemons, laser={"uri": uri})
        frames_before = wait_frames_beyond(scada, topics, 0)
        alerts_before = len(distinct_alerts(scada, topics))
        states_before = len(scada.on(topics.state))

        daemon.signal(signal.SIGHUP)  # the file as it is
        daemon.wait_log(r"configuration reloaded", WAIT_S)
        wait_frames_beyond(scada, topics, frames_before + 60)

        after_reload = daemon.log.split("configuration reloaded", 1)[1]
        assert after_reload.startswith(" from ") and "(changed: nothing); measurement kept" in after_reload, daemon.log
        assert "measurement restarted" not in after_reload
        new_alerts = distinct_alerts(scada, topics)[alerts_before:]
        assert [a["type"] for a in new_alerts if a["type"] != "transition"] == [], new_alerts
        assert "warming_up" not in region_states(scada.on(topics.state)[states_before:], "plate")
        assert _availability(scada, topics) == [b"online"]
        if board is not None:
            assert board.errors == [] and board.is_on  # still measuring, never switched by the reload


@pytest.mark.timeout(150)
def test_a_measurement_reload_publishes_one_reset_alert_then_warming_up(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    config, path, topics, scada, daemon = _feed(tmp_path, broker, subscribers, daemons)
    alerts_before = len(distinct_alerts(scada, topics))

    config["estimator"]["window"] = 80
    write_config(path, config)
    sent = time.time()
    daemon.signal(signal.SIGHUP)
    daemon.wait_log(r"configuration reloaded", WAIT_S)
    wait_until(lambda: any(a.get("from") == "warming_up" for a in distinct_alerts(scada, topics)[alerts_before:]),
               60, "out of warming_up again after the reset")

    assert _availability(scada, topics) == [b"online"]
    new_alerts = distinct_alerts(scada, topics)[alerts_before:]
    assert new_alerts[0]["type"] == "reset", new_alerts
    assert "estimator" in new_alerts[0]["reason"] and new_alerts[0]["region"] is None
    assert abs(new_alerts[0]["t"] - sent) < 10  # wall-clock UTC on the wire
    assert [a["type"] for a in new_alerts[1:]] == ["transition"] * (len(new_alerts) - 1)
    assert new_alerts[1]["from"] == "warming_up" and new_alerts[1]["to"] in ("wet", "drying", "dry")
    # the states went back to warming_up only after the reset alert, and explicitly
    # (the state that follows an alert is published right after it: wait for it, bounded)
    def states_since_reset() -> list[str]:
        later = [m.json() for m in scada.on(topics.state)]
        return collapse([s["regions"]["plate"]["state"] for s in later if s["t"] >= new_alerts[0]["t"]])

    wait_until(lambda: len(states_since_reset()) >= 2, WAIT_S, "the state report after the transition")
    assert states_since_reset()[:2] == ["warming_up", new_alerts[1]["to"]]
    # per-region topic: the same RegionState, wall-clock times
    per_region = [m.json() for m in scada.on(f"{topics.state}/plate")]
    assert per_region and set(per_region[-1]) >= {"region", "state", "since", "activity", "time_to_dry_s"}
    assert per_region[-1]["region"] == "plate" and abs(per_region[-1]["since"] - time.time()) < 120


@pytest.mark.timeout(150)
def test_a_removed_region_has_its_retained_topic_cleared_and_laser_command_can_be_disabled(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    config, path, topics, scada, daemon = _feed(tmp_path, broker, subscribers, daemons,
                                                mqtt={"laser_command": False})
    scada.wait_for(f"{topics.state}/plate", lambda m: bool(m.payload), "state/plate")

    scada.client.publish(topics.command("laser"), signed(topics.command("laser"), {"state": "on"}, request_id="q1"),
                         qos=1)
    reply = scada.wait_for(topics.reply("laser"), lambda m: m.json().get("request_id") == "q1", "laser reply").json()
    assert reply["ok"] is False and "disabled by configuration" in reply["error"]
    # the other commands still work
    scada.client.publish(topics.command("publish_maps"), json.dumps({"request_id": "q2"}), qos=1)
    reply = scada.wait_for(topics.reply("publish_maps"), lambda m: m.json().get("request_id") == "q2",
                           "publish_maps reply").json()
    assert reply["ok"] is True

    config["regions"][0]["name"] = "board"
    write_config(path, config)
    daemon.signal(signal.SIGHUP)
    daemon.wait_log(r"configuration reloaded", WAIT_S)
    scada.wait_for(f"{topics.state}/plate", lambda m: m.payload == b"", "state/plate cleared")
    scada.wait_for(f"{topics.state}/board", lambda m: bool(m.payload), "state/board")
    resets = [a for a in distinct_alerts(scada, topics) if a["type"] == "reset"]
    assert len(resets) == 1 and "regions" in resets[0]["reason"]

    # a new subscriber sees the retained per-region state of 'board' only
    late = subscribers(broker.port, [f"{topics.state}/+"], client_id=f"late-{uuid.uuid4().hex[:6]}")
    wait_until(lambda: bool(late.on(f"{topics.state}/board")), WAIT_S, "retained state/board")
    time.sleep(0.5)
    assert late.on(f"{topics.state}/plate") == []

    # removed while the daemon is stopped: cleared at the next start
    code, _ = daemon.terminate()
    assert code == 0
    config["regions"][0]["name"] = "plate"
    write_config(path, config)
    daemons(path)
    scada.wait_for(f"{topics.state}/board", lambda m: m.payload == b"", "state/board cleared at start", timeout=30)
    scada.wait_for(f"{topics.state}/plate", lambda m: bool(m.payload) and m.json()["region"] == "plate",
                   "state/plate again")


@pytest.mark.timeout(150)
def test_only_the_sink_whose_settings_changed_starts_a_new_session(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    from helpers_sparkplug import SparkplugHost

    host = SparkplugHost(broker.port).start()
    try:
        config, path, topics, scada, daemon = _feed(
            tmp_path, broker, subscribers, daemons, sparkplug={"group_id": "plant", "rebirth_min_interval_s": 0.5},
            homeassistant={})
        born = host.wait_for("NBIRTH", "the first NBIRTH")[0].payload.by_name()["bdSeq"].value()
        frames = frames_published(scada, topics)

        # thresholds and cadence: nothing reconnects
        config["regions"][0]["min_dwell_s"] = 1.5
        config["cadence"]["stats_interval_s"] = 0.4
        write_config(path, config)
        daemon.signal(signal.SIGHUP)
        daemon.wait_log(r"configuration reloaded", WAIT_S)
        wait_frames_beyond(scada, topics, frames + 60)
        assert len(host.of("NBIRTH")) == 1 and host.of("NDEATH") == []

        # the Sparkplug node's own settings: that node alone is born again, with the next bdSeq
        config["sparkplug"]["deadband_rel"] = 0.02
        write_config(path, config)
        daemon.signal(signal.SIGHUP)
        wait_until(lambda: daemon.log.count("configuration reloaded") == 2, WAIT_S, "the second reload")
        births = host.wait_for("NBIRTH", "the node born again", count=2)
        assert births[1].payload.by_name()["bdSeq"].value() == (born + 1) % 256
        # the old session's death (the node's own NDEATH; the broker may deliver its will too)
        deaths = {m.payload.by_name()["bdSeq"].value() for m in host.of("NDEATH")}
        assert deaths == {born}, (deaths, born)
        assert _availability(scada, topics) == [b"online"], "the JSON session was dropped with the Sparkplug one"
        assert "sinks built: sparkplug; closed: sparkplug" in daemon.log
        assert not [a for a in distinct_alerts(scada, topics) if a["type"] == "reset"]
    finally:
        host.stop()


@pytest.mark.timeout(60)
def test_a_reload_whose_sink_cannot_start_is_refused_and_the_running_sinks_serve_on(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import socket
    import urllib.request

    from helpers_daemon import service_thread
    from helpers_mqtt import free_port

    config = base_config(tmp_path)
    port = free_port()
    config["http"] = {"listen": f"127.0.0.1:{port}"}
    path = write_config(tmp_path / "daemon.toml", config)
    with socket.socket() as taken, service_thread(path) as (service, result):
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        url = f"http://127.0.0.1:{port}/metrics"
        wait_until(lambda: _frames_total(_get(urllib.request, url)) >= 20, WAIT_S, "metrics served")
        pipeline, metrics = service.pipeline, service.sinks.get("http")
        config["http"] = {"listen": f"127.0.0.1:{taken.getsockname()[1]}"}
        config["regions"][0]["min_dwell_s"] = 2.0
        write_config(path, config)
        before = _frames_total(_get(urllib.request, url))
        service.request_reload()
        wait_until(lambda: "reload refused" in caplog.text, WAIT_S, "the reload refused")
        assert "http.listen" in caplog.text
        assert service.config.regions[0].min_dwell_s == 1.0 and service.pipeline is pipeline
        # the new metrics server is started beside the running one: it could not, so the running one was
        # never closed (its counters not started again from 0)
        assert service.sinks.get("http") is metrics
        assert _frames_total(_get(urllib.request, url)) >= before
        assert "sinks built" not in caplog.text
        assert result["thread"].is_alive() and "Traceback" not in caplog.text


def _frames_total(page: bytes) -> float:
    for line in page.decode().splitlines():
        if line.startswith("edgedsm_frames_total"):
            return float(line.split()[-1])
    return -1.0


def _get(request: Any, url: str) -> bytes:
    try:
        with request.urlopen(url, timeout=2) as response:
            return bytes(response.read())
    except OSError:
        return b""

