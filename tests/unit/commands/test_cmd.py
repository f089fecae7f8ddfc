"""`edgedsm cmd`'s signing (the wire is tested in tests/integration/test_cli_cmd.py and
test_command_security.py)."""

from __future__ import annotations

import pytest

from edgedsm.commands.cmd import signed
from edgedsm.errors import ConfigError
from edgedsm.publish.command_auth import Authorised, CommandVerifier

TOPIC = "edgedsm/line3/cmd/laser"
KEYS = {"alice": b"a" * 32, "bob": b"b" * 32}


def test_commands_that_change_something_are_signed_with_the_first_key_or_the_chosen_one():
    payload = signed(TOPIC, "laser", {"state": "off"}, KEYS, None)
    assert payload["key_id"] == "alice" and payload["state"] == "off"
    verifier = CommandVerifier(KEYS, max_age_s=30.0)
    assert verifier.check(TOPIC, payload, required=True, now=payload["issued"]) == Authorised({"state": "off"}, "alice")
    assert signed(TOPIC, "laser", {"state": "off"}, KEYS, "bob")["key_id"] == "bob"
    with pytest.raises(ConfigError, match="--key-id: no command key with id 'carol'"):
        signed(TOPIC, "laser", {"state": "off"}, KEYS, "carol")


def test_open_commands_and_senders_without_keys_send_unsigned():
    assert signed("edgedsm/line3/cmd/publish_maps", "publish_maps", {}, KEYS, None) == {}
    assert "sig" in signed("edgedsm/line3/cmd/publish_maps", "publish_maps", {}, KEYS, "bob")
    assert signed(TOPIC, "laser", {"state": "on"}, {}, None) == {"state": "on"}  # the daemon says why not
