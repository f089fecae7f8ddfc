"""The daemon's signal handlers are its own only while it runs: in-process callers (tests,
embedding code) get theirs back."""

from __future__ import annotations

import signal
from types import FrameType

from edgedsm.config import load_config
from edgedsm.daemon.service import Service


def test_handlers_stop_and_reload_inside_and_are_restored_after(repo) -> None:
    config = load_config(repo / "config" / "daemon" / "demo.toml")
    config.mqtt = None
    service = Service(None, config=config)
    seen: list[int] = []

    def mine(signum: int, frame: FrameType | None) -> None:
        seen.append(signum)

    before = {signum: signal.signal(signum, mine) for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
    try:
        with service.handling_signals():
            signal.raise_signal(signal.SIGHUP)
            assert service._reload.is_set() and not service._stop.is_set()
            signal.raise_signal(signal.SIGTERM)
            assert service._stop.is_set() and service.exit_reason == "SIGTERM"
        assert seen == []
        assert all(signal.getsignal(signum) is mine for signum in before)
        signal.raise_signal(signal.SIGHUP)
        assert seen == [signal.SIGHUP]
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)
