"""Signed commands for tests: one test command key, given to every process the tests start
(``child_env``) and to in-process publishers (``EDGEDSM_COMMAND_KEY``), and :func:`signed` to
build a payload the daemon accepts (``edgedsm.publish.command_auth``)."""

from __future__ import annotations

import json
import time
from typing import Any

from edgedsm.publish.command_auth import sign

KEY_ID = "tests"
SECRET = "5f0c2a9e" * 8  # 64 characters, as `openssl rand -hex 32` gives
KEY_TEXT = f"{KEY_ID} {SECRET}"
KEYS = {KEY_ID: SECRET.encode()}
ENV = {"EDGEDSM_COMMAND_KEY": KEY_TEXT}
#: A daemon or client started with this in its environment has no command key (read-only).
NO_KEY_ENV = {"EDGEDSM_COMMAND_KEY": ""}


def signed(topic: str, arguments: dict[str, Any] | None = None, *, request_id: Any = None,
           now: float | None = None, nonce: str | None = None, key_id: str = KEY_ID,
           secret: str = SECRET) -> str:
    """The JSON payload of a command for ``topic`` (the full ``<prefix>/<device>/cmd/<name>``),
    signed with the test key (or ``key_id``/``secret``); ``request_id`` added when given."""
    payload = sign(key_id, secret.encode(), topic, arguments or {}, now=time.time() if now is None else now,
                   nonce=nonce)
    if request_id is not None:
        payload["request_id"] = request_id
    return json.dumps(payload)
