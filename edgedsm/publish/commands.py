"""Commands accepted on ``<prefix>/<device>/cmd/<name>``: a small, documented set.

Payload: a JSON object. The optional key ``request_id`` (string or integer) is echoed in the
reply; ``issued``, ``nonce``, ``key_id`` and ``sig`` sign it (``edgedsm.publish.command_auth``);
every other key must belong to the command. Every command but ``publish_maps`` changes the
laser or the measurement and is executed only when signed with a command key the daemon holds
(docs/security.md). A zero-length payload is ignored without a reply: that is what clearing a
retained message delivers. Retained commands are refused (with MQTT 5 also on their first,
live delivery: the daemon subscribes with retain-as-published).

=================  ==========================  ===============================================
name               payload                     effect
=================  ==========================  ===============================================
``laser``          ``{"state": "on"|"off"|     switch the laser on or off and hold it so;
                   "auto"}``                   ``auto`` hands it back to the acquisition plan
``rebaseline``     ``{}``                      restart the estimator window and drying
                                               baseline (daemon handler)
``dark``           ``{}``                      take dark frames (laser off) now (daemon handler)
``publish_maps``   ``{}``                      publish the maps at the next chance instead of
                                               waiting for the maps interval (daemon handler)
``record``         ``{"seconds": S}``          record every frame for S seconds (default
                   (optional)                  ``[recording] post_s``) in a clip file of its
                                               own; needs ``[recording]`` (daemon handler)
=================  ==========================  ===============================================

Bounds: at most 16 KiB and 8 levels of nesting, checked before parsing. Reply (JSON, QoS 1, not
retained) always on ``<prefix>/<device>/cmd/<name>/reply`` (an MQTT v5 Response Topic is
ignored: a requester must not make the daemon publish anywhere else; its Correlation Data is
echoed)::

    {"ok": true|false, "command": "laser", "request_id": ..., "error": null|"why",
     "result": {...}|null, "t": 1718000000.123}
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field


class Command(BaseModel):
    """Base of every command payload: unknown keys refused, immutable once validated."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    #: Changes the laser or the measurement: executed only when signed (``command_auth``).
    requires_authorisation: ClassVar[bool] = True


class LaserCommand(Command):
    """Switch the laser on or off and hold it so, or hand it back to the acquisition plan."""

    state: Literal["on", "off", "auto"] = Field(
        description="'on' or 'off' (held until the next laser command), 'auto' (as the acquisition plan says)")


class RebaselineCommand(Command):
    """Forget the current window and drying baseline and start again."""


class DarkCommand(Command):
    """Take dark frames (laser off) now to re-measure the ambient level."""


class PublishMapsCommand(Command):
    """Publish the maps at the next chance instead of waiting for maps_interval_s."""

    #: Changes nothing: a read of what is already published, coalesced into the next maps
    #: message (so a flood costs at most the maps a frame rate allows); open to any client the
    #: broker lets write the topic.
    requires_authorisation: ClassVar[bool] = False


class RecordCommand(Command):
    """Record a clip now (``[recording]``): every frame for ``seconds``, in any mode."""

    seconds: float | None = Field(None, gt=0, le=3600,
                                  description="length of the clip (default: [recording] post_s)")


COMMANDS: dict[str, type[Command]] = {
    "laser": LaserCommand,
    "rebaseline": RebaselineCommand,
    "dark": DarkCommand,
    "publish_maps": PublishMapsCommand,
    "record": RecordCommand,
}


@dataclass(frozen=True)
class CommandResult:
    """What a handler answers to a command: carried out or refused (``error`` says why), and the
    laser's state where the command concerns it. The reply's ``result`` is its fields but ``ok``
    and ``error`` (:meth:`as_mapping`: what a :data:`CommandHandler` returns)."""

    ok: bool = True
    error: str | None = None
    laser: Literal["on", "off", "unknown"] | None = None

    @classmethod
    def refused(cls, error: str, laser: Literal["on", "off", "unknown"] | None = None) -> CommandResult:
        return cls(ok=False, error=error, laser=laser)

    def as_mapping(self) -> dict[str, Any]:
        result: dict[str, Any] = {"ok": self.ok}
        if self.error is not None:
            result["error"] = self.error
        if self.laser is not None:
            result["laser"] = self.laser
        return result


class CommandReply(BaseModel):
    """The reply to a command (see the module docstring); what subscribers parse."""

    model_config = ConfigDict(extra="ignore", frozen=True)

    ok: bool = Field(description="the command was carried out")
    command: str = Field(max_length=256, description="the command's name, as in the request topic")
    request_id: str | int | None = Field(None, description="echoed from the request")
    error: str | None = Field(None, description="why it was refused (ok false)")
    result: dict[str, Any] | None = Field(None, description="what the handler returned")
    t: float = Field(description="UTC epoch s of the reply")
