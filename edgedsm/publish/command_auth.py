"""Signed, time-limited commands: the one canonical form, signing and verifying (no I/O here; the
keys are read by :func:`edgedsm.publish.settings.resolve_command_keys`).

A command that changes the laser or the measurement carries, beside its arguments::

    {"state": "on", "issued": 1733260000, "nonce": "9f2c...", "key_id": "alice", "sig": "5be1..."}

``sig`` is HMAC-SHA256 (hex) with the key named ``key_id`` over :func:`canonical`: the JSON of
``{"v": 1, "topic": <full command topic>, "issued": ..., "nonce": ..., "key_id": ..., "args": {...}}``
with sorted keys, no spaces and ASCII escapes (``json.dumps(..., sort_keys=True,
separators=(",", ":"))``). ``args`` are the payload's keys but ``request_id`` and the four above.
The topic is in the MAC, so a command signed for ``line3`` is refused by ``line4``; ``issued``
(integer epoch seconds) bounds its age; the daemon remembers every nonce until its command could
no longer pass the age check, so a captured command cannot be sent again.

The daemon refuses (in this order): a command without the four keys, an unknown ``key_id``, a
wrong ``sig``, ``issued`` more than ``max_age_s`` from its clock (either way: clock skew), and a
nonce already seen. With no key configured every command that needs authorisation is refused
("read-only: no command key").
"""

from __future__ import annotations

import hashlib
import hmac
import json
import re
import secrets
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

SIGNATURE_VERSION = 1
AUTH_FIELDS = ("issued", "nonce", "key_id", "sig")
KEY_ID_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,32}$")
NONCE_PATTERN = re.compile(r"^[A-Za-z0-9_-]{16,64}$")
SIG_PATTERN = re.compile(r"^[0-9a-f]{64}$")
KEY_MIN_CHARS = 32      # `openssl rand -hex 32` gives 64
KEY_MAX_CHARS = 1024
KEYS_MAX = 64           # keys in one key file (one per operator or system)
DEFAULT_KEY_ID = "default"
NONCE_CAPACITY = 4096   # nonces remembered at once; beyond it commands are refused as "busy"
READ_ONLY = "read-only: no command key is configured on this daemon (docs/security.md)"


class KeyFileError(ValueError):
    """A key file's text is not valid (the caller names the file)."""


def parse_keys(text: str) -> dict[str, bytes]:
    """Keys from a key file's text: one key per line, ``KEY_ID SECRET`` or a bare ``SECRET``
    (its id is ``default``); blank lines and ``#`` comments ignored. The secret is used as its
    UTF-8 bytes, at least ``KEY_MIN_CHARS`` printable characters without spaces."""
    keys: dict[str, bytes] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) > 2:
            raise KeyFileError(f"line {number}: expected 'KEY_ID SECRET' or 'SECRET', got {len(parts)} words")
        key_id, secret = (DEFAULT_KEY_ID, parts[0]) if len(parts) == 1 else (parts[0], parts[1])
        if not KEY_ID_PATTERN.match(key_id):
            raise KeyFileError(f"line {number}: key id {key_id[:40]!r} is not 1-32 of A-Z a-z 0-9 _ . -")
        if not KEY_MIN_CHARS <= len(secret) <= KEY_MAX_CHARS or not secret.isprintable():
            raise KeyFileError(f"line {number}: the secret of {key_id!r} must be {KEY_MIN_CHARS}-{KEY_MAX_CHARS} "
                               f"printable characters (make one with: openssl rand -hex 32)")
        if key_id in keys:
            raise KeyFileError(f"line {number}: key id {key_id!r} given twice")
        keys[key_id] = secret.encode("utf-8")
        if len(keys) > KEYS_MAX:
            raise KeyFileError(f"more than {KEYS_MAX} keys")
    return keys


def canonical(topic: str, issued: int, nonce: str, key_id: str, arguments: Mapping[str, Any]) -> bytes:
    """The bytes that are signed: the one canonical form of a command."""
    document = {"v": SIGNATURE_VERSION, "topic": topic, "issued": issued, "nonce": nonce, "key_id": key_id,
                "args": dict(arguments)}
    return json.dumps(document, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False).encode("ascii")


def signature(key: bytes, message: bytes) -> str:
    return hmac.new(key, message, hashlib.sha256).hexdigest()


def sign(key_id: str, key: bytes, topic: str, arguments: Mapping[str, Any], *, now: float,
         nonce: str | None = None) -> dict[str, Any]:
    """``arguments`` plus ``issued``, ``nonce``, ``key_id`` and ``sig``: a payload for ``topic``
    (add ``request_id`` after signing, it is not signed). ``now``: epoch seconds."""
    clash = [key for key in arguments if key in AUTH_FIELDS or key == "request_id"]
    if clash:
        raise ValueError(f"arguments may not contain {', '.join(clash)} (set by the signer)")
    issued = int(now)
    nonce = secrets.token_hex(16) if nonce is None else nonce
    sig = signature(key, canonical(topic, issued, nonce, key_id, arguments))
    return {**arguments, "issued": issued, "nonce": nonce, "key_id": key_id, "sig": sig}


def signing_key(keys: Mapping[str, bytes], key_id: str | None = None) -> tuple[str, bytes]:
    """The key a sender signs with: ``key_id``'s, else the first in the file (KeyError saying why)."""
    if not keys:
        raise KeyError("no command key (docs/security.md)")
    if key_id is None:
        key_id = next(iter(keys))
    if key_id not in keys:
        raise KeyError(f"no command key with id {key_id!r} (have: {', '.join(keys)})")
    return key_id, keys[key_id]


@dataclass(frozen=True)
class Authorised:
    """A command whose signature held: its arguments (without the auth keys) and who signed it."""

    arguments: dict[str, Any]
    key_id: str | None  # None: an open command sent without a signature


class ReplayGuard:
    """Nonces seen, each kept until its command could no longer pass the age check (bounded)."""

    def __init__(self, capacity: int = NONCE_CAPACITY) -> None:
        self.capacity = capacity
        self._expiry: OrderedDict[str, float] = OrderedDict()  # nonce -> when it may be forgotten

    def __len__(self) -> int:
        return len(self._expiry)

    def admit(self, nonce: str, expires: float, now: float) -> str | None:
        """Remember ``nonce`` until ``expires``; why not (replayed, full), or None."""
        while self._expiry:  # ordered by insertion, expiries nearly so: forget from the oldest
            old, until = next(iter(self._expiry.items()))
            if until > now:
                break
            del self._expiry[old]
        if nonce in self._expiry:
            return "replayed: this nonce was already used (every command needs a fresh one)"
        if len(self._expiry) >= self.capacity:
            # a late expiry can sit behind an early one: sweep all before refusing
            for old in [n for n, until in self._expiry.items() if until <= now]:
                del self._expiry[old]
            if len(self._expiry) >= self.capacity:
                return f"busy: {self.capacity} signed commands within the replay window; try again"
        self._expiry[nonce] = expires
        return None


class CommandVerifier:
    """The daemon's check of a command's signature, age and nonce (one per command channel).

    ``keys``: key id -> secret (empty: read-only). ``max_age_s``: largest |now - issued|."""

    def __init__(self, keys: Mapping[str, bytes], max_age_s: float, capacity: int = NONCE_CAPACITY) -> None:
        self._keys = dict(keys)
        self.max_age_s = max_age_s
        self._nonces = ReplayGuard(capacity)

    @property
    def read_only(self) -> bool:
        return not self._keys

    def check(self, topic: str, payload: Mapping[str, Any], *, required: bool,
              now: float) -> Authorised | str:
        """``payload`` (without request_id) verified for ``topic``: an :class:`Authorised`, or the
        reason for refusing it. ``required``: the command changes the laser or the measurement;
        an open command passes unsigned (a signed one is still checked when there are keys)."""
        arguments = {key: value for key, value in payload.items() if key not in AUTH_FIELDS}
        present = [key for key in AUTH_FIELDS if key in payload]
        if not required and (not present or self.read_only):
            return Authorised(arguments, None)  # open; without keys a signature cannot be checked
        if self.read_only:
            return READ_ONLY
        if len(present) < len(AUTH_FIELDS):
            missing = ", ".join(key for key in AUTH_FIELDS if key not in payload)
            return f"not signed: {missing} missing (sign it with edgedsm cmd and a command key; docs/security.md)"
        issued, nonce, key_id, sig = (payload[key] for key in AUTH_FIELDS)
        if not isinstance(issued, int) or isinstance(issued, bool) or not 0 <= issued < 2**40:
            return "issued must be an integer (epoch seconds)"
        if not isinstance(nonce, str) or not NONCE_PATTERN.match(nonce):
            return "nonce must be 16-64 characters of A-Z a-z 0-9 _ -"
        if not isinstance(key_id, str) or key_id not in self._keys:
            shown = key_id[:40] if isinstance(key_id, str) else type(key_id).__name__
            return f"unknown key id {shown!r}"
        if not isinstance(sig, str) or not SIG_PATTERN.match(sig):
            return "sig must be 64 lowercase hex digits (HMAC-SHA256)"
        try:
            message = canonical(topic, issued, nonce, key_id, arguments)
        except ValueError as exc:  # NaN/inf arguments cannot have been signed canonically
            return f"arguments have no canonical form: {exc}"
        if not hmac.compare_digest(signature(self._keys[key_id], message), sig):
            return "bad signature (wrong key, another device's topic, or the command was altered)"
        age = now - issued
        if abs(age) > self.max_age_s:
            when = f"{age:.0f} s ago" if age > 0 else f"{-age:.0f} s in the future"
            return (f"expired: issued {when} by this daemon's clock, more than the {self.max_age_s:g} s "
                    f"allowed ([mqtt] command_max_age_s; check both clocks)")
        refusal = self._nonces.admit(nonce, issued + self.max_age_s + 1.0, now)
        if refusal is not None:
            return refusal
        return Authorised(arguments, key_id)
