"""Prometheus metrics and health over a real HTTP server on a free loopback port."""

from __future__ import annotations

import http.client
import math
import socket
from collections.abc import Iterator

import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from edgedsm.frames import Frame
from edgedsm.messages import MapStats, RegionActivity, RegionSignal, Stats
from edgedsm.publish.prometheus import MetricsSink
from tests.ports import free_port


class Link:
    connected = True
    pending_alerts = 3
    refusal: str | None = None
    last_error: str | None = None


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def sink(clock: FakeClock) -> Iterator[MetricsSink]:
    metrics = MetricsSink(stale_after_s=5.0, link=Link(), monotonic=clock).serve(("127.0.0.1", 0))
    yield metrics
    metrics.close(1.0)


def _get(sink: MetricsSink, path: str, method: str = "GET", body: bytes | None = None,
         headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    assert sink.server is not None
    connection = http.client.HTTPConnection("127.0.0.1", sink.server.port, timeout=5)
    try:
        connection.request(method, path, body=body, headers=headers or {})
        response = connection.getresponse()
        return response.status, response.read()
    finally:
        connection.close()


def _samples(text: bytes) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    return {(sample.name, tuple(sorted(sample.labels.items()))): sample.value
            for family in text_string_to_metric_families(text.decode())
            for sample in family.samples}


def _stats(frames: int, state: str = "drying", laser: str = "on") -> Stats:
    per_map = {"s1": MapStats(pixels=9, mean=3.5, std=1, p05=1, median=3, p95=6),
               "s2": MapStats(pixels=9, mean=0.25, std=0.1, p05=0.1, median=0.2, p95=0.4)}
    # judged above the noise: less than the plain S2 mean
    activity = {"panel": RegionActivity(value=0.0625, estimator="s2", unit="1", basis="above_noise")}
    return Stats(t=1.0, frames=frames, ready=True, fps=19.5, laser=laser, estimator="s2",
                 drops={"queue": 4, "invalid": 1}, regions={"panel": per_map}, state={"panel": state},
                 activity=activity)


def _frame(seq: int) -> Frame:
    return Frame(np.zeros((2, 2), np.uint16), seq=seq, t_ns=seq, bits=12)


def test_metrics_carry_the_latest_stats_probes_and_link(sink: MetricsSink) -> None:
    sink.publish_stats(_stats(120))
    for cost in (0.002, 0.004):
        sink.frame_pushed(_frame(1), 0.0, cost)
    status, body = _get(sink, "/metrics")
    assert status == 200
    samples = _samples(body)
    assert samples[("edgedsm_frames_total", ())] == 120
    assert samples[("edgedsm_frames_dropped_total", (("cause", "queue"),))] == 4
    assert samples[("edgedsm_frames_dropped_total", (("cause", "invalid"),))] == 1
    assert samples[("edgedsm_alerts_pending", ())] == 3
    assert samples[("edgedsm_mqtt_connected", ())] == 1
    assert samples[("edgedsm_laser_on", ())] == 1
    # the judged value under `activity`, the plain means under their own name, each with its unit
    activity = {labels: value for (name, labels), value in samples.items() if name == "edgedsm_region_activity"}
    assert activity == {(("estimator", "s2"), ("region", "panel"), ("unit", "1")): 0.0625}
    assert samples[("edgedsm_region_map_mean", (("map", "s1"), ("region", "panel"), ("unit", "grey levels")))] == 3.5
    assert samples[("edgedsm_region_map_mean", (("map", "s2"), ("region", "panel"), ("unit", "1")))] == 0.25
    states = {labels: value for (name, labels), value in samples.items() if name == "edgedsm_region_state"}
    assert sum(states.values()) == 1 and states[(("region", "panel"), ("state", "drying"))] == 1
    assert len(states) == 5
    assert samples[("edgedsm_engine_ms_per_frame", ())] == pytest.approx(3.0)
    assert samples[("edgedsm_engine_push_seconds_total", ())] == pytest.approx(0.006)


def test_each_regions_signal_quality_and_activity_above_the_noise(sink: MetricsSink) -> None:
    sink.publish_stats(_stats(10))  # estimator.noise_floor off: no signal gauges at all
    assert not any(name.startswith(("edgedsm_region_signal", "edgedsm_region_above_noise"))
                   for name, _labels in _samples(_get(sink, "/metrics")[1]))
    signal = {"panel": RegionSignal(signal="low", mean=12.5, dark_fraction=0.25, saturated_fraction=0.0,
                                    speckle_contrast=0.75, noise_floor=0.125, above_noise=0.0625,
                                    above_noise_spread=0.03125, noise_model="frames", intensity_change=0.125,
                                    reason="activity within the noise"),
              "edge": RegionSignal(signal="saturated", mean=250.0, dark_fraction=0.0, saturated_fraction=0.5,
                                   speckle_contrast=0.5)}  # no noise model yet: no floor
    sink.publish_stats(_stats(20).model_copy(update={"signal": signal}))
    samples = _samples(_get(sink, "/metrics")[1])
    verdicts = {labels: value for (name, labels), value in samples.items() if name == "edgedsm_region_signal"}
    assert verdicts == {(("region", region), ("signal", name)): float(name == current)
                        for region, current in (("panel", "low"), ("edge", "saturated"))
                        for name in ("ok", "low", "dark", "saturated", "not_speckle")}
    panel = (("region", "panel"),)
    assert {name: value for (name, labels), value in samples.items() if labels == panel} == {
        "edgedsm_region_above_noise": 0.0625, "edgedsm_region_above_noise_spread": 0.03125,
        "edgedsm_region_noise_floor": 0.125, "edgedsm_region_mean_intensity": 12.5,
        "edgedsm_region_dark_fraction": 0.25, "edgedsm_region_saturated_fraction": 0.0,
        "edgedsm_region_speckle_contrast": 0.75, "edgedsm_region_intensity_change": 0.125}
    edge = {name: value for (name, labels), value in samples.items() if labels == (("region", "edge"),)}
    assert edge == {"edgedsm_region_mean_intensity": 250.0, "edgedsm_region_dark_fraction": 0.0,
                    "edgedsm_region_saturated_fraction": 0.5, "edgedsm_region_speckle_contrast": 0.5}


def test_time_to_dry_comes_from_the_state_report(sink: MetricsSink) -> None:
    from edgedsm.messages import RegionState, StateReport

    sink.publish_state(StateReport(t=1.0, estimator="s2", regions={
        "panel": RegionState(region="panel", state="drying", since=0.0, time_to_dry_s=75.0),
        "edge": RegionState(region="edge", state="wet", since=0.0)}))
    samples = _samples(_get(sink, "/metrics")[1])
    assert samples[("edgedsm_region_time_to_dry_seconds", (("region", "panel"),))] == 75.0
    assert ("edgedsm_region_time_to_dry_seconds", (("region", "edge"),)) not in samples


def test_a_state_change_moves_the_one(sink: MetricsSink) -> None:
    sink.publish_stats(_stats(10, state="wet", laser="unknown"))
    sink.publish_stats(_stats(20, state="dry", laser="unknown"))
    samples = _samples(_get(sink, "/metrics")[1])
    assert samples[("edgedsm_region_state", (("region", "panel"), ("state", "dry")))] == 1
    assert samples[("edgedsm_region_state", (("region", "panel"), ("state", "wet")))] == 0
    assert samples[("edgedsm_laser_on", ())] == 0
    assert samples[("edgedsm_laser_state", (("state", "unknown"),))] == 1


def test_before_any_frame_the_counters_are_0_and_no_gauge_is_made_up(sink: MetricsSink) -> None:
    samples = _samples(_get(sink, "/metrics")[1])
    # counters exist from start: increase() over them has a series before the first frame or drop
    assert samples[("edgedsm_frames_total", ())] == 0
    assert samples[("edgedsm_frames_dropped_total", (("cause", "dropped_queue"),))] == 0
    assert samples[("edgedsm_frames_dropped_total", (("cause", "dropped_invalid"),))] == 0
    assert ("edgedsm_fps", ()) not in samples and ("edgedsm_laser_on", ()) not in samples
    assert math.isnan(samples[("edgedsm_engine_ms_per_frame", ())])
    sink.publish_stats(Stats(t=1.0, frames=3, ready=False, fps=1.0, laser="off", estimator="s2"))
    samples = _samples(_get(sink, "/metrics")[1])  # no drop yet: both causes at 0
    assert samples[("edgedsm_frames_dropped_total", (("cause", "dropped_queue"),))] == 0
    assert samples[("edgedsm_frames_total", ())] == 3


def test_healthz_is_200_while_frames_flow_and_503_otherwise(sink: MetricsSink, clock: FakeClock) -> None:
    status, body = _get(sink, "/healthz")
    assert (status, body) == (503, b"no frame yet; MQTT connected\n")
    sink.frame_taken(_frame(1), 1)
    clock.now += 4.9
    assert _get(sink, "/healthz")[0] == 200
    assert _samples(_get(sink, "/metrics")[1])[("edgedsm_healthy", ())] == 1
    clock.now += 0.2
    status, body = _get(sink, "/healthz")
    assert status == 503 and b"no frame for 5.1 s" in body


def test_healthz_says_the_mqtt_link_and_a_refused_password_is_unhealthy(sink: MetricsSink, clock: FakeClock) -> None:
    sink.frame_taken(_frame(1), 1)
    assert _get(sink, "/healthz") == (200, b"frames flowing (last 0.0 s ago); MQTT connected\n")
    link = sink.link
    assert isinstance(link, Link)
    link.connected, link.last_error = False, "cannot reach 127.0.0.1:1883: Connection refused"
    status, body = _get(sink, "/healthz")  # a broker down: measuring goes on, restarting would not help
    assert status == 200 and body.endswith(b"; MQTT not connected: cannot reach 127.0.0.1:1883: Connection refused\n")
    link.refusal = "broker 127.0.0.1:1883 refused the connection: Not authorized (sent user 'line3' with a password)"
    status, body = _get(sink, "/healthz")  # frames flow, but nothing is published
    assert status == 503 and body == f"MQTT: {link.refusal}\n".encode()
    assert _samples(_get(sink, "/metrics")[1])[("edgedsm_healthy", ())] == 0
    link.refusal = None
    assert _get(sink, "/healthz")[0] == 200


def test_stats_with_more_frames_count_as_flowing_without_probes(sink: MetricsSink, clock: FakeClock) -> None:
    sink.publish_stats(_stats(10))
    assert _get(sink, "/healthz")[0] == 503  # one stats message says nothing about flow
    clock.now += 1
    sink.publish_stats(_stats(30))
    assert _get(sink, "/healthz")[0] == 200
    clock.now += 6
    sink.publish_stats(_stats(30))  # frames stopped
    assert _get(sink, "/healthz")[0] == 503


@pytest.mark.parametrize(("method", "path", "body", "status"), [
    ("GET", "/nope", None, 404), ("GET", "/metrics/../etc/passwd", None, 404), ("POST", "/metrics", b"x", 405),
    ("DELETE", "/healthz", None, 405), ("GET", "/metrics", b"x" * 10, 413)])
def test_bad_requests_are_refused_and_the_server_keeps_serving(sink: MetricsSink, method: str, path: str,
                                                               body: bytes | None, status: int) -> None:
    sink.publish_stats(_stats(5))
    got, text = _get(sink, path, method, body)
    assert got == status and str(status).encode() in text
    assert _get(sink, "/metrics")[0] == 200


def test_an_oversized_request_line_and_too_many_headers_are_refused(sink: MetricsSink) -> None:
    assert _get(sink, "/" + "a" * 70_000)[0] == 414
    assert _get(sink, "/metrics", headers={f"X-{i}": "1" for i in range(40)})[0] == 431
    assert _get(sink, "/metrics")[0] == 200


def test_a_port_in_use_is_a_config_error_naming_http_listen() -> None:
    from edgedsm.errors import ConfigError

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        with pytest.raises(ConfigError, match=r"^http.listen: cannot listen on 127.0.0.1:\d+"):
            MetricsSink(5.0).serve(("127.0.0.1", taken.getsockname()[1]))


def test_the_grafana_dashboard_uses_only_metrics_the_daemon_exposes(sink: MetricsSink) -> None:
    import json
    import re
    from pathlib import Path

    sink.publish_stats(_stats(10))
    exposed = {family.name for family in text_string_to_metric_families(_get(sink, "/metrics")[1].decode())}
    exposed |= {f"{name}_total" for name in exposed}
    dashboard = json.loads((Path(__file__).parents[3] / "docs" / "grafana-edgedsm.json").read_text())
    used = {name for panel in dashboard["panels"] for target in panel["targets"]
            for name in re.findall(r"edgedsm_[a-z_]+", target["expr"])}
    assert len(used) >= 10 and used <= exposed, used - exposed


def test_idle_connections_are_evicted_by_a_scrape_and_busy_ones_get_503(sink: MetricsSink) -> None:
    import time

    from edgedsm.publish.http_server import LIMITS

    assert sink.server is not None
    sink.frame_taken(_frame(1), 1)
    idle = [socket.create_connection(("127.0.0.1", sink.server.port)) for _ in range(4 * LIMITS.max_connections)]
    try:
        started = time.monotonic()
        assert _get(sink, "/healthz")[0] == 200  # the oldest idle connection made room
        assert time.monotonic() - started < 2.0
        counts = sink.server._server.limiter.counts()
        assert counts["open"] <= LIMITS.max_connections and counts["evicted"] >= 3 * LIMITS.max_connections
    finally:
        for connection in idle:
            connection.close()


def test_the_daemon_registers_metrics_beside_the_log_and_wires_its_probes() -> None:
    from edgedsm.config import DaemonConfig
    from edgedsm.daemon.service import make_sink
    from edgedsm.errors import ConfigError
    from edgedsm.publish.sink import FanOut, LogSink

    free = free_port()
    config = DaemonConfig.model_validate({"camera": {"uri": "sim:default"}, "http": {"listen": f"127.0.0.1:{free}"}})
    sink, probes = make_sink(config, lambda name, command: None)
    try:
        assert isinstance(sink, FanOut) and [type(s) for s in sink.sinks] == [LogSink, MetricsSink]
        metrics = sink.sinks[1]
        probes.frame_taken(_frame(1), 1)
        assert metrics.healthy()[0]
        with pytest.raises(ConfigError, match=f"http.listen: cannot listen on 127.0.0.1:{free}"):
            make_sink(config, lambda name, command: None)  # the port is taken by the first
    finally:
        sink.close(1.0)
