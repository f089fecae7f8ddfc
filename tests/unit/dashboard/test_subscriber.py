"""The dashboard's commands without a command key (signed ones are tested against a real daemon
in tests/integration/test_command_security.py)."""

from __future__ import annotations

import pytest

from edgedsm.dashboard.subscriber import PlantSubscriber
from edgedsm.publish import MqttSettings


class _Plant:
    def handle(self, topic: str, payload: bytes) -> None:  # never called: nothing connects here
        raise AssertionError(topic)


def test_without_a_key_the_dashboard_refuses_what_the_daemon_would_refuse():
    subscriber = PlantSubscriber(MqttSettings(port=1), _Plant(), password=None, command_keys={})
    for name in ("rebaseline", "dark"):
        with pytest.raises(ValueError, match=f"the dashboard has no command key, so the daemon would refuse '{name}'"):
            subscriber.send_command("line3", name)
    with pytest.raises(ValueError, match="not allowed from the dashboard"):
        subscriber.send_command("line3", "laser")
    subscriber.send_command("line3", "publish_maps")  # open: queued unsigned (not connected here)
