"""The command channel: receives ``<base>/cmd/<name>``, validates and bounds it, checks that it
is authorised, hands it to the daemon's handler on a thread of its own, and replies
(``edgedsm.publish.commands``).

Bounds come before parsing: a payload over ``COMMAND_MAX_BYTES`` or nested deeper than
``COMMAND_MAX_DEPTH`` is refused without being parsed (a JSON nested 100 000 deep would exhaust
the parser's recursion). A command that changes the laser or the measurement runs only with a
valid signature, issued within ``[mqtt] command_max_age_s`` and with a nonce not seen before
(``edgedsm.publish.command_auth``); a retained message is never run. Replies go only to
``<base>/cmd/<name>/reply``: an MQTT 5 Response Topic is ignored (the daemon's credentials must
not publish into Home Assistant's, Sparkplug's or another device's topics at a requester's word);
its Correlation Data is echoed.
"""

from __future__ import annotations

import contextlib
import json
import logging
import queue
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from paho.mqtt.client import MQTTMessage
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from pydantic import ValidationError

from edgedsm import _json
from edgedsm.errors import EdgedsmError
from edgedsm.publish.command_auth import Authorised, CommandVerifier
from edgedsm.publish.commands import COMMANDS, Command
from edgedsm.publish.counters import Counters
from edgedsm.publish.topics import Topics

log = logging.getLogger(__name__)

CommandHandler = Callable[[str, Command], Mapping[str, Any] | None]
"""``on_command(name, command) -> result``: run a validated command (``command`` is the pydantic
model of ``edgedsm.publish.commands``; ``command.model_dump()`` gives a plain dict). The returned
mapping (or None) becomes the reply's ``result``; to refuse, return ``{"ok": False, "error":
"why"}`` or raise (an EdgedsmError's message is sent as is). Runs in the command thread, one
command at a time, so it may wait (bounded) for the pipeline."""

Publish = Callable[..., Any]  # paho's Client.publish(topic, payload, qos=..., properties=...)

COMMAND_BACKLOG = 8           # commands waiting for the handler before "busy" is answered
COMMAND_MAX_BYTES = 16 * 1024  # a command is a few dozen bytes; this leaves room for a long request_id
COMMAND_MAX_DEPTH = 8          # nesting of arrays/objects; commands are flat
REQUEST_ID_MAX = 128           # characters of a string request_id
WORKER_POLL_S = 0.25           # how often the idle worker looks at the stop flag


def json_depth_exceeds(payload: bytes, limit: int) -> bool:
    """True when ``payload`` nests arrays/objects deeper than ``limit`` (brackets inside strings
    do not count); a linear scan, so it is safe on any input."""
    depth = 0
    in_string = escaped = False
    for byte in payload:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:  # quote
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):  # [ {
            depth += 1
            if depth > limit:
                return True
        elif byte in (0x5D, 0x7D):  # ] }
            depth -= 1
    return False


class CommandChannel:
    """Receives commands (paho's thread), runs them (its own thread), replies (QoS 1).

    ``verifier``: checks signatures (None: the same as no key, read-only); ``clock``: epoch
    seconds (tests)."""

    def __init__(self, topics: Topics, publish: Publish, on_command: CommandHandler | None,
                 counters: Counters, *, mqtt5: bool, disabled: Mapping[str, str] | None = None,
                 verifier: CommandVerifier | None = None, clock: Callable[[], float] = time.time) -> None:
        self.topics = topics
        self._verifier = verifier if verifier is not None else CommandVerifier({}, max_age_s=30.0)
        self._clock = clock
        self._disabled = dict(disabled or {})  # command name -> why it is refused
        self._publish = publish
        self._on_command = on_command
        self._counters = counters
        self._mqtt5 = mqtt5
        # None wakes the worker at shutdown.
        self._pending: queue.Queue[tuple[str, Command, Any, bytes | None] | None] = \
            queue.Queue(maxsize=COMMAND_BACKLOG)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._work, name="edgedsm-mqtt-commands", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self._stop.set()
        with contextlib.suppress(queue.Full):
            self._pending.put_nowait(None)

    # -- receiving (paho's network thread) ------------------------------------------------------

    def receive(self, message: MQTTMessage) -> None:
        """Validate one message on ``<base>/cmd/<name>``; queue it for the handler or refuse it."""
        prefix = f"{self.topics.base}/cmd/"
        if not message.topic.startswith(prefix):
            return
        name = message.topic[len(prefix):]
        props = getattr(message, "properties", None)
        correlation = getattr(props, "CorrelationData", None) or None
        request_id: Any = None

        def refuse(reason: str) -> None:
            self._counters.add("commands_refused")
            log.warning("MQTT command %r refused: %s", name, reason)
            self._reply(name, request_id, correlation, ok=False, error=reason)

        if not message.payload:
            # Zero bytes is how a retained message is cleared; the clearing is delivered too.
            log.debug("MQTT: empty message on %r ignored", message.topic)
            return
        if message.retain:
            refuse(f"retained commands are refused (they would run again on every reconnection); "
                   f"clear it with: mosquitto_pub -r -n -t '{message.topic}'")
            return
        if len(message.payload) > COMMAND_MAX_BYTES:
            refuse(f"payload of {len(message.payload)} bytes exceeds the {COMMAND_MAX_BYTES}-byte limit")
            return
        if json_depth_exceeds(message.payload, COMMAND_MAX_DEPTH):
            refuse(f"payload nested deeper than {COMMAND_MAX_DEPTH} levels")
            return
        try:
            data = json.loads(message.payload.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            refuse(f"payload is not valid JSON: {exc}")
            return
        if not isinstance(data, dict):
            refuse(f"payload must be a JSON object, got {type(data).__name__}")
            return
        request_id = data.pop("request_id", None)
        if request_id is not None and not (
                (isinstance(request_id, str) and len(request_id) <= REQUEST_ID_MAX)
                or (isinstance(request_id, int) and not isinstance(request_id, bool))):
            request_id = None
            refuse(f"request_id must be a string of at most {REQUEST_ID_MAX} characters or an integer")
            return
        model = COMMANDS.get(name)
        if model is None:
            refuse(f"unknown command {name!r}; known commands: {', '.join(COMMANDS)}")
            return
        if name in self._disabled:
            refuse(self._disabled[name])
            return
        checked = self._verifier.check(message.topic, data, required=model.requires_authorisation,
                                       now=self._clock())
        if not isinstance(checked, Authorised):
            refuse(checked)
            return
        try:
            command = model.model_validate(checked.arguments)
        except ValidationError as exc:
            refuse("; ".join(f"{'.'.join(str(p) for p in err['loc']) or 'payload'}: "
                             f"{'unknown key' if err['type'] == 'extra_forbidden' else err['msg']}"
                             for err in exc.errors()))
            return
        if self._on_command is None:
            refuse("this process does not carry out commands (no handler)")
            return
        try:
            self._pending.put_nowait((name, command, request_id, correlation))
            if checked.key_id is not None:
                log.info("MQTT command %r signed by key %r accepted", name, checked.key_id)
        except queue.Full:
            refuse(f"busy: {COMMAND_BACKLOG} commands are already waiting; try again")

    # -- running (the command thread) -----------------------------------------------------------

    def _work(self) -> None:
        while not self._stop.is_set():
            try:
                item = self._pending.get(timeout=WORKER_POLL_S)
            except queue.Empty:
                continue
            if item is None:
                return
            self._run(*item)

    def _run(self, name: str, command: Command, request_id: Any, correlation: bytes | None) -> None:
        assert self._on_command is not None
        try:
            result = dict(self._on_command(name, command) or {})
        except EdgedsmError as exc:
            self._counters.add("commands_refused")
            self._reply(name, request_id, correlation, ok=False, error=str(exc))
            return
        except Exception as exc:
            log.exception("MQTT command %r failed in its handler", name)
            self._counters.add("commands_refused")
            self._reply(name, request_id, correlation, ok=False,
                        error=f"internal error: {type(exc).__name__}: {exc}")
            return
        # A handler may answer {"ok": False, "error": "..."} instead of raising.
        ok = result.pop("ok", True) is not False
        error = result.pop("error", None)
        self._counters.add("commands" if ok else "commands_refused")
        self._reply(name, request_id, correlation, ok=ok,
                    error=None if ok else str(error or "refused by the handler"), result=result or None)

    def _reply(self, name: str, request_id: Any, correlation: bytes | None, *,
               ok: bool, error: str | None = None, result: Mapping[str, Any] | None = None) -> None:
        body = {"ok": ok, "command": name, "request_id": request_id, "error": error,
                "result": result, "t": time.time()}
        try:
            payload = _json.dumps(body)
        except (TypeError, ValueError) as exc:
            payload = _json.dumps({**body, "ok": False, "result": None,
                                   "error": f"handler result is not JSON: {exc}"})
        properties = None
        if correlation is not None and self._mqtt5:
            properties = Properties(PacketTypes.PUBLISH)
            properties.CorrelationData = correlation
        self._publish(self.topics.reply(name), payload, qos=1, properties=properties)
