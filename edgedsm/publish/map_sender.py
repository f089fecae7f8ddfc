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
from edgedsm.publish.mapcodec import encode_map
from edgedsm.publish.settings import MqttSettings
from edgedsm.publish.topics import Topics

log = logging.getLogger(__name__)

WORKER_POLL_S = 0.25  # how often the idle worker looks at the stop flag


class MapSender:
    """Sends maps handed to :meth:`submit` while ``connected`` is set."""

    def __init__(self, settings: MqttSettings, topics: Topics, client: mqtt.Client, connected: threading.Event,
                 counters: Counters) -> None:
        self.settings = settings
        self.topics = topics
        self._client = client
        self._connected = connected
        self._counters = counters
        self._lock = threading.Lock()
        self._jobs: dict[str, tuple[np.ndarray, dict[str, Any]]] = {}
        self._sending = False  # the worker holds a map it has taken off _jobs
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._work, name="edgedsm-mqtt-maps", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()

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
        with self._lock:
            replaced = self._jobs.pop(str(name), None) is not None
            self._jobs[str(name)] = (values, info)
        if replaced:
            self._counters.add("maps_dropped")
        self._wake.set()
        return True

    def flush(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s until every map handed over has left (or was dropped)."""
        deadline = time.monotonic() + timeout
        while True:
            with self._lock:
                idle = not self._jobs and not self._sending
            if idle:
                return True
            if time.monotonic() >= deadline:
                return False
            self._wake.set()
            time.sleep(0.02)

    def _work(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(WORKER_POLL_S)
            self._wake.clear()
            while not self._stop.is_set():
                with self._lock:
                    if not self._jobs:
                        break
                    name = next(iter(self._jobs))
                    values, meta = self._jobs.pop(name)
                    self._sending = True
                try:
                    if not self._connected.is_set():
                        self._counters.add("maps_dropped")
                        continue
                    self._send(name, values, meta)
                except Exception:  # keep the worker alive for the next maps
                    self._counters.add("maps_dropped")
                    log.exception("map %r could not be published", name)
                finally:
                    with self._lock:
                        self._sending = False

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
        deadline = time.monotonic() + max(5.0, self.settings.maps_interval_s)
        while not sent.is_published() and sent.rc == MQTTErrorCode.MQTT_ERR_SUCCESS:
            if self._stop.is_set() or time.monotonic() >= deadline:
                return
            time.sleep(0.01)
        self._counters.add("maps_sent")
