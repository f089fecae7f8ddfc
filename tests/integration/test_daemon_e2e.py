"""The daemon end to end: `edgedsm run -c CONFIG` as a real process (or `Service` in a thread
where a test must look inside) against a REAL mosquitto on a free loopback port, with the
simulated drying plate (config/scenes/drying_demo.toml, paced 5x faster than real time) or a
replayed recording as the camera, and the simulated relay or a PTY-emulated Modbus board as
the laser.

Alerts are checked the way a subscriber must consume them (edgedsm.publish.mqtt): at least
once, deduplicated on (stream, seq); "exactly once" means exactly once after deduplication.
Across a broker restart the broker keeps sessions (persistence on) and the subscriber uses a
persistent session (fixed client id, clean session off, QoS 1).

Each test bounds its own time (pytest-timeout) and every wait has its own limit.
mosquitto and socat are required: without them these tests FAIL.
"""

from __future__ import annotations

import itertools
import os
import re
import signal
import socket
import threading
import time
import uuid
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers_commands import KEY_TEXT, signed
from helpers_daemon import (
    DEMO_PLATE,
    DRYING_SCENE,
    SIM_CAMERA,
    Daemon,
    base_config,
    collapse,
    distinct_alerts,
    frames_published,
    last_stats,
    moves,
    region_states,
    service_thread,
    toml_text,
    wait_frames_beyond,
    write_config,
)
from helpers_mqtt import WAIT_S, Broker, Subscriber, wait_until
from helpers_relay import OFF, ON, READ, ModbusBoard, NumatoBoard, open_pty_pair

from edgedsm.devices.laser import simulated_board
from edgedsm.estimators import all_maps
from edgedsm.publish import Topics, decode_map
from edgedsm.sim import load_scene, simulate

pytestmark = [pytest.mark.integration, pytest.mark.slow]

CYCLE = [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")]
STATES = ["warming_up", "wet", "drying", "dry"]
STOP_BOUND_S = 2.0  # SIGTERM → exit, as the issue demands
MODBUS = "protocol=modbus&slave=7&channel=5"  # the frames in helpers_relay are for this board


# -- 1. a drying plate, alerts exactly once across broker and daemon restarts ---------------

@pytest.mark.alone
@pytest.mark.timeout(150)
def test_drying_states_and_alerts_exactly_once_across_broker_and_daemon_restarts(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    broker = make_broker(persistence=True)
    topics = Topics.of("edgedsm", "e2e")
    config = write_config(tmp_path / "daemon.toml", base_config(tmp_path, port=broker.port, laser="sim:e2e"))
    scada = subscribers(broker.port, [topics.availability, topics.state, topics.alerts], client_id="e2e-scada")

    first = daemons(config)
    scada.wait_for(topics.availability, lambda m: m.payload == b"online", "availability online", timeout=30)
    wait_until(lambda: moves(distinct_alerts(scada, topics)) == CYCLE[:1], 30, "the alert warming_up -> wet")

    # The broker restarts in mid-run, and an alert is raised while it is down.
    broker.stop()
    went_down = time.monotonic()
    raised = first.wait_log(r"region plate: wet -> drying", 60)
    assert raised > went_down, "the alert was raised before the broker went down: the test proves nothing"
    broker.start()
    wait_until(lambda: len(distinct_alerts(scada, topics)) >= 2, WAIT_S, "the alert raised while the broker was down")

    # The broker goes down again; the next alert is stored but never acknowledged, and the
    # daemon is stopped (SIGTERM) before it can send it. A new daemon on the same state
    # directory must deliver it, then continue the numbering.
    broker.stop()
    went_down = time.monotonic()
    raised = first.wait_log(r"region plate: drying -> dry", 60)
    assert raised > went_down
    code, took = first.terminate()
    assert code == 0 and took < STOP_BOUND_S, first.log
    assert len(distinct_alerts(scada, topics)) == 2  # alert 3 has not reached anybody yet
    broker.start()
    states_before = len(scada.on(topics.state))
    second = daemons(config)
    wait_until(lambda: len(distinct_alerts(scada, topics)) >= 6, 90, "six distinct alerts (two drying cycles)")
    code, took = second.terminate()
    assert code == 0 and took < STOP_BOUND_S, second.log
    scada.wait_for(topics.availability, lambda m: m.payload == b"offline", "availability offline")
    time.sleep(0.3)  # anything still in flight (there must be nothing new)

    alerts = distinct_alerts(scada, topics)
    assert [a["seq"] for a in alerts] == [1, 2, 3, 4, 5, 6]
    assert len({a["stream"] for a in alerts}) == 1
    assert moves(alerts) == CYCLE + CYCLE
    assert all(a["region"] == "plate" and a["type"] == "transition" for a in alerts)
    # resent copies (at least once) are byte-for-byte the same alert
    by_key = {(a["stream"], a["seq"]): a for a in alerts}
    assert all(raw == by_key[(raw["stream"], raw["seq"])] for raw in scada.alerts(topics))
    # the thresholds were really crossed: S2 activity falls through the cycle
    activities = [a["activity"] for a in alerts[:3]]
    wet, dry = DEMO_PLATE["wet_above"], DEMO_PLATE["dry_below"]
    assert activities[0] >= wet and dry < activities[1] < wet * 0.95 and activities[2] <= dry * 0.95

    # States in order: the second daemon's live states went through the whole cycle; the first
    # one's never went backwards (some were published while the broker was down).
    messages = scada.on(topics.state)
    assert collapse(region_states([m for m in messages[states_before:] if not m.retain], "plate")) == STATES
    first_run = [STATES.index(s) for s in collapse(region_states(messages[:states_before], "plate"))]
    assert first_run == sorted(first_run) and {1, 2} <= set(first_run)
    availability = [m.payload for m in scada.on(topics.availability)]
    assert availability.count(b"online") >= 2 and availability[-1] == b"offline"


# -- 2. published maps decode to the engine's maps ------------------------------------------

def _last_maps(subscriber: Subscriber, topics: Topics) -> dict[str, tuple[np.ndarray, dict[str, Any]]]:
    """The newest decoded map per estimator, each paired with its meta by CRC-32."""
    found: dict[str, tuple[np.ndarray, dict[str, Any]]] = {}
    for name in ("s1", "s2", "s3"):
        metas = {meta["png_crc32"]: meta for meta in (m.json() for m in subscriber.on(topics.map_meta(name)))}
        for message in subscriber.on(topics.map(name)):
            meta = metas.get(zlib.crc32(message.payload))
            assert meta is not None, f"a {name} PNG arrived without its meta"
            if name not in found or meta["frames"] >= found[name][1]["frames"]:
                found[name] = (decode_map(message.payload, meta), meta)
    return found


@pytest.mark.timeout(90)
def test_final_published_maps_decode_to_the_engine_maps_within_one_quantization_step(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    scene = load_scene(DRYING_SCENE)
    scene.scene.size = 64
    total, window, lag, q = 300, 100, 5, 1.0  # frames 200..300: the plate starts drying
    recording = np.stack(list(itertools.islice(simulate(scene), total)))
    assert recording.dtype == np.uint8 and recording.shape == (total, 64, 64)
    np.save(tmp_path / "frames.npy", recording)

    broker = make_broker()
    topics = Topics.of("edgedsm", "e2e")
    config = base_config(tmp_path, port=broker.port, camera=f"replay:{tmp_path / 'frames.npy'}?rate=100")
    config["acquisition"].update(queue_frames=10_000)  # dark_frames = 0, no laser: every frame is measured
    config["estimator"].update(window=window, lag=lag, q=q)
    subscriber = subscribers(broker.port, [topics.stats, topics.maps_filter, f"{topics.base}/map/+/meta"])
    daemon = daemons(write_config(tmp_path / "daemon.toml", config))
    assert daemon.wait(60) == 0, daemon.log  # a finite stream ends the daemon normally
    assert "camera stream ended" in daemon.log

    wait_until(lambda: {"s1", "s2", "s3"} <= set(_last_maps(subscriber, topics)), 5, "the final maps")
    maps = _last_maps(subscriber, topics)
    stats = last_stats(subscriber, topics)
    assert stats is not None and stats["frames"] == total and not stats["drops"].get("dropped_queue")
    expected = all_maps(recording[-window:], lag, q=q)
    earlier = all_maps(recording[-window - 25:-25], lag, q=q)
    for name, (decoded, meta) in maps.items():
        assert meta["frames"] == total and meta["window"] == window and meta["lag"] == lag
        assert meta["shape"] == [64, 64] and not meta["downsampled"]
        step = meta["scale"]
        assert 0 < step < 1e-3 * float(np.ptp(expected[name]))
        error = np.abs(decoded - expected[name]).max()
        assert error <= step / 2 * (1 + 1e-9) + 1e-12, f"{name}: off by {error / step:.3f} steps"
        # the check is sharp: the window 25 frames earlier is many steps away
        assert np.abs(decoded - earlier[name]).max() > 20 * step, name


# -- 3. SIGTERM: exit 0 within 2 s, 'offline', laser left off -------------------------------

@pytest.mark.alone
@pytest.mark.timeout(60)
def test_stop_leaves_the_simulated_laser_off_and_publishes_offline(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        sim_board_name: str) -> None:
    broker = make_broker()
    topics = Topics.of("edgedsm", "e2e")
    board = simulated_board(sim_board_name)
    config = write_config(tmp_path / "daemon.toml",
                          base_config(tmp_path, port=broker.port, laser=f"sim:{sim_board_name}"))
    subscriber = subscribers(broker.port, [topics.availability, topics.stats])
    with service_thread(config) as (service, result):
        subscriber.wait_for(topics.availability, lambda m: m.payload == b"online", "online", timeout=30)
        wait_until(lambda: board.is_on, 30, "the laser on (measuring)")
        measured = wait_frames_beyond(subscriber, topics, 50)
        assert board.is_on and last_stats(subscriber, topics)["laser"] == "on"  # type: ignore[index]
        started = time.monotonic()
        service.stop()  # what the SIGTERM handler does
        result["thread"].join(STOP_BOUND_S)
        took = time.monotonic() - started
        assert not result["thread"].is_alive() and took < STOP_BOUND_S
    assert result["code"] == 0 and measured > 50
    assert not board.is_on
    history = board.history
    last_on = max(i for i, s in enumerate(history) if s.on)
    assert not history[0].on and not history[-1].on and last_on < len(history) - 1
    assert 0 <= history[last_on + 1].t_ns / 1e9 - started < STOP_BOUND_S  # off once asked to stop, promptly
    subscriber.wait_for(topics.availability, lambda m: m.payload == b"offline", "offline", timeout=5)
    assert subscriber.on(topics.availability)[-1].payload == b"offline"


@pytest.mark.alone
@pytest.mark.timeout(60)
def test_sigterm_leaves_a_modbus_board_off_with_the_exact_bytes(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    broker = make_broker()
    topics = Topics.of("edgedsm", "e2e")
    subscriber = subscribers(broker.port, [topics.availability, topics.stats])
    with open_pty_pair(tmp_path) as pair:
        board = ModbusBoard(pair.board, channel=5, slave=7)
        board.start()
        try:
            config = base_config(tmp_path, port=broker.port, laser=f"serial:{pair.app}?{MODBUS}")
            daemon = daemons(write_config(tmp_path / "daemon.toml", config))
            wait_until(lambda: board.is_on, 30, "the emulated board's relay on (measuring)")
            wait_frames_beyond(subscriber, topics, 50)
            assert board.is_on and last_stats(subscriber, topics)["laser"] == "on"  # type: ignore[index]
            before_stop = board.frames()
            code, took = daemon.terminate()
            assert code == 0 and took < STOP_BOUND_S, daemon.log
            assert not board.is_on
            frames = board.frames()
        finally:
            board.stop()
        assert board.errors == []
    # Off (with readback) at start by the safety guard and by the pipeline, off for the dark
    # frames, on to measure; at SIGTERM off by the pipeline, then by the safety guard as it
    # closes the relay: every switching is read back, and nothing else is sent but the
    # periodic readback checks while the laser is on.
    off, on = [OFF["modbus"], READ["modbus"]], [ON["modbus"], READ["modbus"]]
    start = off * 3 + on
    assert before_stop[:len(start)] == start and set(before_stop[len(start):]) <= {READ["modbus"]}
    assert frames[:len(before_stop)] == before_stop and frames[len(before_stop):] == off * 2
    subscriber.wait_for(topics.availability, lambda m: m.payload == b"offline", "offline", timeout=5)


@pytest.mark.timeout(90)
def test_a_numato_board_gone_silent_while_on_is_unknown_faulted_and_exit_69(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    """Issue 11: the board dies with the relay ON. Stats must say 'unknown' (never 'off'), a
    fault alert must say why, and at SIGTERM the daemon must say the laser may still be on:
    CRITICAL in the log, a fault alert before 'offline', exit 69."""
    broker = make_broker()
    topics = Topics.of("edgedsm", "e2e")
    subscriber = subscribers(broker.port, [topics.availability, topics.stats, topics.alerts])
    with open_pty_pair(tmp_path) as pair:
        board = NumatoBoard(pair.board, channel=11)
        board.start()
        try:
            config = base_config(tmp_path, port=broker.port, laser=f"serial:{pair.app}?protocol=numato&channel=11")
            daemon = daemons(write_config(tmp_path / "daemon.toml", config))
            wait_until(lambda: board.is_on, 30, "the emulated Numato relay on (measuring)")
            wait_frames_beyond(subscriber, topics, 50)
            assert last_stats(subscriber, topics)["laser"] == "on"  # type: ignore[index]
            board.mode = "silent"  # dead with the contact closed
            silenced = time.monotonic()
            wait_until(lambda: last_stats(subscriber, topics)["laser"] == "unknown", 15,  # type: ignore[index]
                       "stats saying the laser is unknown")
            noticed = time.monotonic() - silenced
            frames_when_unknown = frames_published(subscriber, topics)
            time.sleep(1.0)
            # measuring stopped: frames are still counted, but the states are not judged on them
            lasers = [m.json()["laser"] for m in subscriber.on(topics.stats)]
            assert "off" not in lasers[lasers.index("unknown"):]  # never "off" while the contact is closed
            assert board.is_on
            code, _ = daemon.terminate(timeout=20)
        finally:
            board.stop()
    assert noticed < 5.0 + 3.0  # the readback check every 5 s, plus the driver's timeout
    assert frames_published(subscriber, topics) >= frames_when_unknown
    assert code == 69, daemon.log
    assert re.search(r"CRITICAL .*COULD NOT BE SWITCHED OFF", daemon.log), daemon.log
    faults = [a for a in distinct_alerts(subscriber, topics) if a["type"] == "fault"]
    assert len(faults) >= 2 and "relay" in faults[0]["reason"]
    assert "may still be on" in faults[-1]["reason"]
    # the last fault alert went out before 'offline'
    subscriber.wait_for(topics.availability, lambda m: m.payload == b"offline", "offline", timeout=5)
    order = [m for m in subscriber.messages if m.topic in (topics.alerts, topics.availability)]
    offline_at = max(i for i, m in enumerate(order) if m.payload == b"offline")
    last_fault_at = max(i for i, m in enumerate(order) if m.topic == topics.alerts
                        and "may still be on" in m.json()["reason"])
    assert last_fault_at < offline_at


# -- 4. commands: malformed ones refused and harmless, a good one obeyed --------------------

@pytest.mark.timeout(60)
def test_malformed_commands_are_refused_and_change_nothing_and_laser_off_is_obeyed(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        sim_board_name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("EDGEDSM_COMMAND_KEY", KEY_TEXT)  # the in-process daemon's command key
    broker = make_broker()
    topics = Topics.of("edgedsm", "e2e")
    board = simulated_board(sim_board_name)
    config = write_config(tmp_path / "daemon.toml",
                          base_config(tmp_path, port=broker.port, laser=f"sim:{sim_board_name}"))
    subscriber = subscribers(broker.port, [topics.availability, topics.stats, f"{topics.base}/cmd/+/reply"])
    sender = subscribers(broker.port, [f"{topics.base}/nothing"])

    def command(name: str, payload: bytes | str) -> dict[str, Any]:
        replies = len(subscriber.on(topics.reply(name)))
        sender.client.publish(topics.command(name), payload, qos=1)
        wait_until(lambda: len(subscriber.on(topics.reply(name))) > replies, WAIT_S, f"a reply on cmd/{name}")
        return subscriber.on(topics.reply(name))[-1].json()

    with service_thread(config) as (_, result):
        subscriber.wait_for(topics.availability, lambda m: m.payload == b"online", "online", timeout=30)
        wait_until(lambda: board.is_on, 30, "the laser on (measuring)")
        time.sleep(0.5)  # the daemon's command subscription is in place once it is online and measuring
        switched = len(board.history)
        seen = frames_published(subscriber, topics)
        malformed = [  # (command, payload, what the refusal says, request_id echoed)
            ("laser", b"{state: off", "not valid JSON", None),
            ("laser", b'["off"]', "must be a JSON object", None),
            ("self_destruct", b'{"request_id": "r3"}', "unknown command 'self_destruct'", "r3"),
            ("laser", signed(topics.command("laser"), {"state": "dim"}, request_id="r4"),
             "state: Input should be 'on', 'off' or 'auto'", "r4"),
            ("laser", signed(topics.command("laser"), {"state": "off", "power": 5}, request_id=5),
             "power: unknown key", 5),
            ("laser", b'{"state": "off", "request_id": "r7"}', "not signed", "r7"),  # anyone's
            ("laser", signed(topics.command("laser"), {"state": "off"}, request_id="r8", now=time.time() - 60),
             "expired: issued 6", "r8"),  # 60 s ago, or a second more by the time it is sent
            ("laser", b'{"state": "off", "request_id": [1]}', "request_id must be", None),
        ]
        for name, payload, why, request_id in malformed:
            reply = command(name, payload)
            assert reply["ok"] is False and why in reply["error"], (payload, reply)
            assert reply["command"] == name and reply["result"] is None and reply["request_id"] == request_id
        # nothing changed: the laser never switched, and the daemon keeps measuring with it on
        seen = wait_frames_beyond(subscriber, topics, seen + 20)
        assert board.is_on and len(board.history) == switched
        assert last_stats(subscriber, topics)["laser"] == "on"  # type: ignore[index]
        assert result["thread"].is_alive()

        reply = command("laser", signed(topics.command("laser"), {"state": "off"}, request_id="r6"))
        assert reply["ok"] is True and reply["error"] is None and reply["request_id"] == "r6"
        assert reply["result"] == {"laser": "off"}
        assert not board.is_on and len(board.history) == switched + 1 and not board.history[-1].on
        # still measuring (ambient-only frames now), and it says the laser is off
        wait_frames_beyond(subscriber, topics, seen + 20)
        wait_until(lambda: last_stats(subscriber, topics)["laser"] == "off", WAIT_S,  # type: ignore[index]
                   "stats saying the laser is off")
        assert not board.is_on and result["thread"].is_alive()
    assert result["code"] == 0 and not board.is_on


# -- 5. bad configs: refused at start (78, nothing started) and at reload (kept running) -----

@pytest.mark.timeout(60)
def test_bad_config_exits_78_with_key_paths_and_starts_nothing(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    broker = make_broker()
    subscriber = subscribers(broker.port, ["#"])
    with open_pty_pair(tmp_path) as pair:
        board = ModbusBoard(pair.board, channel=5, slave=7)
        board.start()
        try:
            config = base_config(tmp_path, port=broker.port, laser=f"serial:{pair.app}?{MODBUS}")
            config["estimator"]["window"] = 1            # out of range
            config["regions"][0]["dry_below"] = 0.5      # above wet_above
            config["camera"]["exposure"] = 1000          # unknown key (exposure_us)
            config["laser"]["uri"] += "&chanel=5"        # a typo in the relay URI
            daemon = daemons(write_config(tmp_path / "daemon.toml", config))
            assert daemon.wait(30) == 78
            time.sleep(0.3)
            assert board.frames() == []  # the relay was never even talked to
        finally:
            board.stop()
        assert board.errors == []
    err = daemon.log
    for key_path in ("estimator.window", "regions.0", "camera.exposure", "laser.uri"):
        assert re.search(rf"daemon\.toml: {re.escape(key_path)}\S*: ", err), (key_path, err)
    assert "unknown key" in err and "unknown option 'chanel'" in err and "Traceback" not in err
    assert not (tmp_path / "state").exists()
    assert subscriber.messages == []  # nothing was published


def _stats_after(subscriber: Subscriber, topics: Topics, since: float) -> list[dict[str, Any]]:
    """Stats messages whose daemon time is after ``since`` (seconds since the epoch)."""
    return [s for s in (m.json() for m in subscriber.on(topics.stats)) if s["t"] > since]


@pytest.mark.alone
@pytest.mark.timeout(90)
def test_sighup_refuses_bad_configs_and_applies_a_good_one(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    broker = make_broker()
    topics = Topics.of("edgedsm", "e2e")
    config = base_config(tmp_path, port=broker.port)
    path = write_config(tmp_path / "daemon.toml", config)
    subscriber = subscribers(broker.port, [topics.availability, topics.state, topics.stats])
    daemon = daemons(path)
    subscriber.wait_for(topics.state, lambda m: "plate" in m.json()["regions"], "the state of region plate", 30)
    wait_frames_beyond(subscriber, topics, 20)

    bad_files = {
        "schema": toml_text({**config, "estimator": {**config["estimator"], "lag": 500}}),
        "syntax": toml_text(config).replace("[estimator]", "[estimator"),
        "camera URI": toml_text({**config, "camera": {"uri": SIM_CAMERA.replace("time_scale", "time_scal")}}),
        "missing scene": toml_text({**config, "camera": {"uri": f"sim:{tmp_path / 'no-such-scene.toml'}"}}),
    }
    for refused, (what, text) in enumerate(bad_files.items(), start=1):
        write_config(path, text)
        sent = time.time()
        daemon.signal(signal.SIGHUP)
        wait_until(lambda: daemon.log.count("reload refused") >= refused, WAIT_S,  # noqa: B023 (called at once)
                   f"the refusal of the {what} error")
        # still running the old configuration, still measuring and publishing
        wait_until(lambda: len(_stats_after(subscriber, topics, sent + 1.0)) >= 2, WAIT_S,  # noqa: B023
                   f"stats after refusing the {what} error")
        assert daemon.process.poll() is None, daemon.log
        newest = _stats_after(subscriber, topics, sent)
        assert newest[-1]["frames"] > newest[0]["frames"] and set(newest[-1]["state"]) == {"plate"}
    log = daemon.log
    assert "estimator: Value error, lag (500) must be smaller than window (100)" in log
    assert "not valid TOML" in log and "camera.uri: Value error, camera URI" in log
    assert "unknown option 'time_scal'" in log and "no-such-scene.toml" in log
    assert "configuration reloaded" not in log

    config["regions"][0]["name"] = "panel"
    write_config(path, config)
    daemon.signal(signal.SIGHUP)
    daemon.wait_log(r"configuration reloaded", WAIT_S)
    state = subscriber.wait_for(topics.state, lambda m: "panel" in m.json()["regions"], "the state of region panel")
    assert set(state.json()["regions"]) == {"panel"}
    wait_until(lambda: "panel" in (last_stats(subscriber, topics) or {}).get("regions", {}), 30,
               "stats of region panel (its window full again)")
    assert set(last_stats(subscriber, topics)["state"]) == {"panel"}  # type: ignore[index]
    code, took = daemon.terminate()
    assert code == 0 and took < STOP_BOUND_S, daemon.log
    assert subscriber.on(topics.availability)[-1].payload == b"offline"


@pytest.mark.alone
@pytest.mark.timeout(90)
def test_sighup_reload_is_transactional_a_config_that_cannot_run_is_refused(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    """Issue 11 §3: files that parse but cannot run (a relay device that does not exist, a region
    outside the camera's frame) and files that do not even decode are refused before the running
    pipeline is touched: logged, published as a warning alert, the old configuration kept."""
    broker = make_broker()
    topics = Topics.of("edgedsm", "e2e")
    config = base_config(tmp_path, port=broker.port)
    path = write_config(tmp_path / "daemon.toml", config)
    subscriber = subscribers(broker.port, [topics.availability, topics.stats, topics.alerts])
    daemon = daemons(path)
    wait_frames_beyond(subscriber, topics, 20)
    outside = {**config["regions"][0], "shape": "rect", "x": 5000, "y": 5000, "width": 10, "height": 10}
    bad_files: dict[str, bytes] = {
        "missing relay device": toml_text(
            {**config, "laser": {"uri": f"serial:{tmp_path / 'no-such-tty'}?protocol=lcus&channel=1"}}).encode(),
        "region outside the frame": toml_text({**config, "regions": [outside]}).encode(),
        "not UTF-8": toml_text(config).encode().replace(b'name = "e2e"', b'name = "\xff\xfe"'),
    }
    for refused, (what, data) in enumerate(bad_files.items(), start=1):
        partial = path.with_name("daemon.toml.partial")
        partial.write_bytes(data)
        partial.replace(path)
        sent = time.time()
        daemon.signal(signal.SIGHUP)
        wait_until(lambda: daemon.log.count("reload refused") >= refused, WAIT_S,  # noqa: B023 (called at once)
                   f"the refusal of the {what}")
        wait_until(lambda: len(_stats_after(subscriber, topics, sent + 1.0)) >= 2, WAIT_S,  # noqa: B023
                   f"stats after refusing the {what}")
        assert daemon.process.poll() is None, daemon.log
        wait_until(lambda: len([a for a in distinct_alerts(subscriber, topics)
                                if a["type"] == "warning"]) >= refused,  # noqa: B023 (called at once)
                   WAIT_S, f"a warning alert about the {what}")
    log = daemon.log
    assert "Traceback" not in log and "configuration reloaded" not in log
    warnings = [a["reason"] for a in distinct_alerts(subscriber, topics) if a["type"] == "warning"]
    assert len(warnings) == 3 and all(w.startswith("reload refused") for w in warnings)
    assert "no-such-tty" in warnings[0]
    assert "no pixel inside the 128x128 frame" in warnings[1]
    assert re.search("UnicodeDecodeError|not UTF-8", warnings[2]), warnings[2]
    code, took = daemon.terminate()
    assert code == 0 and took < STOP_BOUND_S, daemon.log


# -- 6. systemd notification and the watchdog ----------------------------------------------

class NotifySocket:
    """A unix datagram socket standing in for systemd's $NOTIFY_SOCKET."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.1)
        self.messages: list[tuple[float, str]] = []
        self._halt = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._receive, daemon=True, name="notify-socket")
        self._thread.start()

    def _receive(self) -> None:
        while not self._halt.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            with self._lock:
                self.messages.append((time.monotonic(), data.decode()))

    def times(self, field: str) -> list[float]:
        with self._lock:
            return [t for t, text in self.messages if field in text.split("\n")]

    def fields(self) -> list[str]:
        with self._lock:
            return [text.split("\n")[0] for _, text in self.messages]

    def close(self) -> None:
        self._halt.set()
        self._thread.join(2)
        self.sock.close()


@pytest.mark.alone
@pytest.mark.timeout(60)
def test_watchdog_pings_only_while_frames_arrive(tmp_path: Path, daemons: Callable[..., Daemon]) -> None:
    directory = tmp_path if len(str(tmp_path)) < 80 else Path(os.environ.get("TMPDIR", "/tmp"))
    notify = NotifySocket(directory / f"notify-{uuid.uuid4().hex[:8]}.sock")
    try:
        # The camera is lost after 400 frames (4 s) and comes back 3 s later; a frame that
        # does not arrive within 0.5 s is a fault.
        config = base_config(tmp_path, camera=f"{SIM_CAMERA}&lose_after=400")
        config["camera"].update(grab_timeout_s=0.5, reconnect_initial_s=3.0)
        env = {"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "400000"}  # ping every 0.2 s
        daemon = daemons(write_config(tmp_path / "daemon.toml", config), env)
        lost = daemon.wait_log(r"camera lost", 30)
        back = daemon.wait_log(r"camera reconnected", 10)
        wait_until(lambda: len([t for t in notify.times("WATCHDOG=1") if t > back]) >= 5, 5,
                   "watchdog pings after the camera came back")
        code, took = daemon.terminate()
        assert code == 0 and took < STOP_BOUND_S, daemon.log
        time.sleep(0.2)
    finally:
        notify.close()
    fields = notify.fields()
    statuses = [f for f in fields if f.startswith("STATUS=")]
    fields = [f for f in fields if not f.startswith("STATUS=")]
    assert fields[0] == "READY=1" and fields[-1] == "STOPPING=1"
    assert set(fields) == {"READY=1", "WATCHDOG=1", "STOPPING=1"}
    # periodic STATUS lines for `systemctl status`: rate, frames, drops, laser, region states
    assert statuses and all(re.fullmatch(r"STATUS=[\d.]+ frames/s, \d+ frames, \d+ dropped, laser (on|off); "
                                         r"plate (warming_up|wet|drying|dry|fault)", f) for f in statuses), statuses
    pings = notify.times("WATCHDOG=1")
    ready = notify.times("READY=1")[0]
    assert ready < pings[0]
    gaps = np.diff(pings)
    # while frames arrive: a ping every 0.2 s (plus at most one 0.1 s loop turn)
    before, after = [t for t in pings if t < lost], [t for t in pings if t > back]
    assert len(before) >= 10 and len(after) >= 5
    assert np.diff(before).max() < 0.6 and np.diff(after).max() < 0.6
    # the camera stalled: the pings stopped within grab_timeout_s of the last frame and only
    # came back with the frames, leaving one long silence
    assert int((gaps > 1.0).sum()) == 1
    silence_start = pings[int(np.argmax(gaps))]
    silence_end = pings[int(np.argmax(gaps)) + 1]
    assert silence_end - silence_start > 2.0
    assert lost - 1.0 < silence_start < lost + 0.8
    assert silence_end > back - 0.2
