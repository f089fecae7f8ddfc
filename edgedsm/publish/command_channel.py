"""The command channel: receives ``<base>/cmd/<name>``, validates and bounds it, hands it to the
daemon's handler on a thread of its own, and replies (``edgedsm.publish.commands``).

Bounds come before parsing: a payload over ``COMMAND_MAX_BYTES`` or nested deeper than
``COMMAND_MAX_DEPTH`` is refused without being parsed (a JSON nested 100 000 deep would exhaust
the parser's recursion). Replies go to ``<base>/cmd/<name>/reply`` or to the request's MQTT 5
Response Topic only when that is the same topic or lies outside ``<topic_prefix>/`` and has no
wildcard: a requester must not make the daemon write into its own (or another device's) topics.
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
RESPONSE_TOPIC_MAX = 256       # characters of an MQTT 5 Response Topic
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


def response_topic_refusal(topic: str, own_reply: str, topics: Topics) -> str | None:
    """Why a requested Response Topic may not be published to, or None when it may."""
    if topic == own_reply:
        return None
    if len(topic) > RESPONSE_TOPIC_MAX:
        return f"response topic longer than {RESPONSE_TOPIC_MAX} characters"
    if any(c in topic for c in "#+\0"):
        return f"response topic {topic!r} has a wildcard"
    if topic.startswith("$"):
        return f"response topic {topic!r} is a broker topic ($...)"
    if topic == topics.prefix or topic.startswith(f"{topics.prefix}/"):
        return (f"response topic {topic!r} is inside {topics.prefix}/#: replies go to {own_reply} "
                f"or to a topic of the requester's own")
    return None


class CommandChannel:
    """Receives commands (paho's thread), runs them (its own thread), replies (QoS 1)."""

    def __init__(self, topics: Topics, publish: Publish, on_command: CommandHandler | None,
                 counters: Counters, *, mqtt5: bool, disabled: Mapping[str, str] | None = None) -> None:
        self.topics = topics
        self._disabled = dict(disabled or {})  # command name -> why it is refused
        self._publish = publish
        self._on_command = on_command
        self._counters = counters
        self._mqtt5 = mqtt5
        # None wakes the worker at shutdown.
        self._pending: queue.Queue[tuple[str, Command, Any, str | None, bytes | None] | None] = \
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
        reply_to = getattr(props, "ResponseTopic", None) or None
        correlation = getattr(props, "CorrelationData", None) or None
        request_id: Any = None

        def refuse(reason: str) -> None:
            self._counters.add("commands_refused")
            log.warning("MQTT command %r refused: %s", name, reason)
            self._reply(name, request_id, reply_to, correlation, ok=False, error=reason)

        if not message.payload:
            # Zero bytes is how a retained message is cleared; the clearing is delivered too.
            log.debug("MQTT: empty message on %r ignored", message.topic)
            return
        # Checked first so no refusal goes there; refused once request_id is known.
        topic_refusal = None if reply_to is None else \
            response_topic_refusal(reply_to, self.topics.reply(name), self.topics)
        if topic_refusal is not None:
            reply_to = None
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
        if topic_refusal is not None:
            refuse(topic_refusal)
            return
        model = COMMANDS.get(name)
        if model is None:
            refuse(f"unknown command {name!r}; known commands: {', '.join(COMMANDS)}")
            return
        try:
            command = model.model_validate(data)
        except ValidationError as exc:
            refuse("; ".join(f"{'.'.join(str(p) for p in err['loc']) or 'payload'}: "
                             f"{'unknown key' if err['type'] == 'extra_forbidden' else err['msg']}"
                             for err in exc.errors()))
            return
        if name in self._disabled:
            refuse(self._disabled[name])
            return
        if self._on_command is None:
            refuse("this process does not carry out commands (no handler)")
            return
        try:
            self._pending.put_nowait((name, command, request_id, reply_to, correlation))
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

    def _run(self, name: str, command: Command, request_id: Any, reply_to: str | None,
             correlation: bytes | None) -> None:
        assert self._on_command is not None
        try:
            result = dict(self._on_command(name, command) or {})
        except EdgedsmError as exc:
            self._counters.add("commands_refused")
            self._reply(name, request_id, reply_to, correlation, ok=False, error=str(exc))
            return
        except Exception as exc:
            log.exception("MQTT command %r failed in its handler", name)
            self._counters.add("commands_refused")
            self._reply(name, request_id, reply_to, correlation, ok=False,
                        error=f"internal error: {type(exc).__name__}: {exc}")
            return
        # A handler may answer {"ok": False, "error": "..."} instead of raising.
        ok = result.pop("ok", True) is not False
        error = result.pop("error", None)
        self._counters.add("commands" if ok else "commands_refused")
        self._reply(name, request_id, reply_to, correlation, ok=ok,
                    error=None if ok else str(error or "refused by the handler"), result=result or None)

    def _reply(self, name: str, request_id: Any, reply_to: str | None, correlation: bytes | None, *,
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
        self._publish(reply_to or self.topics.reply(name), payload, qos=1, properties=properties)
