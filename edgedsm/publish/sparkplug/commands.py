"""Node commands (NCMD): what edgedsm accepts and how it refuses the rest (pure, apart from the
log). The one writable metric is ``Node Control/Rebirth`` (boolean ``true``); every other metric
is read-only, and a payload that is not Sparkplug B, a retained command, an unknown name or alias
and a value of the wrong type are refused: logged (rate-limited) and counted, never raised."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from edgedsm.publish.sparkplug.book import MetricBook
from edgedsm.publish.sparkplug.payload import PayloadError, decode_command

#: The rebirth request (spec: tck-id-operational-behavior-data-commands-rebirth-name).
REBIRTH = "Node Control/Rebirth"

#: Longest NCMD payload decoded (a rebirth request is a few dozen bytes).
MAX_COMMAND_BYTES = 64 * 1024

#: Refusals are logged at most this often; the ones in between are counted in the next line.
REFUSAL_LOG_EVERY_S = 1.0


@dataclass
class Verdict:
    """What one NCMD asks for: a rebirth, and the reasons its other parts were refused."""

    rebirth: bool = False
    refusals: list[str] = field(default_factory=list)


def judge(payload: bytes, retained: bool, node: MetricBook, device: MetricBook) -> Verdict:
    """Decide on one NCMD payload against the node's and the device's metrics."""
    verdict = Verdict()
    if retained:
        # a retained command would run again after every reconnection
        verdict.refusals.append("NCMD refused: retained (commands must be published with retain=false)")
        return verdict
    if len(payload) > MAX_COMMAND_BYTES:
        verdict.refusals.append(f"NCMD refused: {len(payload)} bytes, more than the {MAX_COMMAND_BYTES} accepted")
        return verdict
    try:
        metrics = decode_command(payload)
    except PayloadError as exc:
        verdict.refusals.append(f"NCMD refused: {exc}")
        return verdict
    for metric in metrics:
        name = metric.name
        if name is None and metric.alias is not None:
            name = node.name_of(metric.alias) or device.name_of(metric.alias)
            if name is None:
                verdict.refusals.append(f"NCMD refused: unknown metric alias {metric.alias}")
                continue
        if name is None:
            verdict.refusals.append("NCMD refused: a metric with neither name nor alias")
        elif name == REBIRTH:
            if metric.value_kind == "boolean_value" and metric.value is True:
                verdict.rebirth = True
            else:
                verdict.refusals.append(f"NCMD refused: {REBIRTH} needs the boolean value true, "
                                        f"got {metric.value_kind or 'no value'} {metric.value!r}")
        elif name in node or name in device:
            verdict.refusals.append(f"NCMD refused: {name!r} is read-only (only {REBIRTH!r} can be written)")
        else:
            verdict.refusals.append(f"NCMD refused: unknown metric {name[:80]!r}")
    return verdict


class RefusalLog:
    """Logs refusals at most once per ``REFUSAL_LOG_EVERY_S``, with how many were not logged,
    so a flood of bad commands cannot flood the journal."""

    def __init__(self, logger: logging.Logger) -> None:
        self._log = logger
        self._last = -float("inf")
        self._suppressed = 0

    def refused(self, reason: str) -> None:
        now = time.monotonic()
        if now - self._last < REFUSAL_LOG_EVERY_S:
            self._suppressed += 1
            return
        more = f" ({self._suppressed} more refused since the last report)" if self._suppressed else ""
        self._log.warning("Sparkplug: %s%s", reason, more)
        self._last, self._suppressed = now, 0
