"""τc through the real daemon and a real broker: a recorded drying plate replayed faster than
real time, τc switched on; the stats carry each region's τc in seconds (Δt from the recording's
timestamps, 50 ms, not from the replay's pace, 10 ms) and the τc map goes out in seconds."""

from __future__ import annotations

import itertools
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from helpers_daemon import DRYING_SCENE, Daemon, base_config, last_stats, write_config
from helpers_mqtt import Broker, Subscriber, wait_until

from edgedsm.publish import Topics, decode_map
from edgedsm.sim import load_scene, simulate

pytestmark = pytest.mark.integration


@pytest.mark.timeout(90)
def test_the_daemon_publishes_region_tau_in_seconds_and_its_map(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    scene = load_scene(DRYING_SCENE)
    scene.scene.size = 64
    total = 200  # the plate starts drying at frame 200: τc = 3 Δt = 0.15 s throughout
    np.save(tmp_path / "frames.npy", np.stack(list(itertools.islice(simulate(scene), total))))

    broker = make_broker()
    topics = Topics.of("edgedsm", "e2e")
    config = base_config(tmp_path, port=broker.port, camera=f"replay:{tmp_path / 'frames.npy'}?rate=100&dt=0.05")
    config["acquisition"].update(queue_frames=10_000)
    config["estimator"].update(tau_c=True, max_lag=20)
    subscriber = subscribers(broker.port, [topics.stats, topics.maps_filter, f"{topics.base}/map/+/meta"])
    daemon = daemons(write_config(tmp_path / "daemon.toml", config))
    assert daemon.wait(60) == 0, daemon.log

    wait_until(lambda: (last_stats(subscriber, topics) or {}).get("frames") == total, 5, "the final stats")
    stats = last_stats(subscriber, topics)
    assert stats is not None and stats["frame_interval_s"] == pytest.approx(0.05)
    tau = stats["tau_c"]["plate"]
    assert tau["status"] == "measured" and tau["tau_c_s"] == pytest.approx(0.15, rel=0.1), tau
    assert stats["estimator"] == "s2" and set(stats["regions"]["plate"]) == {"s1", "s2", "s3"}

    def tau_map() -> tuple[np.ndarray, dict] | None:
        metas = {m.json()["png_crc32"]: m.json() for m in subscriber.on(topics.map_meta("tau_c"))}
        pngs = [message.payload for message in subscriber.on(topics.map("tau_c"))]
        maps = [(png, metas.get(zlib.crc32(png))) for png in pngs]
        final = [(decode_map(png, meta), meta) for png, meta in maps if meta is not None and meta["frames"] == total]
        return final[-1] if final else None

    wait_until(lambda: tau_map() is not None, 5, "the final τc map")
    values, meta = tau_map()  # type: ignore[misc]
    assert meta["unit"] == "s" and meta["estimator"] == "tau_c" and meta["max_lag"] == 20
    assert values.shape == (64, 64) and values.min() >= 0 and values.max() <= 20 * 0.05 + meta["scale"]
    assert 0.1 < float(np.median(values)) < 0.2  # per-pixel τc of a 0.15 s surface, in seconds
