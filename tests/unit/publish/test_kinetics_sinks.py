"""The kinetics in the sinks (issue 37): one metric a sink, its unit the registry's
(edgedsm.publish.units): Prometheus ``edgedsm_region_kinetics_seconds`` (status as a label),
Home Assistant's ``<region> τ (kinetics)`` sensor, Sparkplug's ``regions/<r>/kinetics``; τ when
ok, the bound when above or below, no number for a dark region."""

from __future__ import annotations

import json

import jinja2
from prometheus_client.parser import text_string_to_metric_families

from edgedsm.messages import RegionKinetics, Stats
from edgedsm.publish import units
from edgedsm.publish.ha_discovery import Discovery
from edgedsm.publish.prometheus import MetricsSink
from edgedsm.publish.sparkplug.metrics import kinetics_readings, stats_readings
from edgedsm.publish.topics import Topics

READINGS = {"wet": RegionKinetics(status="ok", tau_s=0.25, rate_hz=4.0, frame=90),
            "cured": RegionKinetics(status="above", bound_s=3270.5, frame=90),
            "shadow": RegionKinetics(status="dark", frame=90)}


def _stats(kinetics: dict[str, RegionKinetics]) -> Stats:
    return Stats(t=1.0, frames=100, ready=True, fps=20.0, laser="on", estimator="kinetics", kinetics=kinetics)


def test_prometheus_has_tau_or_its_bound_with_the_status_and_nothing_for_a_dark_region() -> None:
    sink = MetricsSink(stale_after_s=5.0)
    sink.publish_stats(_stats(READINGS))
    text = generate(sink)
    samples = {(s.name, tuple(sorted(s.labels.items()))): s.value for family in text_string_to_metric_families(text)
               for s in family.samples if s.name == "edgedsm_region_kinetics_seconds"}
    assert units.unit_of("kinetics") == "s"
    assert samples == {("edgedsm_region_kinetics_seconds", (("region", "wet"), ("status", "ok"))): 0.25,
                       ("edgedsm_region_kinetics_seconds", (("region", "cured"), ("status", "above"))): 3270.5}
    sink.publish_stats(_stats({}))  # [kinetics] off: no family at all
    text = generate(sink)
    assert "edgedsm_region_kinetics_seconds" not in text


def generate(sink: MetricsSink) -> str:
    return sink.exposition().decode()


def test_home_assistant_reads_tau_in_the_registry_s_unit() -> None:
    entity = Discovery("homeassistant", Topics.of("edgedsm", "line3"), "line3").kinetics_entity("wet")
    assert entity.config["unit_of_measurement"] == "s" and entity.config["device_class"] == "duration"
    assert entity.config["name"] == "wet τ (kinetics)" and entity.config["state_topic"].endswith("/stats")
    render = jinja2.Environment().from_string(entity.config["value_template"])
    payload = json.loads(_stats(READINGS).to_bytes())
    assert render.render(value_json=payload) == "0.25"
    shadow = Discovery("homeassistant", Topics.of("edgedsm", "line3"), "line3").kinetics_entity("shadow")
    assert jinja2.Environment().from_string(shadow.config["value_template"]).render(value_json=payload) == "None"


def test_sparkplug_carries_tau_with_its_unit_and_status() -> None:
    readings = stats_readings(_stats(READINGS))
    assert readings["regions/wet/kinetics"].value == 0.25 and readings["regions/wet/kinetics"].unit == "s"
    assert readings["regions/cured/kinetics"].value == 3270.5
    assert readings["regions/cured/kinetics_status"].value == "above"
    assert readings["regions/shadow/kinetics"].value is None and readings["regions/shadow/kinetics_status"].value == \
        "dark"
    assert kinetics_readings("wet", READINGS["wet"]).keys() == {"regions/wet/kinetics", "regions/wet/kinetics_status"}
    assert not any("kinetics" in name for name in stats_readings(_stats({})))
