"""The map sender: a worker that downsamples, encodes (``edgedsm.publish.mapcodec``) and sends
maps as PNG + JSON meta, QoS 0, one at a time.

Back-pressure: the latest map per name waits here; a newer one replaces (and drops, counted) it,
and the worker waits until a PNG has left before taking the next, so a slow link never piles
maps up in memory.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
from paho.mqtt.enums import MQTTErrorCode

from edgedsm import _json
from edgedsm.publish.counters import Counters
from edgedsm.publish.errors import MapCodecError
from edgedsm.publish.latest_worker import LatestWorker
from edgedsm.publish.mapcodec import encode_map
from edgedsm.publish.settings import MqttSettings
from edgedsm.publish.topics import Topics

log = logging.getLogger(__name__)

#: Longest wait for one map's PNG to leave before the worker moves on (s): the next map of that
#: name replaces it anyway (maps are state, not events).
MAP_SEND_WAIT_S = 30.0


class MapSender:
    """Sends maps handed to :meth:`submit` while ``connected`` is set."""

    def __init__(self, settings: MqttSettings, topics: Topics, client: mqtt.Client, connected: threading.Event,
                 counters: Counters) -> None:
        self.settings = settings
        self.topics = topics
        self._client = client
        self._connected = connected
        self._counters = counters
        self._worker: LatestWorker[tuple[np.ndarray, dict[str, Any]]] = LatestWorker(
            "edgedsm-mqtt-maps", "map", self._handle, on_error=lambda name: self._counters.add("maps_dropped"))

    @property
    def thread(self) -> threading.Thread:
        return self._worker.thread

    def start(self) -> None:
        self._worker.start()

    def stop(self) -> None:
        self._worker.stop()

    def submit(self, name: str, values: np.ndarray, meta: Mapping[str, Any] | None = None) -> bool:
        """Hand one map over (returns at once); False (counted as dropped) when not connected.

        ``meta``: ``seq`` (``frames`` is taken when there is none), ``t``, ``window``, ``lag``;
        other keys go into the published meta as they are. ``values`` is read after this
        returns: nobody may modify it.
        """
        if not self._connected.is_set():
            self._counters.add("maps_dropped")
            return False
        info = dict(meta or {})
        if info.get("estimator") == name:
            del info["estimator"]  # the codec writes it
        if "seq" not in info and "frames" in info:
            info["seq"] = info["frames"]
        if self._worker.submit(str(name), (values, info)):
            self._counters.add("maps_dropped")  # the one it replaced
        return True

    def flush(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s until every map handed over has left (or was dropped)."""
        return self._worker.flush(timeout)

    def _handle(self, name: str, job: tuple[np.ndarray, dict[str, Any]]) -> None:
        if not self._connected.is_set():
            self._counters.add("maps_dropped")
            return
        self._send(name, *job)

    def _send(self, name: str, values: np.ndarray, meta: dict[str, Any]) -> None:
        extra = {key: value for key, value in meta.items() if key not in ("seq", "t", "window", "lag")}
        try:
            png, info = encode_map(values, estimator=name, seq=meta.get("seq"), t=meta.get("t"),
                                   window=meta.get("window"), lag=meta.get("lag"),
                                   max_size=self.settings.map_max_size,
                                   compression=self.settings.map_png_compression, extra=extra)
        except MapCodecError as exc:
            self._counters.add("maps_dropped")
            log.error("map %r not published: %s", name, exc)
            return
        # Meta first: a subscriber that pairs by png_crc32 does not care, one that takes "the last
        # meta" gets the right one.
        self._client.publish(self.topics.map_meta(name), _json.dumps(info), qos=0)
        sent = self._client.publish(self.topics.map(name), png, qos=0)
        # Back-pressure: wait (in this thread only) until the PNG left, so maps never pile up.
        deadline = time.monotonic() + MAP_SEND_WAIT_S
        while not sent.is_published() and sent.rc == MQTTErrorCode.MQTT_ERR_SUCCESS:
            if self._worker.stopping or time.monotonic() >= deadline:
                return
            time.sleep(0.01)
        self._counters.add("maps_sent")
