"""The docs equal the payloads: a real daemon (simulated drying plate, `estimator.noise_floor` on, as
by default) with every sink (MQTT JSON, Home Assistant, Sparkplug B, Prometheus) on a REAL
mosquitto, and what it publishes compared with what docs/mqtt.md, docs/integration.md and
docs/sparkplug.md say:

- every field a JSON payload carries is documented (the section's example or its table), and every
  documented field is published or its table row says when it is absent ("present only ...",
  "absent", "when τc is estimated", "with `[recording]`" ...);
- every Prometheus metric, Home Assistant entity and Sparkplug metric published is in its table,
  and every one in the table is published (or said to appear only under a condition);
- the judged activity is ONE number: the state report's ``activity``, the stats' ``activity``,
  Prometheus ``edgedsm_region_activity``, Home Assistant's ``<region> activity``, Sparkplug's
  ``regions/<r>/activity`` and the dashboard's history API (its chart) agree, and it is below the
  plain S2 mean by the noise floor.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jinja2
import pytest
from helpers_daemon import Daemon, base_config, http_get, write_config
from helpers_dashboard import DashboardProcess
from helpers_mqtt import REPO, WAIT_S, Broker, Subscriber, free_port, wait_until
from prometheus_client.parser import text_string_to_metric_families

from edgedsm.messages import DROP_CAUSES
from edgedsm.publish import Topics
from tests.sparkplug_decoder import decode

pytestmark = [pytest.mark.integration, pytest.mark.slow]

TOPICS = Topics.of("edgedsm", "e2e")
DOCS = REPO / "docs"
#: A table row that says its field is not always there.
CONDITIONAL = re.compile(r"present only|absent|`\{\}`|when τc is estimated|with `\[|once a|when the engine computes")
#: A sink's row that is published only with a section this daemon does not turn on (the kinetics).
OFF_HERE = "with `[kinetics]` on"
#: For each payload, the objects whose keys are names (regions, maps, causes...), not fields.
DYNAMIC = {"state": {"regions"}, "region": set(), "alert": set(), "reply": {"result"}, "meta": set(),
           "stats": {"drops", "camera", "activity", "regions", "regions.*", "state", "tau_c", "kinetics", "signal",
                     "mqtt"}}


# -- what the docs say ------------------------------------------------------------------------------

def _section(text: str, heading: str) -> str:
    start = text.index(f"\n## {heading}")
    end = text.find("\n## ", start + 1)
    return text[start:] if end < 0 else text[start:end]


def _example(section: str) -> dict[str, Any]:
    match = re.search(r"```json\n(.*?)```", section, re.S)
    assert match is not None, section[:80]
    return json.loads(match.group(1))


def _rows(section: str) -> list[tuple[list[str], str]]:
    """(names of the first cell, the whole row) of each table row; ``.x`` after ``a.b.c`` is ``a.b.x``."""
    rows = []
    for line in section.splitlines():
        if not line.startswith("| `"):
            continue
        first = line.split("|")[1]
        names: list[str] = []
        for name in re.findall(r"`([^`]+)`", first):
            if name.startswith(".") and names:
                name = names[-1].rsplit(".", 1)[0] + name
            names.append(name)
        rows.append((names, line))
    return rows


def _normal(name: str) -> str:
    return re.sub(r"<[a-z]+>", "*", name)


def _paths(value: Any, dynamic: set[str], prefix: str = "") -> set[str]:
    """Dotted paths of every key, the keys of ``dynamic`` objects as ``*``."""
    out: set[str] = set()
    if isinstance(value, dict):
        for key, item in value.items():
            path = ".".join(filter(None, [prefix, "*" if prefix in dynamic else key]))
            out.add(path)
            out |= _paths(item, dynamic, path)
    return out


def _documented(section: str, kind: str) -> tuple[set[str], set[str], set[str]]:
    """(paths of the example, paths of the table, paths whose row says when they are absent)."""
    example = _paths(_example(section), DYNAMIC[kind]) if "```json" in section else set()
    table, conditional = set(), set()
    for names, row in _rows(section):
        for name in names:
            path = _normal(name)
            table.add(path)
            if CONDITIONAL.search(row):
                conditional.add(path)
    return example, table, conditional


def _check(kind: str, published: set[str], documented: tuple[set[str], set[str], set[str]]) -> None:
    example, table, conditional = documented
    undocumented = published - example - table
    assert not undocumented, f"{kind}: published but not in the docs: {sorted(undocumented)}"

    def excused(path: str) -> bool:  # the field or one of its parents is said to be absent at times
        parts = path.split(".")
        return any(".".join(parts[:n]) in conditional for n in range(1, len(parts) + 1))

    missing = {path for path in example | table if path not in published and not excused(path)}
    assert not missing, f"{kind}: in the docs but not published, and no row says when: {sorted(missing)}"


# -- the run ----------------------------------------------------------------------------------------

def _json(subscriber: Subscriber, topic: str) -> list[dict[str, Any]]:
    return [m.json() for m in subscriber.on(topic) if m.payload]


@pytest.mark.timeout(150)
def test_every_payload_field_is_documented_and_every_sink_carries_the_one_judged_activity(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    http_port = free_port()
    config = base_config(tmp_path, port=broker.port)
    config["cadence"]["maps_interval_s"] = 1.0
    config["homeassistant"] = {"discovery_prefix": "homeassistant"}
    config["sparkplug"] = {"group_id": "line3"}
    config["http"] = {"listen": f"127.0.0.1:{http_port}", "stale_after_s": 3.0}
    live = subscribers(broker.port, [f"{TOPICS.base}/#", "homeassistant/#", "spBv1.0/#"])
    dashboard = DashboardProcess(["--broker", f"127.0.0.1:{broker.port}", "--listen", "127.0.0.1:0",
                                  "--database", str(tmp_path / "history.sqlite3")])
    try:
        wait_until(lambda: json.loads(dashboard.get("/api/info"))["broker_connected"], WAIT_S, "the dashboard")
        daemon = daemons(write_config(tmp_path / "daemon.toml", config))
        _run_and_check(daemon, live, dashboard, http_port)
    finally:
        dashboard.stop()


def _run_and_check(daemon: Daemon, live: Subscriber, dashboard: DashboardProcess, http_port: int) -> None:
    # the plate goes wet -> drying -> dry in ~12 s at this pace; its alerts carry from/to/activity
    daemon.wait_until(lambda: any(a.get("to") == "dry" for a in _json(live, TOPICS.alerts)), 90, "the plate dry")
    daemon.wait_until(lambda: len(_json(live, f"{TOPICS.map('s2')}/meta")) >= 2, WAIT_S, "map metas")
    request = {"request_id": "docs-1"}
    live.client.publish(TOPICS.command("publish_maps"), json.dumps(request), qos=1)
    daemon.wait_until(lambda: _json(live, TOPICS.reply("publish_maps")), WAIT_S, "the command's reply")
    daemon.wait_until(lambda: http_get(http_port, "/healthz")[0] == 200, WAIT_S, "/healthz 200")
    scraped = [http_get(http_port, "/metrics")[1].decode()]
    time.sleep(1.0)  # the dashboard writes its history every 0.5 s
    start = min(m.json()["t"] for m in live.on(TOPICS.stats))
    history = json.loads(dashboard.get(f"/api/history?device=e2e&region=plate&from={start - 1}&to={time.time() + 5}"))
    code, _ = daemon.terminate()
    assert code == 0, daemon.log
    wait_until(lambda: any(s.get("availability") == "offline" for s in _json(live, TOPICS.state)), WAIT_S,
               "the last word")

    mqtt_doc = (DOCS / "mqtt.md").read_text(encoding="utf-8")
    states, stats = _json(live, TOPICS.state), _json(live, TOPICS.stats)
    alerts, metas = _json(live, TOPICS.alerts), _json(live, f"{TOPICS.map('s2')}/meta")
    regions = _json(live, TOPICS.region_state("plate"))
    replies = _json(live, TOPICS.reply("publish_maps"))

    # -- 1. docs/mqtt.md: every JSON payload's fields -----------------------------------------------
    state_section = _section(mqtt_doc, "State report")
    _check("state", set().union(*(_paths(s, DYNAMIC["state"]) for s in states)),
           _documented(state_section, "state"))
    # <base>/state/<region>: one region's object, documented under regions.<name>
    in_region = [{p.removeprefix("regions.*.") for p in paths if p.startswith("regions.*.")}
                 for paths in _documented(state_section, "state")]
    _check("state/<region>", set().union(*(_paths(r, set()) for r in regions)),
           (in_region[0], in_region[1], in_region[2]))
    _check("stats", set().union(*(_paths(s, DYNAMIC["stats"]) for s in stats)),
           _documented(_section(mqtt_doc, "Statistics"), "stats"))
    _check("alerts", set().union(*(_paths(a, DYNAMIC["alert"]) for a in alerts)),
           _documented(_section(mqtt_doc, "Alerts"), "alert"))
    _check("map meta", set().union(*(_paths(m, DYNAMIC["meta"]) for m in metas)),
           _documented(_section(mqtt_doc, "Maps"), "meta"))
    reply_section = _section(mqtt_doc, "Commands").split("Reply (QoS 1)")[1]  # not the commands' own table
    _check("reply", set().union(*(_paths(r, DYNAMIC["reply"]) for r in replies)),
           _documented(reply_section, "reply"))
    # counters exist from start at 0, as the example shows them
    assert set(stats[0]["drops"]) == set(DROP_CAUSES) == set(_example(_section(mqtt_doc, "Statistics"))["drops"])

    # -- 2. docs/integration.md: Prometheus metrics and Home Assistant entities -----------------------
    integration = (DOCS / "integration.md").read_text(encoding="utf-8")
    prometheus = _section(integration, "Prometheus and Grafana")
    families = list(text_string_to_metric_families(scraped[0]))
    published = {sample.name for family in families for sample in family.samples}
    documented = {name for names, _ in _rows(prometheus) for name in names if name.startswith("edgedsm_")}
    conditional = {name for names, row in _rows(prometheus) for name in names
                   if re.search(r"when τc is estimated|absent until", row) or OFF_HERE in row}
    assert published <= documented, f"metrics not in docs/integration.md: {sorted(published - documented)}"
    assert documented - published <= conditional, sorted(documented - published - conditional)
    samples = {(s.name, tuple(sorted(s.labels.items()))): s.value for f in families for s in f.samples}
    for cause in DROP_CAUSES:  # counters from start: an increase() rule has its series
        assert samples[("edgedsm_frames_dropped_total", (("cause", cause),))] == 0

    entities = _section(integration, "Home Assistant (MQTT discovery)")
    names, off_here = set(), set()
    for cell, row in _rows(entities):
        names |= {name.removeprefix("<region> ") for name in cell}
        off_here |= {name.removeprefix("<region> ") for name in cell} if OFF_HERE in row else set()
    configs = {m.topic: json.loads(m.payload) for m in live.messages
               if m.topic.startswith("homeassistant/") and m.topic.endswith("/config") and m.payload}
    announced = {config["name"].removeprefix("plate ") for config in configs.values()}
    assert announced <= names, f"Home Assistant entities not in the docs: {sorted(announced - names)}"
    assert names - announced <= {"…", "..."} | off_here, sorted(names - announced)

    # -- 3. docs/sparkplug.md: node and device metrics ---------------------------------------------------
    sparkplug = (DOCS / "sparkplug.md").read_text(encoding="utf-8")
    metrics_section = _section(sparkplug, "Metrics")
    node_doc, device_doc = metrics_section.split("Device (DBIRTH, DDATA)")
    births = {kind: decode(next(m.payload for m in live.messages if f"/{kind}/" in m.topic))
              for kind in ("NBIRTH", "DBIRTH")}

    def normal(name: str) -> str:
        name = re.sub(r"^regions/plate/", "regions/<r>/", name)
        name = re.sub(r"^regions/<r>/(s1|s2|s3)/mean$", "regions/<r>/<map>/mean", name)
        return re.sub(r"^drops/\w+$", "drops/<cause>", name)

    for kind, doc in (("NBIRTH", node_doc), ("DBIRTH", device_doc)):
        born = {normal(metric.name) for metric in births[kind].metrics if metric.name}
        listed = {name for cell, _ in _rows(doc) for name in cell if "/" in name or name.isidentifier()
                  or " " in name}
        when = {name for cell, row in _rows(doc) for name in cell if "when τc is estimated" in row or OFF_HERE in row}
        assert born <= listed, f"{kind}: not in docs/sparkplug.md: {sorted(born - listed)}"
        assert listed - born <= when, f"{kind}: documented, not born: {sorted(listed - born - when)}"

    # -- 4. one judged activity, everywhere ---------------------------------------------------------------
    judged = [s["activity"]["plate"] for s in stats if s["activity"]["plate"]["value"] is not None]
    assert judged and {(j["estimator"], j["unit"]) for j in judged} == {("s2", "1")}
    assert judged[-1]["basis"] == "above_noise"
    last = stats[-1]
    floor = last["signal"]["plate"]["noise_floor"]
    assert floor > 0 and last["activity"]["plate"]["value"] < last["regions"]["plate"]["s2"]["mean"]
    # a state report and the stats of the same evaluation carry the same number (both made from it)
    pairs = [(report, other) for report in states if report["availability"] == "online"
             for other in stats if abs(other["t"] - report["t"]) < 0.05]
    assert len(pairs) >= 2
    for report, other in pairs:
        assert report["regions"]["plate"].get("activity") == other["activity"]["plate"]["value"]
    values = {s["activity"]["plate"]["value"] for s in stats}
    exposed = samples[("edgedsm_region_activity", (("estimator", "s2"), ("region", "plate"), ("unit", "1")))]
    assert exposed in values  # one of the stats' numbers (scraped between two of them), not the plain mean
    sensor = next(c for c in configs.values() if c["name"] == "plate activity")
    rendered = jinja2.Environment().from_string(sensor["value_template"]).render(value_json=last)
    assert float(rendered) == last["activity"]["plate"]["value"] and "unit_of_measurement" not in sensor
    aliases = {m.alias: m.name for m in births["DBIRTH"].metrics}
    sent = [metric.value() for m in live.messages if "/DDATA/" in m.topic for metric in decode(m.payload).metrics
            if aliases.get(metric.alias) == "regions/plate/activity" and not metric.is_null]
    reported = {report["regions"]["plate"].get("activity") for report in states}
    assert sent and set(sent) <= reported, (sent[:5], sorted(reported)[:5])
    assert reported & values  # the report's numbers are the stats' numbers
    # the dashboard's history (its chart and CSV): the stats' judged numbers, point for point
    plotted = [activity for _, activity, _ in history["points"] if activity is not None]
    assert len(plotted) >= 10 and set(plotted) <= values, (plotted[:5], sorted(values)[:5])
    print(f"judged activity: last {last['activity']['plate']['value']:.4g} (S2 mean "
          f"{last['regions']['plate']['s2']['mean']:.4g}, floor {floor:.4g}); {len(pairs)} report/stats pairs, "
          f"{len(sent)} Sparkplug values; {len(published)} metrics, {len(announced)} entities checked")
