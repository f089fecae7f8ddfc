"""The Sparkplug pieces without a broker: the [sparkplug] config, payload encoding checked with
the independent wire reader, the metric book (aliases, report-by-exception, deadband), bdSeq
persistence, the primary host's STATE rules and the judging of node commands."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import BaseModel
from sparkplug_decoder import command, decode, encode_varint, key, length_delimited

from edgedsm.config import load_config
from edgedsm.errors import ConfigError
from edgedsm.messages import Alert, AlertKind, MapStats, RegionSignal, RegionState, StateReport, Stats
from edgedsm.publish.sparkplug.book import Deadband, MetricBook
from edgedsm.publish.sparkplug.commands import REBIRTH, judge
from edgedsm.publish.sparkplug.metrics import Reading, alert_readings, declared_readings, state_readings, stats_readings
from edgedsm.publish.sparkplug.payload import DataType, Metric, PayloadError, decode_command, encode
from edgedsm.publish.sparkplug.proto import sparkplug_b_pb2 as pb
from edgedsm.publish.sparkplug.session import BDSEQ_FILE, BdSeqStore, BirthLimiter, PrimaryHost, SeqCounter
from edgedsm.publish.sparkplug.settings import SparkplugSettings

CONFIG = """
[device]
name = "cam7"
state_dir = "state"
[camera]
uri = "sim:default"
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "daemon.toml"
    path.write_text(text)
    return path


# -- config -----------------------------------------------------------------------------------

def test_sparkplug_without_mqtt_is_refused_with_its_key_path(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"daemon\.toml: sparkplug: .*needs an \[mqtt\] table"):
        load_config(_write(tmp_path, CONFIG + '[sparkplug]\ngroup_id = "line1"\n'))


def test_edge_node_id_defaults_to_the_device_name(tmp_path: Path) -> None:
    config = load_config(_write(tmp_path, CONFIG + '[mqtt]\nhost = "127.0.0.1"\n[sparkplug]\ngroup_id = "line 1"\n'))
    assert config.sparkplug is not None
    assert (config.sparkplug.group_id, config.sparkplug.edge_node_id, config.sparkplug.device_id) == (
        "line 1", "cam7", "camera")


@pytest.mark.parametrize(("table", "where"), [
    ('group_id = "a/b"', "sparkplug.group_id"),
    ('group_id = "a#"', "sparkplug.group_id"),
    ('group_id = "g"\nedge_node_id = "n+1"', "sparkplug.edge_node_id"),
    ('group_id = "g"\nprimary_host_id = ""', "sparkplug.primary_host_id"),
    ('group_id = "g"\ndeadband_rel = 2.0', "sparkplug.deadband_rel"),
    ('group_id = "g"\nrebirth_min_interval_s = -1', "sparkplug.rebirth_min_interval_s"),
    ('group_id = "g"\nbdseq = 3', "sparkplug.bdseq: unknown key"),
    ("", "sparkplug.group_id: Field required"),
])
def test_bad_sparkplug_values_name_their_key(tmp_path: Path, table: str, where: str) -> None:
    with pytest.raises(ConfigError) as error:
        load_config(_write(tmp_path, CONFIG + f'[mqtt]\nhost = "h"\n[sparkplug]\n{table}\n'))
    assert where in str(error.value)


def test_every_sparkplug_field_is_described_and_numbers_bounded() -> None:
    model: type[BaseModel] = SparkplugSettings
    for name, field in model.model_fields.items():
        assert field.description and len(field.description) > 10, name
        if field.annotation in (int, float):
            kinds = {type(item).__name__ for item in field.metadata}
            assert kinds & {"Ge", "Gt"} and kinds & {"Le", "Lt"}, name


def test_the_example_config_sparkplug_table_is_valid_uncommented(repo: Path, tmp_path: Path) -> None:
    text = (repo / "config" / "daemon" / "example.toml").read_text()
    head, _, table = text.partition("\n# [sparkplug]\n")
    assert table, "example.toml has no commented [sparkplug] table"
    lines = [line.removeprefix("# ") for line in table.splitlines() if line.startswith("# ")]
    config = load_config(_write(tmp_path, head + "\n[sparkplug]\n" + "\n".join(lines) + "\n"))
    assert config.sparkplug is not None and config.sparkplug.primary_host_id == "ignition"


# -- payloads ---------------------------------------------------------------------------------

def test_birth_payload_decodes_independently_with_types_nulls_and_units() -> None:
    metrics = [Metric("bdSeq", DataType.INT64, 7, 1000, alias=1), Metric("big", DataType.INT64, -2, 1000, alias=2),
               Metric("fps", DataType.DOUBLE, 19.5, 1001, alias=3, unit="frames/s"),
               Metric("gone", DataType.DOUBLE, None, 1001, alias=4), Metric("nan", DataType.DOUBLE, float("nan"), 1001),
               Metric("laser", DataType.STRING, "on", 1002, alias=5), Metric(REBIRTH, DataType.BOOLEAN, False, 1002),
               Metric("since", DataType.DATETIME, 1_796_092_360_120, 1002, alias=6)]
    payload = decode(encode(metrics, timestamp_ms=1234, seq=0, birth=True))
    assert (payload.timestamp, payload.seq) == (1234, 0)
    by_name = payload.by_name()
    assert [m.name for m in payload.metrics] == [m.name for m in metrics]
    assert (by_name["bdSeq"].datatype_name, by_name["bdSeq"].value(), by_name["bdSeq"].alias) == ("Int64", 7, 1)
    assert by_name["big"].value() == -2  # two's complement in a uint64
    assert (by_name["fps"].value(), by_name["fps"].properties) == (19.5, {"engUnit": "frames/s"})
    for name in ("gone", "nan"):  # null: flag set, no value (non-finite floats too)
        assert (by_name[name].is_null, by_name[name].value_field) == (True, None)
    assert (by_name["laser"].value(), by_name[REBIRTH].value(), by_name[REBIRTH].alias) == ("on", False, None)
    assert by_name["since"].datatype_name == "DateTime" and by_name["since"].value() == 1_796_092_360_120


def test_data_payload_carries_aliases_only_and_death_has_no_seq() -> None:
    data = decode(encode([Metric("fps", DataType.DOUBLE, 20.0, 5, alias=3)], timestamp_ms=6, seq=255, birth=False))
    assert [(m.name, m.alias, m.datatype, m.value(10)) for m in data.metrics] == [(None, 3, None, 20.0)]
    assert data.seq == 255
    death = decode(encode([Metric("bdSeq", DataType.INT64, 4, 9)], timestamp_ms=9, seq=None, birth=True))
    assert death.seq is None and [(m.name, m.datatype, m.value()) for m in death.metrics] == [("bdSeq", 4, 4)]


def test_commands_decode_from_hand_written_wire_bytes() -> None:
    metrics = decode_command(command([{"name": REBIRTH, "datatype": 11, "boolean_value": True},
                                      {"alias": 12, "long_value": 5}]))
    assert [(m.name, m.alias, m.datatype, m.value, m.value_kind) for m in metrics] == [
        (REBIRTH, None, 11, True, "boolean_value"), (None, 12, None, 5, "long_value")]
    for bad, reason in ((b"\xff\xff\xff", "not a Sparkplug B"), (b"", "no metric")):
        with pytest.raises(PayloadError, match=reason):
            decode_command(bad)


def test_a_name_that_is_not_utf8_is_text_and_refused() -> None:
    metric = length_delimited(1, b"\xff\xfeRebirth") + key(14, 0) + encode_varint(1)
    (decoded,) = decode_command(length_delimited(2, metric))
    assert decoded.name == "\ufffd\ufffdRebirth"
    node, device = _books()
    assert "unknown metric" in judge(length_delimited(2, metric), False, node, device).refusals[0]


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_on_ncmd_never_raise(data: bytes) -> None:
    node, device = _books()
    verdict = judge(data, False, node, device)
    assert verdict.rebirth or verdict.refusals


def test_the_generated_module_matches_the_vendored_schema() -> None:
    # field numbers the spec fixes, read from the generated descriptor
    metric = pb.Payload.Metric.DESCRIPTOR.fields_by_name
    assert {name: metric[name].number for name in ("name", "alias", "timestamp", "datatype", "is_null",
                                                     "long_value", "double_value", "boolean_value")} == {
        "name": 1, "alias": 2, "timestamp": 3, "datatype": 4, "is_null": 7, "long_value": 11, "double_value": 13,
        "boolean_value": 14}
    assert (pb.Int64, pb.UInt64, pb.Double, pb.Boolean, pb.String, pb.DateTime) == (4, 8, 10, 11, 12, 13)


# -- metrics and the book ---------------------------------------------------------------------

def _stats(**overrides) -> Stats:
    region = {"s2": MapStats(pixels=10, mean=0.3, std=0.0, p05=0.3, median=0.3, p95=0.3),
              "tau_c": MapStats(pixels=10, mean=42.0, std=0.0, p05=40.0, median=42.0, p95=44.0)}
    fields = {"t": 100.0, "frames": 5, "ready": True, "fps": 20.0, "laser": "on", "estimator": "s2",
              "drops": {"dropped_queue": 2, "dropped_invalid": 1}, "regions": {"plate": region}}
    return Stats(**{**fields, **overrides})


def test_readings_are_data_driven_new_maps_and_drop_causes_appear() -> None:
    readings = stats_readings(_stats())
    assert readings["regions/plate/tau_c/mean"] == Reading(DataType.DOUBLE, 42.0, "s")  # the daemon publishes τc in s
    assert readings["drops/dropped_queue"].value == 2 and readings["frames_dropped"].value == 3
    region = RegionState(region="plate", state="drying", since=10.0, activity=0.3, time_to_dry_s=12.5)
    state = state_readings(StateReport(t=11.0, estimator="s2", laser="unknown", regions={"plate": region}))
    assert state["regions/plate/since"] == Reading(DataType.DATETIME, 10_000)
    assert (state["regions/plate/time_to_dry_s"].value, state["laser"].value) == (12.5, "unknown")
    alert = alert_readings(Alert(kind=AlertKind.FAULT, t=12.0, reason="camera lost"), 3)
    assert (alert["alerts/count"].value, alert["alerts/last_type"].value) == (3, "fault")
    assert set(declared_readings(["plate"], ["s1"])) >= {"regions/plate/s1/mean", "regions/plate/state", "fps"}


def test_each_regions_signal_quality_is_read_from_the_stats_and_declared_for_the_birth() -> None:
    signal = RegionSignal(signal="dark", mean=12.5, dark_fraction=0.75, saturated_fraction=0.0,
                          speckle_contrast=0.5, noise_floor=0.25, above_noise=0.0625, above_noise_spread=0.03125,
                          noise_model="datasheet", intensity_change=0.125, reason="signal dark: 75% of the pixels dark")
    readings = stats_readings(_stats(signal={"plate": signal}))
    assert {name: (reading.datatype, reading.value, reading.unit) for name, reading in readings.items()
            if name.startswith("regions/plate/") and not name.endswith("/mean")} == {
        "regions/plate/signal": (DataType.STRING, "dark", None),
        "regions/plate/signal_reason": (DataType.STRING, "signal dark: 75% of the pixels dark", None),
        "regions/plate/above_noise": (DataType.DOUBLE, 0.0625, None),
        "regions/plate/above_noise_spread": (DataType.DOUBLE, 0.03125, None),
        "regions/plate/noise_floor": (DataType.DOUBLE, 0.25, None),
        "regions/plate/mean_intensity": (DataType.DOUBLE, 12.5, "grey levels"),
        "regions/plate/dark_fraction": (DataType.DOUBLE, 0.75, None),
        "regions/plate/saturated_fraction": (DataType.DOUBLE, 0.0, None),
        "regions/plate/speckle_contrast": (DataType.DOUBLE, 0.5, None),
        "regions/plate/intensity_change": (DataType.DOUBLE, 0.125, None)}
    no_model = stats_readings(_stats(signal={"plate": signal.model_copy(update={"noise_floor": None,
                                                                                "above_noise": None})}))
    assert no_model["regions/plate/above_noise"].value is None and no_model["regions/plate/signal"].value == "dark"
    assert not any("signal" in name or "noise" in name for name in stats_readings(_stats()))  # noise floor off
    declared = declared_readings(["plate"], ["s2"])
    assert {name: reading for name, reading in declared.items() if name in readings} == {
        name: Reading(reading.datatype, None, reading.unit)  # the same datatypes and units, null
        for name, reading in readings.items() if name in declared}
    assert declared["regions/plate/signal"] == Reading(DataType.STRING, None)
    assert len([name for name in declared if name.startswith("regions/plate/")]) == 4 + 1 + 10
    assert not any("noise" in name for name in declared_readings(["plate"], ["s2"], signal=False))


def test_book_aliases_unique_across_books_and_births_in_time_order() -> None:
    aliases = itertools.count(1)
    node, device = MetricBook(aliases, Deadband(), no_alias=frozenset({REBIRTH})), MetricBook(aliases, Deadband())
    node.declare({REBIRTH: Reading(DataType.BOOLEAN, False), "bdSeq": Reading(DataType.INT64, 0)})
    device.declare({"a": Reading(DataType.DOUBLE, None)})
    device.update({"b": Reading(DataType.DOUBLE, 1.0)}, 50)
    assert node.alias_of(REBIRTH) is None and {node.alias_of("bdSeq"), device.alias_of("a"), device.alias_of("b")} == {
        1, 2, 3}
    birth = device.birth(now_ms=99)
    assert [(m.name, m.timestamp_ms) for m in birth] == [("b", 50), ("a", 99)]
    assert not device.needs_birth


def test_report_by_exception_with_relative_and_absolute_deadbands() -> None:
    book = MetricBook(itertools.count(1), Deadband(relative=0.05, absolute=0.01))
    book.update({"x": Reading(DataType.DOUBLE, 1.0), "s": Reading(DataType.STRING, "wet")}, 1)
    book.birth(1)
    assert book.changes() == []
    book.update({"x": Reading(DataType.DOUBLE, 1.04)}, 2)  # 4 % < 5 %
    assert book.changes() == []
    book.update({"x": Reading(DataType.DOUBLE, 1.06)}, 3)  # 6 % from the last SENT value
    assert [(m.name, m.value, m.timestamp_ms) for m in book.changes()] == [("x", 1.06, 3)]
    book.update({"x": Reading(DataType.DOUBLE, None), "s": Reading(DataType.STRING, "drying")}, 4)
    assert {(m.name, m.value) for m in book.changes()} == {("x", None), ("s", "drying")}
    book.update({"x": Reading(DataType.DOUBLE, 0.0)}, 5)
    assert [m.value for m in book.changes()] == [0.0]
    book.update({"x": Reading(DataType.DOUBLE, 0.009)}, 6)  # below the absolute band near zero
    assert book.changes() == []
    book.update({"new": Reading(DataType.UINT64, 1)}, 7)
    assert book.needs_birth and [m.name for m in book.changes()] == []  # waits for a birth
    book.update({"s": Reading(DataType.UINT64, 3)}, 8)  # datatype changed: a birth again
    assert book.needs_birth


# -- session ----------------------------------------------------------------------------------

def test_bdseq_starts_at_zero_persists_and_wraps(tmp_path: Path) -> None:
    store = BdSeqStore(tmp_path)
    assert store.next() == 0
    store.commit(0)
    assert BdSeqStore(tmp_path).next() == 1
    store.commit(255)
    assert (tmp_path / BDSEQ_FILE).read_text() == "255\n" and BdSeqStore(tmp_path).next() == 0


def test_a_corrupt_bdseq_file_starts_again_at_zero(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / BDSEQ_FILE).write_text("banana")
    assert BdSeqStore(tmp_path).next() == 0
    assert "not a bdSeq" in caplog.text


def test_a_state_dir_that_is_a_file_is_a_config_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigError, match=r"device\.state_dir: .*file"):
        BdSeqStore(tmp_path / "file")


def test_seq_counts_to_255_then_wraps() -> None:
    seq = SeqCounter()
    assert seq.birth() == 0
    values = [seq.next() for _ in range(300)]
    assert values[:2] == [1, 2] and values[254] == 255 and values[255] == 0 and values[299] == 44


def _state(online: bool, timestamp: float) -> bytes:
    return json.dumps({"online": online, "timestamp": timestamp}).encode()


def test_primary_host_state_rules() -> None:
    host = PrimaryHost("scada")
    assert host.topic == "spBv1.0/STATE/scada" and not host.online
    assert host.on_state(_state(True, 100)) == "online"
    assert host.on_state(_state(True, 50)) == "stale"  # older than the previous STATE
    assert host.on_state(_state(False, 90)) == "stale"  # the death of an older host session
    assert host.online
    assert host.on_state(_state(False, 100)) == "offline"  # same timestamp as the birth: valid
    assert host.on_state(_state(True, 200)) == "online"
    for bad in (b"ONLINE", b'{"online": "yes", "timestamp": 1}', b'{"online": true}', b"\xff",
                b'{"online": true, "timestamp": true}'):
        with pytest.raises(ValueError, match="STATE of 'scada'"):
            host.on_state(bad)
    assert host.online  # a bad message changes nothing
    first = PrimaryHost("h")
    assert first.on_state(_state(False, 5)) == "offline"  # no previous STATE: the flag is honoured


def test_births_are_rate_limited() -> None:
    limiter = BirthLimiter(2.0)
    assert limiter.wait_s(10.0) == 0.0
    limiter.record(10.0)
    assert limiter.wait_s(10.5) == pytest.approx(1.5) and limiter.wait_s(12.0) == 0.0


# -- commands ---------------------------------------------------------------------------------

def _books() -> tuple[MetricBook, MetricBook]:
    aliases = itertools.count(1)
    node, device = MetricBook(aliases, Deadband(), no_alias=frozenset({REBIRTH})), MetricBook(aliases, Deadband())
    node.declare({REBIRTH: Reading(DataType.BOOLEAN, False), "bdSeq": Reading(DataType.INT64, 0)})
    device.declare({"fps": Reading(DataType.DOUBLE, None)})
    return node, device


@pytest.mark.parametrize(("payload", "retained", "rebirth", "refusal"), [
    (command([{"name": REBIRTH, "boolean_value": True}]), False, True, None),
    (command([{"name": REBIRTH, "boolean_value": True}]), True, False, "retained"),
    (command([{"name": REBIRTH, "boolean_value": False}]), False, False, "needs the boolean value true"),
    (command([{"name": REBIRTH, "string_value": "true"}]), False, False, "needs the boolean value true"),
    (command([{"name": "fps", "long_value": 1}]), False, False, "'fps' is read-only"),
    (command([{"alias": 2, "long_value": 1}]), False, False, "'fps' is read-only"),
    (command([{"alias": 77, "boolean_value": True}]), False, False, "unknown metric alias 77"),
    (command([{"name": "Node Control/Reboot", "boolean_value": True}]), False, False, "unknown metric"),
    (command([{"datatype": 11}]), False, False, "neither name nor alias"),
    (b"\x0a", False, False, "not a Sparkplug B"),
    (command([{"name": REBIRTH, "boolean_value": True, "string_value": "x" * 70_000}]), False, False,
     "more than the 65536 accepted"),
])
def test_commands_are_judged(payload: bytes, retained: bool, rebirth: bool, refusal: str | None) -> None:
    node, device = _books()
    verdict = judge(payload, retained, node, device)
    assert verdict.rebirth is rebirth
    if refusal is None:
        assert verdict.refusals == []
    else:
        assert len(verdict.refusals) == 1 and refusal in verdict.refusals[0]


def test_a_regions_activity_carries_its_estimators_unit_in_the_birth_and_in_each_state() -> None:
    judged = {"plate": "s1", "film": "tau_c", "glass": "s2"}
    declared = declared_readings(list(judged), ["s1", "s2", "tau_c"], judged=judged)
    assert {name: declared[f"regions/{name}/activity"].unit for name in judged} == {
        "plate": "grey levels", "film": "s", "glass": None}  # the registry's units; S2 is dimensionless
    regions = {"plate": RegionState(region="plate", state="wet", since=1.0, activity=12.5),
               "film": RegionState(region="film", state="drying", since=1.0, activity=0.75, estimator="tau_c",
                                   tau_c_status="measured"),
               "glass": RegionState(region="glass", state="wet", since=1.0, activity=0.25)}
    state = state_readings(StateReport(t=2.0, estimator="s1", regions=regions))
    assert {name: state[f"regions/{name}/activity"].unit for name in regions} == {
        "plate": "grey levels", "film": "s", "glass": "grey levels"}  # glass: the report's estimator, s1
    state = state_readings(StateReport(t=2.0, estimator="s2", regions={"glass": regions["glass"]}))
    # the birth and the data agree, so a state report does not make the node announce a new birth
    assert state["regions/glass/activity"] == Reading(DataType.DOUBLE, 0.25, declared["regions/glass/activity"].unit)
    assert declared_readings(["plate"], ["s1"])["regions/plate/activity"].unit is None  # unknown: none declared
