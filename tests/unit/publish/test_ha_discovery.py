"""Home Assistant discovery payloads: one device, the daemon's topics, templates that render."""

from __future__ import annotations

import json

import jinja2
import pytest

from edgedsm import __version__
from edgedsm.messages import MapStats, RegionActivity, RegionSignal, RegionState, StateReport, Stats
from edgedsm.publish.ha_discovery import SIGNALS, STATES, Discovery
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
                discovery.activity_entity("panel", "1"), discovery.map_mean_entity("panel", "s2"),
                discovery.image_entity("s2")]
    assert len({e.topic for e in entities}) == len({e.config["unique_id"] for e in entities}) == 7
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
    judged = RegionActivity(value=0.0625, estimator="s2", unit="1", basis="above_noise")
    stats = Stats(t=1.0, frames=10, ready=True, fps=20.0, laser="on", estimator="s2", activity={"panel": judged},
                  regions={"panel": {"s1": MapStats(pixels=4, mean=3.5, std=1, p05=1, median=3, p95=6),
                                     "s2": MapStats(pixels=4, mean=0.25, std=0.1, p05=0.1, median=0.2, p95=0.4)}})
    # `activity`: the value the thresholds judge, not the plain mean beside it
    activity = discovery.activity_entity("panel", "1")
    assert activity.topic == "homeassistant/sensor/edgedsm_line3/panel_activity/config"
    assert activity.config["state_topic"] == "plant/edgedsm/line3/stats" and activity.config["name"] == "panel activity"
    assert _render(activity.config["value_template"], stats.to_bytes()) == "0.0625"
    assert "unit_of_measurement" not in activity.config  # dimensionless: a bare number
    held = stats.model_copy(update={"activity": {"panel": judged.model_copy(update={"value": None})}})
    assert _render(activity.config["value_template"], held.to_bytes()) == "None"
    assert discovery.activity_entity("panel", "s").config["unit_of_measurement"] == "s"  # judged on τc
    s2, s1 = discovery.map_mean_entity("panel", "s2"), discovery.map_mean_entity("panel", "s1")
    assert s2.config["name"] == "panel S2 mean" and "unit_of_measurement" not in s2.config
    assert s1.config["name"] == "panel S1 mean" and s1.config["unit_of_measurement"] == "grey levels"
    assert _render(s2.config["value_template"], stats.to_bytes()) == "0.25"
    assert _render(s1.config["value_template"], stats.to_bytes()) == "3.5"
    assert _render(discovery.map_mean_entity("panel", "tau_c").config["value_template"], stats.to_bytes()) == "None"
    laser = discovery.device_entities()[0]
    assert "command_topic" not in laser.config  # read-only
    assert _render(laser.config["value_template"], stats.to_bytes()) == laser.config["payload_on"]
    unknown = stats.model_copy(update={"laser": "unknown"})
    assert _render(laser.config["value_template"], unknown.to_bytes()) == "None"


def test_the_signal_quality_and_the_activity_above_the_noise_are_read_from_the_stats(discovery: Discovery) -> None:
    signal, above = discovery.signal_entities("panel")
    assert signal.topic == "homeassistant/sensor/edgedsm_line3/panel_signal/config" and signal.region == "panel"
    assert signal.config["device_class"] == "enum" and SIGNALS == ["ok", "low", "dark", "saturated", "not_speckle"]
    assert signal.config["options"] == SIGNALS and signal.config["json_attributes_topic"] == TOPICS.stats
    assert above.topic == "homeassistant/sensor/edgedsm_line3/panel_above_noise/config"
    assert above.config["state_topic"] == signal.config["state_topic"] == "plant/edgedsm/line3/stats"
    light = RegionSignal(signal="saturated", mean=240.5, dark_fraction=0.0, saturated_fraction=0.25,
                         speckle_contrast=0.5, noise_floor=0.125, above_noise=0.0625, above_noise_spread=0.03125,
                         noise_model="frames", intensity_change=1.5, reason="signal saturated: 25% of the pixels")
    stats = Stats(t=1.0, frames=10, ready=True, fps=20.0, laser="on", estimator="s2", signal={"panel": light})
    assert _render(signal.config["value_template"], stats.to_bytes()) == "saturated"
    assert _render(above.config["value_template"], stats.to_bytes()) == "0.0625"
    attributes = json.loads(_render(signal.config["json_attributes_template"], stats.to_bytes()))
    assert attributes == {"signal": "saturated", "mean": 240.5, "dark_fraction": 0.0, "saturated_fraction": 0.25,
                          "speckle_contrast": 0.5, "noise_floor": 0.125, "above_noise": 0.0625,
                          "above_noise_spread": 0.03125, "noise_model": "frames", "intensity_change": 1.5,
                          "reason": "signal saturated: 25% of the pixels"}
    no_model = stats.model_copy(update={"signal": {"panel": light.model_copy(update={"above_noise": None})}})
    assert _render(above.config["value_template"], no_model.to_bytes()) == "None"
    off = stats.model_copy(update={"signal": {}})  # estimator.noise_floor off: unknown, not an error
    assert _render(signal.config["value_template"], off.to_bytes()) == "None"
    assert json.loads(_render(signal.config["json_attributes_template"], off.to_bytes())) == {}


def test_the_link_entity_reads_availability_and_the_image_the_colour_map(discovery: Discovery) -> None:
    online = discovery.device_entities()[1]
    assert online.config["state_topic"] == TOPICS.availability and "availability_topic" not in online.config
    image = discovery.image_entity("s2")
    assert image.topic == "homeassistant/image/edgedsm_line3/map_s2/config"
    assert image.config["image_topic"] == "plant/edgedsm/line3/map/s2/color"
    assert image.config["content_type"] == "image/png"
