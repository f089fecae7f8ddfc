"""Home Assistant discovery payloads: one device, the daemon's topics, templates that render."""

from __future__ import annotations

import json

import jinja2
import pytest

from edgedsm import __version__
from edgedsm.messages import MapStats, RegionState, StateReport, Stats
from edgedsm.publish.ha_discovery import STATES, Discovery
from edgedsm.publish.topics import Topics

TOPICS = Topics.of("plant/edgedsm", "line3")


@pytest.fixture
def discovery() -> Discovery:
    return Discovery("homeassistant", TOPICS, "line3")


def _render(template: str, payload: bytes) -> str:
    # Home Assistant renders value templates with Jinja2 and `value_json` = the parsed payload
    return jinja2.Environment().from_string(template).render(value_json=json.loads(payload))


def test_every_entity_is_of_one_device_with_unique_ids(discovery: Discovery) -> None:
    entities = [*discovery.device_entities(), *discovery.region_entities("panel"),
                discovery.activity_entity("panel", "s2"), discovery.image_entity("s2")]
    assert len({e.topic for e in entities}) == len({e.config["unique_id"] for e in entities}) == 6
    for entity in entities:
        assert entity.topic.startswith("homeassistant/") and entity.topic.endswith("/config")
        assert entity.topic.split("/")[2] == "edgedsm_line3"
        assert entity.config["device"] == {"identifiers": ["edgedsm_plant_edgedsm_line3"], "name": "edgedsm line3",
                                           "manufacturer": "edgedsm", "model": "dynamic speckle activity monitor",
                                           "sw_version": __version__}


def test_region_state_is_an_enum_of_the_five_states_read_from_the_state_topic(discovery: Discovery) -> None:
    state, time_to_dry = discovery.region_entities("panel")
    assert state.topic == "homeassistant/sensor/edgedsm_line3/panel_state/config"
    assert state.config["device_class"] == "enum" and state.config["options"] == STATES
    assert state.config["state_topic"] == "plant/edgedsm/line3/state"
    assert state.config["availability_topic"] == "plant/edgedsm/line3/availability"
    report = StateReport(t=1.0, estimator="s2", regions={
        "panel": RegionState(region="panel", state="drying", since=0.5, activity=0.2, time_to_dry_s=42.5)})
    assert _render(state.config["value_template"], report.to_bytes()) == "drying"
    assert _render(time_to_dry.config["value_template"], report.to_bytes()) == "42.5"
    assert time_to_dry.config["unit_of_measurement"] == "s"
    other = StateReport(t=1.0, estimator="s2")  # region not (yet) in the payload: unknown, not an error
    assert _render(state.config["value_template"], other.to_bytes()) == "None"


def test_activity_and_laser_are_read_from_the_stats(discovery: Discovery) -> None:
    stats = Stats(t=1.0, frames=10, ready=True, fps=20.0, laser="on", estimator="s2", regions={
        "panel": {"s2": MapStats(pixels=4, mean=0.25, std=0.1, p05=0.1, median=0.2, p95=0.4)}})
    activity = discovery.activity_entity("panel", "s2")
    assert activity.config["state_topic"] == "plant/edgedsm/line3/stats"
    assert _render(activity.config["value_template"], stats.to_bytes()) == "0.25"
    assert _render(discovery.activity_entity("panel", "tau_c").config["value_template"], stats.to_bytes()) == "None"
    laser = discovery.device_entities()[0]
    assert "command_topic" not in laser.config  # read-only
    assert _render(laser.config["value_template"], stats.to_bytes()) == laser.config["payload_on"]
    unknown = stats.model_copy(update={"laser": "unknown"})
    assert _render(laser.config["value_template"], unknown.to_bytes()) == "None"


def test_the_link_entity_reads_availability_and_the_image_the_colour_map(discovery: Discovery) -> None:
    online = discovery.device_entities()[1]
    assert online.config["state_topic"] == TOPICS.availability and "availability_topic" not in online.config
    image = discovery.image_entity("s2")
    assert image.topic == "homeassistant/image/edgedsm_line3/map_s2/config"
    assert image.config["image_topic"] == "plant/edgedsm/line3/map/s2/color"
    assert image.config["content_type"] == "image/png"
