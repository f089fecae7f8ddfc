"""Errors of the publishing layer (MQTT, map encoding, alert queue)."""

from __future__ import annotations

from edgedsm.errors import EdgedsmError


class PublishError(EdgedsmError):
    """The broker refused us, could not be reached in time, or an alert could not be stored."""


class MapCodecError(PublishError, ValueError):
    """A map could not be encoded (non-finite values, bad shape) or a payload not decoded."""


class StorageError(PublishError):
    """The state directory refused a write or a read (disk full, read-only, I/O error)."""
