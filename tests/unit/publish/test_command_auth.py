"""Signing and verifying commands (edgedsm.publish.command_auth): the canonical form, every refusal,
the replay window and its memory bound; properties with hypothesis."""

from __future__ import annotations

import hashlib
import hmac
import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edgedsm.publish.command_auth import (
    AUTH_FIELDS,
    READ_ONLY,
    Authorised,
    CommandVerifier,
    KeyFileError,
    ReplayGuard,
    canonical,
    parse_keys,
    sign,
    signing_key,
)

KEY = b"k" * 32
OTHER = b"o" * 32
TOPIC = "edgedsm/line3/cmd/laser"
NOW = 1_733_260_000.0


def verifier(**kwargs) -> CommandVerifier:
    return CommandVerifier({"alice": KEY, "bob": OTHER}, max_age_s=30.0, **kwargs)


def check(v: CommandVerifier, payload: dict, *, topic: str = TOPIC, now: float = NOW, required: bool = True):
    return v.check(topic, payload, required=required, now=now)


def test_the_canonical_form_is_sorted_compact_json_with_the_topic():
    text = canonical(TOPIC, 1733260000, "n" * 16, "alice", {"state": "on"})
    assert text == (b'{"args":{"state":"on"},"issued":1733260000,"key_id":"alice","nonce":"nnnnnnnnnnnnnnnn",'
                    b'"topic":"edgedsm/line3/cmd/laser","v":1}')
    # the signature is plain HMAC-SHA256 over it: any language can produce it
    payload = sign("alice", KEY, TOPIC, {"state": "on"}, now=NOW + 0.9, nonce="n" * 16)
    assert payload["issued"] == 1733260000
    assert payload["sig"] == hmac.new(KEY, text, hashlib.sha256).hexdigest()


def test_a_signed_command_passes_once_with_its_arguments():
    v = verifier()
    payload = sign("alice", KEY, TOPIC, {"state": "on"}, now=NOW)
    assert check(v, payload) == Authorised({"state": "on"}, "alice")
    assert "replayed" in check(v, payload)


@pytest.mark.parametrize(("change", "why"), [
    (lambda p: p.update(state="off"), "bad signature"),                    # altered argument
    (lambda p: p.update(extra=1), "bad signature"),                        # added argument
    (lambda p: p.update(issued=p["issued"] + 1), "bad signature"),         # altered time
    (lambda p: p.update(nonce="x" * 32), "bad signature"),
    (lambda p: p.update(key_id="bob"), "bad signature"),                   # another operator's id
    (lambda p: p.update(key_id="mallory"), "unknown key id 'mallory'"),
    (lambda p: p.update(sig="0" * 64), "bad signature"),
    (lambda p: p.update(sig=p["sig"].upper()), "sig must be 64 lowercase hex"),
    (lambda p: p.pop("sig"), "not signed: sig missing"),
    (lambda p: [p.pop(k) for k in AUTH_FIELDS], "not signed: issued, nonce, key_id, sig missing"),
    (lambda p: p.update(issued=str(p["issued"])), "issued must be an integer"),
    (lambda p: p.update(issued=True), "issued must be an integer"),
    (lambda p: p.update(nonce="short"), "nonce must be 16-64"),
    (lambda p: p.update(key_id=["alice"]), "unknown key id 'list'"),
])
def test_anything_altered_or_missing_is_refused(change, why):
    payload = sign("alice", KEY, TOPIC, {"state": "on"}, now=NOW)
    change(payload)
    refusal = check(verifier(), payload)
    assert isinstance(refusal, str)
    assert refusal.startswith(why)


def test_a_command_signed_for_another_device_or_command_is_refused():
    payload = sign("alice", KEY, "edgedsm/line4/cmd/laser", {"state": "on"}, now=NOW)
    assert check(verifier(), payload).startswith("bad signature")
    payload = sign("alice", KEY, "edgedsm/line3/cmd/dark", {}, now=NOW)
    assert check(verifier(), payload, topic="edgedsm/line3/cmd/rebaseline").startswith("bad signature")


@pytest.mark.parametrize(("age", "ok"), [(0, True), (30, True), (-30, True), (31, False), (-31, False),
                                         (3600, False), (-86400, False)])
def test_the_age_is_bounded_both_ways(age, ok):
    payload = sign("alice", KEY, TOPIC, {"state": "on"}, now=NOW)
    result = check(verifier(), payload, now=int(NOW) + age)
    assert isinstance(result, Authorised) is ok
    if not ok:
        when = f"{age} s ago" if age > 0 else f"{-age} s in the future"
        assert result.startswith(f"expired: issued {when} by this daemon's clock, more than the 30 s")


def test_without_keys_everything_that_changes_something_is_read_only():
    v = CommandVerifier({}, max_age_s=30.0)
    payload = sign("alice", KEY, TOPIC, {"state": "on"}, now=NOW)
    assert check(v, payload) == READ_ONLY
    assert check(v, {"state": "on"}) == READ_ONLY
    # an open command (publish_maps) passes unsigned, with or without keys
    assert check(v, {}, required=False) == Authorised({}, None)
    assert check(v, sign("alice", KEY, TOPIC, {}, now=NOW), required=False) == Authorised({}, None)
    assert check(verifier(), {}, required=False) == Authorised({}, None)
    # ...but a signature on it must hold
    bad = {**sign("alice", KEY, TOPIC, {}, now=NOW), "sig": "0" * 64}
    assert check(verifier(), bad, required=False).startswith("bad signature")


def test_nan_arguments_have_no_canonical_form():
    payload = sign("alice", KEY, TOPIC, {"seconds": 1.0}, now=NOW)
    payload["seconds"] = float("nan")
    assert check(verifier(), payload).startswith("arguments have no canonical form")


def test_the_signer_refuses_arguments_named_like_auth_keys():
    with pytest.raises(ValueError, match="nonce, request_id"):
        sign("alice", KEY, TOPIC, {"nonce": "x", "request_id": 1}, now=NOW)


def test_nonces_are_forgotten_after_the_window_and_memory_is_bounded():
    guard = ReplayGuard(capacity=3)
    assert guard.admit("a", expires=10, now=0) is None
    assert guard.admit("a", expires=10, now=5).startswith("replayed")
    assert guard.admit("b", expires=12, now=5) is None
    assert guard.admit("c", expires=11, now=5) is None
    assert guard.admit("d", expires=20, now=5).startswith("busy: 3 signed commands")
    assert len(guard) == 3
    assert guard.admit("d", expires=20, now=10.5) is None  # "a" expired at 10
    assert len(guard) == 3
    assert guard.admit("e", expires=30, now=12) is None    # b (12) and c (11) expired
    assert len(guard) == 2
    assert guard.admit("a", expires=40, now=12) is None    # forgotten: the age check stops it now


def test_a_flood_of_signed_commands_stays_within_capacity():
    v = verifier(capacity=100)
    accepted = 0
    for i in range(1000):  # 1000 commands, 10 per second over 100 s
        now = NOW + i / 10
        payload = sign("alice", KEY, TOPIC, {"state": "on"}, now=now, nonce=f"{i:032d}")
        accepted += isinstance(check(v, payload, now=now), Authorised)
    # a nonce lives 31 s (30 + 1), so at 10/s about 310 would be remembered: the bound refuses
    assert len(v._nonces) <= 100
    assert 300 <= accepted <= 400


def test_key_files():
    assert parse_keys("# operators\n\nalice " + "a" * 32 + "\nbob\t" + "b" * 64 + "\n") == {
        "alice": b"a" * 32, "bob": b"b" * 64}
    assert parse_keys("c" * 40 + "\n") == {"default": b"c" * 40}
    for text, why in [("alice " + "a" * 31, "line 1: the secret of 'alice' must be 32-1024"),
                      ("a b c", "line 1: expected 'KEY_ID SECRET'"),
                      ("al/ice " + "a" * 32, "key id 'al/ice'"),
                      (f"x {'a' * 32}\nx {'b' * 32}", "line 2: key id 'x' given twice")]:
        with pytest.raises(KeyFileError, match=why):
            parse_keys(text)
    assert signing_key({"alice": KEY, "bob": OTHER}) == ("alice", KEY)
    assert signing_key({"alice": KEY, "bob": OTHER}, "bob") == ("bob", OTHER)
    with pytest.raises(KeyError, match="no command key with id 'carol'"):
        signing_key({"alice": KEY}, "carol")


json_scalars = st.none() | st.booleans() | st.integers(-2**53, 2**53) | st.floats(allow_nan=False,
                                                                                    allow_infinity=False) \
    | st.text(max_size=20)
arguments = st.dictionaries(st.text(max_size=10).filter(lambda k: k not in (*AUTH_FIELDS, "request_id")),
                            json_scalars, max_size=5)


@settings(max_examples=200, deadline=None)
@given(args=arguments, topic=st.text(min_size=1, max_size=60), age=st.integers(-30, 30))
def test_property_what_is_signed_survives_the_wire_and_passes(args, topic, age):
    payload = sign("alice", KEY, topic, args, now=NOW)
    wire = json.loads(json.dumps({**payload, "request_id": "r"}))  # what the daemon parses
    wire.pop("request_id")
    assert check(verifier(), wire, topic=topic, now=int(NOW) + age) == Authorised(args, "alice")


@settings(max_examples=200, deadline=None)
@given(args=arguments, key=st.binary(min_size=32, max_size=64))
def test_property_a_wrong_key_never_passes(args, key):
    if key == KEY:
        return
    payload = sign("alice", key, TOPIC, args, now=NOW)
    assert check(verifier(), payload).startswith("bad signature")
