"""Session bookkeeping of the edge node (pure apart from one small file): the birth/death
sequence number ``bdSeq`` that survives restarts, the message sequence number ``seq``, the
primary host's STATE, and the rate limit of births."""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from edgedsm.errors import ConfigError

log = logging.getLogger(__name__)

#: File in the state directory holding the last bdSeq sent in a CONNECT (a decimal number).
BDSEQ_FILE = "sparkplug-bdseq"


class BdSeqStore:
    """The bdSeq of the MQTT CONNECT packets: 0 first, +1 on every new CONNECT, 255 wraps to 0
    (spec: tck-id-message-flow-edge-node-birth-publish-will-message-payload-bdSeq), persisted in
    the state directory so a restarted daemon goes on counting (an NDEATH the broker delivers
    late for the previous process must not match the new NBIRTH).

    A state directory that cannot be used at start is a ConfigError naming ``device.state_dir``;
    a write failing later is logged and counting goes on in memory."""

    def __init__(self, state_dir: str | Path) -> None:
        self.path = Path(state_dir) / BDSEQ_FILE
        self.last: int | None = None
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            text = self.path.read_text(encoding="ascii").strip() if self.path.exists() else ""
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"device.state_dir: {self.path.parent}: cannot keep the Sparkplug bdSeq: {exc}") from None
        if text:
            if text.isdigit() and int(text) <= 255:
                self.last = int(text)
            else:
                log.warning("%s holds %r, not a bdSeq (0-255): starting again at 0", self.path, text[:40])
        if not os.access(self.path.parent, os.W_OK):
            raise ConfigError(f"device.state_dir: {self.path.parent}: not writable (the Sparkplug bdSeq is kept there)")

    def next(self) -> int:
        """The bdSeq for the next CONNECT (not yet committed)."""
        return 0 if self.last is None else (self.last + 1) % 256

    def commit(self, value: int) -> None:
        """``value`` went out in a CONNECT: remember it (atomically, on disk)."""
        self.last = value
        partial = self.path.with_name(self.path.name + ".partial")
        try:
            partial.write_text(f"{value}\n", encoding="ascii")
            partial.replace(self.path)
        except OSError as exc:
            log.error("Sparkplug bdSeq %d not saved to %s (%s): a restart would count from an older value",
                      value, self.path, exc)


class SeqCounter:
    """The message sequence number: 0 on NBIRTH, then +1 per message, 255 wraps to 0."""

    def __init__(self) -> None:
        self.value = 0

    def birth(self) -> int:
        self.value = 0
        return 0

    def next(self) -> int:
        self.value = (self.value + 1) % 256
        return self.value


HostEvent = Literal["online", "offline", "stale"]


@dataclass
class PrimaryHost:
    """The primary host application's STATE (``spBv1.0/STATE/<host_id>``, JSON
    ``{"online": bool, "timestamp": ms}``), judged by the spec's rules: an online message counts
    when its timestamp is not older than the previous STATE's
    (tck-id-message-flow-edge-node-birth-publish-phid-wait-timestamp); an offline one when it is
    not older than the latest online one (tck-id-operational-behavior-edge-node-termination-host-offline,
    ...-host-offline-timestamp)."""

    host_id: str
    online: bool = False
    last_timestamp: float | None = None
    online_timestamp: float | None = None

    @property
    def topic(self) -> str:
        return f"spBv1.0/STATE/{self.host_id}"

    def on_state(self, payload: bytes) -> HostEvent:
        """Judge one STATE message; ValueError (in words) when the payload is not valid STATE JSON."""
        try:
            data = json.loads(payload.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            raise ValueError(f"STATE of {self.host_id!r} is not JSON: {payload[:60]!r}") from None
        if not isinstance(data, dict) or not isinstance(data.get("online"), bool):
            raise ValueError(f"STATE of {self.host_id!r} has no boolean 'online': {payload[:60]!r}")
        timestamp = data.get("timestamp")
        if isinstance(timestamp, bool) or not isinstance(timestamp, int | float) or not math.isfinite(timestamp):
            raise ValueError(f"STATE of {self.host_id!r} has no numeric 'timestamp': {payload[:60]!r}")
        if data["online"]:
            if self.last_timestamp is not None and timestamp < self.last_timestamp:
                return "stale"
            self.online, self.online_timestamp = True, timestamp
        else:
            if self.online_timestamp is not None and timestamp < self.online_timestamp:
                return "stale"  # the death of an older host session, delivered late
            self.online = False
        self.last_timestamp = timestamp if self.last_timestamp is None else max(self.last_timestamp, timestamp)
        return "online" if self.online else "offline"


class BirthLimiter:
    """Births at most every ``min_interval_s`` (monotonic clock): a rebirth flood is answered by
    one birth per interval."""

    def __init__(self, min_interval_s: float) -> None:
        self.min_interval_s = min_interval_s
        self.last: float = -math.inf

    def wait_s(self, now: float) -> float:
        """Seconds until a birth is allowed (0: now)."""
        return max(0.0, self.last + self.min_interval_s - now)

    def record(self, now: float) -> None:
        self.last = now
