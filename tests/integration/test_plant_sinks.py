"""Home Assistant discovery and Prometheus metrics of a real daemon (`edgedsm run`) on a REAL
mosquitto: configs retained and their state topics live (templates rendered as Home Assistant
does), `/metrics` scraped with a real HTTP client and parsed with `prometheus_client.parser`,
`/healthz`, a removed region's entity removed at the next start."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import jinja2
import numpy as np
import pytest
from helpers_daemon import Daemon, base_config, http_get, write_config
from helpers_mqtt import WAIT_S, Broker, Received, Subscriber, free_port, wait_until
from prometheus_client.parser import text_string_to_metric_families

from edgedsm.publish import Topics

pytestmark = [pytest.mark.integration, pytest.mark.slow]

PREFIX = "homeassistant"




def _config(tmp_path: Path, port: int, http_port: int, region: str = "plate") -> dict[str, Any]:
    config = base_config(tmp_path, port=port, region=region)
    config["cadence"]["maps_interval_s"] = 1.0
    config["homeassistant"] = {"discovery_prefix": PREFIX}
    config["http"] = {"listen": f"127.0.0.1:{http_port}", "stale_after_s": 3.0}
    return config


def _render(template: str, payload: bytes) -> str:
    return jinja2.Environment().from_string(template).render(value_json=json.loads(payload))


def _configs(subscriber: Subscriber) -> dict[str, dict[str, Any]]:
    """The latest non-empty discovery config per topic."""
    found: dict[str, dict[str, Any]] = {}
    for message in subscriber.messages:
        if message.topic.startswith(f"{PREFIX}/") and message.topic.endswith("/config"):
            if message.payload:
                found[message.topic] = json.loads(message.payload)
            else:
                found.pop(message.topic, None)
    return found


def _last(subscriber: Subscriber, topic: str) -> Received | None:
    messages = subscriber.on(topic)
    return messages[-1] if messages else None


@pytest.mark.timeout(120)
def test_home_assistant_entities_and_metrics_of_a_running_daemon(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[[Path], Daemon]) -> None:
    http_port = free_port()
    settings = _config(tmp_path, broker.port, http_port)
    settings["logging"] = {"level": "info", "json_lines": True}
    config = write_config(tmp_path / "edgedsm.toml", settings)
    topics = Topics.of("edgedsm", "e2e")
    live = subscribers(broker.port, [f"{PREFIX}/#", f"{topics.base}/#"])
    daemon = daemons(config)
    # every colour map published once before the late subscriber arrives (else one may reach it
    # live, not retained: a race of the test, not of the sink)
    wait_until(lambda: all(_last(live, topics.map(name) + "/color") is not None for name in ("s1", "s2", "s3")),
               WAIT_S, "the colour maps")
    wait_until(lambda: any("activity" in m.topic or "_s2/" in m.topic for m in live.messages
                           if m.topic.startswith(PREFIX)), WAIT_S, "the activity entities")

    # a subscriber arriving later gets every config, retained
    late = subscribers(broker.port, [f"{PREFIX}/#", f"{topics.maps_filter}/color"])
    colour_topics = [topics.map(name) + "/color" for name in ("s1", "s2", "s3")]
    wait_until(lambda: len(_configs(late)) >= 13 and all(late.on(topic) for topic in colour_topics), WAIT_S,
               "retained discovery configs (the signal's too: estimator.noise_floor) and colour maps")
    first: dict[str, Received] = {}
    for message in late.messages:
        first.setdefault(message.topic, message)
    # later copies (a new map) arrive live, not retained
    assert [t for t, m in first.items() if not m.retain] == []
    configs = _configs(late)
    kinds = sorted(topic.split("/")[1] for topic in configs)
    assert kinds == ["binary_sensor", "binary_sensor", "image", "image", "image", *["sensor"] * 8], sorted(configs)
    assert {f"{PREFIX}/sensor/edgedsm_e2e/plate_signal/config",
            f"{PREFIX}/sensor/edgedsm_e2e/plate_above_noise/config"} <= set(configs)
    devices = {json.dumps(c["device"], sort_keys=True) for c in configs.values()}
    assert len(devices) == 1 and json.loads(devices.pop())["identifiers"] == ["edgedsm_edgedsm_e2e"]

    # every referenced topic carries a value the template turns into a valid state
    for topic, entity in configs.items():
        if "image_topic" in entity:
            png = first.get(entity["image_topic"])
            assert png is not None and png.retain, entity["image_topic"]  # a viewer starting later sees it
            image = cv2.imdecode(np.frombuffer(png.payload, np.uint8), cv2.IMREAD_UNCHANGED)
            assert image.dtype == np.uint8 and image.shape[2] == 3
            continue
        message = _last(live, entity["state_topic"])
        assert message is not None, f"{topic}: nothing on {entity['state_topic']}"
        value = _render(entity["value_template"], message.payload) if "value_template" in entity \
            else message.payload.decode()
        if entity.get("device_class") == "enum":
            assert value in entity["options"]
        elif topic.split("/")[1] == "binary_sensor":
            assert value in (entity["payload_on"], entity["payload_off"]), (topic, value)
        elif value != "None":  # the activity above the noise (judged) may read below 0, within its spread
            assert float(value) >= 0 or topic.endswith(("_above_noise/config", "_activity/config")), (topic, value)
        if "availability_topic" in entity:
            assert _last(live, entity["availability_topic"]).payload == b"online"
    state_entity = configs[f"{PREFIX}/sensor/edgedsm_e2e/plate_state/config"]
    state = _last(live, topics.state)
    assert _render(state_entity["value_template"], state.payload) == state.json()["regions"]["plate"]["state"]

    # Prometheus: scraped and parsed
    wait_until(lambda: http_get(http_port, "/healthz")[0] == 200, WAIT_S, "/healthz 200")
    status, body = http_get(http_port, "/metrics")
    assert status == 200
    samples = {(s.name, tuple(sorted(s.labels.items()))): s.value
               for family in text_string_to_metric_families(body.decode()) for s in family.samples}
    assert samples[("edgedsm_frames_total", ())] > 0
    assert samples[("edgedsm_mqtt_connected", ())] == 1
    assert samples[("edgedsm_alerts_pending", ())] >= 0
    assert 0 < samples[("edgedsm_engine_ms_per_frame", ())] < 1000
    states = [v for (name, labels), v in samples.items() if name == "edgedsm_region_state"]
    assert len(states) == 5 and sum(states) == 1
    assert ("edgedsm_region_activity", (("estimator", "s2"), ("region", "plate"), ("unit", "1"))) in samples
    assert ("edgedsm_region_map_mean", (("map", "s1"), ("region", "plate"), ("unit", "grey levels"))) in samples
    verdicts = {labels: v for (name, labels), v in samples.items() if name == "edgedsm_region_signal"}
    assert len(verdicts) == 5 and sum(verdicts.values()) == 1, verdicts
    assert samples[("edgedsm_region_mean_intensity", (("region", "plate"),))] > 0
    assert http_get(http_port, "/nothing")[0] == 404
    assert http_get(http_port, "/healthz")[0] == 200  # still measuring

    # the JSON log names the region and the state entered on every transition
    daemon.wait_log(r'"region": "plate", "state": "', WAIT_S)
    transition = next(json.loads(line) for line in daemon.log.splitlines() if '"region": "plate"' in line)
    assert transition["level"] == "info"  # a normal transition is news, not a warning
    assert transition["message"].startswith(f"region plate: warming_up -> {transition['state']} ")

    code, _ = daemon.terminate()
    assert code == 0
    wait_until(lambda: _last(live, topics.availability).payload == b"offline", WAIT_S, "offline")


@pytest.mark.timeout(120)
def test_a_region_removed_from_the_config_loses_its_entities_at_the_next_start(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[[Path], Daemon]) -> None:
    config = tmp_path / "edgedsm.toml"
    write_config(config, _config(tmp_path, broker.port, free_port(), region="plate"))
    old = f"{PREFIX}/sensor/edgedsm_e2e/plate_state/config"
    new = f"{PREFIX}/sensor/edgedsm_e2e/panel_state/config"
    watcher = subscribers(broker.port, [f"{PREFIX}/#"])
    first = daemons(config)
    wait_until(lambda: old in _configs(watcher) and f"{PREFIX}/sensor/edgedsm_e2e/plate_s2/config"
               in _configs(watcher), WAIT_S, "the plate's entities")
    assert first.terminate()[0] == 0
    write_config(config, _config(tmp_path, broker.port, free_port(), region="panel"))
    second = daemons(config)
    wait_until(lambda: new in _configs(watcher), WAIT_S, "the panel's entities")
    assert second.terminate()[0] == 0
    later = subscribers(broker.port, [f"{PREFIX}/#"])
    wait_until(lambda: new in _configs(later), WAIT_S, "retained configs")
    assert not [topic for topic in _configs(later) if "/plate_" in topic]
    removed = [m.topic for m in watcher.messages if not m.payload]
    assert old in removed and f"{PREFIX}/sensor/edgedsm_e2e/plate_s2/config" in removed


@pytest.mark.timeout(60)
def test_new_estimators_appear_and_home_assistant_restarting_gets_every_config_again(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber]) -> None:
    import paho.mqtt.publish as single

    from edgedsm.messages import MapStats, RegionSignal, RegionTau, Stats
    from edgedsm.publish.homeassistant import HomeAssistantSink
    from edgedsm.publish.session import MqttSession
    from edgedsm.publish.settings import MqttSettings

    settings = MqttSettings(host="127.0.0.1", port=broker.port, device="line3", reconnect_min_s=0.1,
                            reconnect_max_s=0.5)
    watcher = subscribers(broker.port, [f"{PREFIX}/#"])
    session = MqttSession(settings, client_id="line3-link", password="").start()
    sink = HomeAssistantSink(session, PREFIX, ["panel"], tmp_path / "state", colormap=None).start()
    try:
        wait_until(lambda: sink.connected and len(_configs(watcher)) == 4, WAIT_S, "the static entities")
        one = MapStats(pixels=4, mean=0.2, std=0.1, p05=0.1, median=0.2, p95=0.3)
        # as a daemon's stats: a τc map's region mean beside the region's pooled τc, which owns the sensor
        tau_c = RegionTau(tau_c_s=2.5, status="measured")
        stats = Stats(t=1.0, frames=5, ready=True, fps=10.0, laser="on", estimator="s2",
                      regions={"panel": {"s2": one, "tau_c": one}, "ghost": {"s2": one}},
                      tau_c={"panel": tau_c, "ghost": tau_c})
        sink.publish_stats(stats)
        tau = f"{PREFIX}/sensor/edgedsm_line3/panel_tau_c/config"
        wait_until(lambda: tau in _configs(watcher), WAIT_S, "the tau_c sensor")
        assert len(_configs(watcher)) == 6  # panel s2 and tau_c; 'ghost' is not a configured region
        assert _configs(watcher)[tau]["name"] == "panel τc"
        light = RegionSignal(signal="low", mean=84.0, dark_fraction=0.0, saturated_fraction=0.0,
                             speckle_contrast=0.5, noise_floor=0.025, above_noise=0.0013, above_noise_spread=0.0006)
        sink.publish_stats(stats.model_copy(update={"signal": {"panel": light, "ghost": light}}))
        signal = f"{PREFIX}/sensor/edgedsm_line3/panel_signal/config"
        wait_until(lambda: signal in _configs(watcher), WAIT_S, "the signal sensor")
        wait_until(lambda: len(_configs(watcher)) == 8, WAIT_S, "the above-noise sensor")  # not the ghost's
        assert _configs(watcher)[signal]["options"] == ["ok", "low", "dark", "saturated", "not_speckle"]
        before = len(watcher.messages)
        single.single(f"{PREFIX}/status", b"online", hostname="127.0.0.1", port=broker.port)
        again = lambda: {m.topic for m in watcher.messages[before:] if m.topic.endswith("/config")}  # noqa: E731
        wait_until(lambda: len(again()) >= 8, WAIT_S, "every config again")
        assert again() == set(_configs(watcher))
        remembered = json.loads((tmp_path / "state" / "homeassistant-line3.json").read_text())
        assert remembered[tau] == remembered[signal] == "panel" and len(remembered) == 8
    finally:
        sink.close(1.0)
        session.close(1.0)
