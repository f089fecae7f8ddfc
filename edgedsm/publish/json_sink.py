"""The MQTT JSON sink: the daemon's typed messages as JSON on ``<prefix>/<device>/...``.

It composes :class:`edgedsm.publish.mqtt.MqttPublisher` (the connection and its collaborators:
alert store and sender, map sender, command channel); topics and payloads are documented in
``docs/mqtt.md``.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

from edgedsm.errors import ConfigError
from edgedsm.messages import Alert, LaserState, MapFrame, StateReport, Stats
from edgedsm.publish.command_channel import CommandHandler
from edgedsm.publish.mqtt import MqttPublisher
from edgedsm.publish.session import MqttSession
from edgedsm.publish.settings import CREDENTIAL_NAME, PASSWORD_ENV, MqttSettings
from edgedsm.publish.topics import Topics

log = logging.getLogger(__name__)

#: In ``device.state_dir``: the per-region state topics this device left retained, so a region
#: removed while the daemon was stopped is cleared at the next start.
RETAINED_REGIONS_FILE = "retained-region-topics.json"
#: How long :meth:`MqttSink.start` waits for the broker's first answer (at most
#: ``connect_timeout_s``): long enough for a CONNACK on a plant network, short enough that a
#: broker that does not answer delays measuring by no more than this.
FIRST_ANSWER_S = 2.0


class MqttSink:
    """Implements :class:`edgedsm.publish.sink.Sink` over MQTT (JSON payloads, PNG maps).

    ``state_dir`` holds the alert queue (ConfigError naming ``device.state_dir`` when it cannot);
    ``on_command`` runs validated commands (see ``CommandHandler``); ``password`` overrides the
    environment (tests). Nothing connects until :meth:`start`.
    """

    def __init__(self, settings: MqttSettings, state_dir: str | Path, on_command: CommandHandler | None = None,
                 *, password: str | None = None) -> None:
        self.publisher = MqttPublisher(settings, state_dir, on_command, password=password)
        self._regions_file = Path(state_dir) / RETAINED_REGIONS_FILE
        self._region_topics: set[str] | None = None  # None: not read yet
        self._last_report: StateReport | None = None
        self._stopped = False

    @property
    def topics(self) -> Topics:
        return self.publisher.topics

    @property
    def session(self) -> MqttSession:
        """The link's MQTT connection, which Home Assistant's discovery shares."""
        return self.publisher.session

    def start(self) -> MqttSink:
        """Start connecting in the background, waiting at most ``FIRST_ANSWER_S`` for the broker's
        first answer: credentials it refuses then (bad user name or password, not authorised) can
        never work, a ConfigError (exit 78: not restarted by systemd; a reload is refused). A
        broker down or slow to answer is retried in the background, measuring goes on."""
        self.publisher.start()
        session = self.session
        session.answered.wait(min(FIRST_ANSWER_S, session.settings.connect_timeout_s))
        if session.refused_credentials:
            refusal = session.refusal
            self.publisher.close(timeout=0.5)
            raise ConfigError(f"mqtt.username: {refusal}: these credentials will be refused every time; fix the "
                              f"user name or the password (${PASSWORD_ENV}, the credential {CREDENTIAL_NAME!r}) "
                              f"or the broker's ACL")
        return self

    # -- the Sink protocol ------------------------------------------------------------------------

    def publish_state(self, report: StateReport) -> None:
        """The combined state, then each region's on ``state/<region>`` (all retained); a region
        published before (by this or an earlier run) and absent now has its topic cleared."""
        if self._stopped:  # a late evaluation must not overwrite the daemon's last word
            return
        self._last_report = report
        self.publisher.publish_state(report.to_json())
        topics = {self.topics.region_state(name): region for name, region in report.regions.items()}
        for topic, region in topics.items():
            self.publisher.publish_retained(topic, region.to_bytes())
        previous = self._remembered_region_topics()
        for gone in sorted(previous - topics.keys()):
            log.info("region topic %s cleared: the region is no longer configured", gone)
            self.publisher.publish_retained(gone, b"")
        if previous != topics.keys():
            self._remember_region_topics(set(topics))

    def _remembered_region_topics(self) -> set[str]:
        if self._region_topics is None:
            try:
                self._region_topics = set(json.loads(self._regions_file.read_text(encoding="utf-8"))["topics"])
            except FileNotFoundError:
                self._region_topics = set()
            except (OSError, ValueError, KeyError, TypeError) as exc:
                log.warning("%s unreadable (%s): removed regions' topics are not cleared", self._regions_file, exc)
                self._region_topics = set()
        return self._region_topics

    def _remember_region_topics(self, topics: set[str]) -> None:
        self._region_topics = topics
        partial = self._regions_file.with_name(self._regions_file.name + ".partial")
        try:
            partial.write_text(json.dumps({"topics": sorted(topics)}), encoding="utf-8")
            os.replace(partial, self._regions_file)
        except OSError as exc:  # measuring goes on; only the clearing after a restart is lost
            log.warning("cannot write %s: %s", self._regions_file, exc)

    def publish_alert(self, alert: Alert) -> int:
        """Store and send the alert; returns the ``seq`` it was given (``stream`` and ``seq`` of
        ``alert`` are replaced)."""
        return self.publisher.publish_alert(alert.to_json())

    def publish_stats(self, stats: Stats) -> None:
        self.publisher.publish_stats(stats.to_json())

    def publish_map(self, frame: MapFrame) -> None:
        self.publisher.publish_map(frame.name, frame.values, frame.meta())

    def flush(self, timeout_s: float) -> bool:
        return self.publisher.flush_maps(timeout_s)

    def stopping(self, laser: LaserState, t: float) -> None:
        """The daemon stops (``FanOut.stopping``, before :meth:`close`): the retained state and
        each region's become its last word, ``availability: offline`` with the laser as confirmed
        at stop and no time to dry, so a reader of the retained state alone is not told the
        laser is on. Nothing is published without an earlier state (no region to speak of)."""
        report = self._last_report
        if report is None or self._stopped:
            return
        final = report.stopped(t, laser)
        self.publish_state(final)
        self._stopped = True

    def close(self, timeout_s: float) -> None:
        self.publisher.close(timeout=timeout_s)

    # -- health, for the daemon's status and for tests --------------------------------------------

    def wait_connected(self, timeout_s: float) -> None:
        """Wait (bounded) for the broker; PublishError saying why not."""
        self.publisher.wait_connected(timeout_s)

    @property
    def connected(self) -> bool:
        return self.publisher.connected

    @property
    def refusal(self) -> str | None:
        """The broker's refusal of our credentials (None while it accepts them, or refuses for
        another reason): ``/healthz`` reports the service unhealthy meanwhile."""
        return self.session.refusal if self.session.refused_credentials else None

    @property
    def last_error(self) -> str | None:
        """The latest connection problem, or None while all is well."""
        return self.publisher.last_error

    def flush_alerts(self, timeout_s: float) -> bool:
        """Wait (bounded) until every alert is acknowledged by the broker; True if so."""
        return self.publisher.flush_alerts(timeout_s)

    @property
    def alert_stream(self) -> str:
        return self.publisher.alert_stream

    @property
    def pending_alerts(self) -> int:
        return self.publisher.pending_alerts

    def counters(self) -> dict[str, Any]:
        """What goes under ``mqtt`` in the stats (see :meth:`MqttPublisher.counters`)."""
        return self.publisher.counters()
