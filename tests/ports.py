"""Loopback TCP ports for what the tests start (brokers, HTTP listeners, socat), each pytest-xdist
worker from its own range.

A port taken with bind(("127.0.0.1", 0)) and released again is only free until someone else binds
it: the kernel hands the same ephemeral range to every process's bind(0) and connect(), so with
several workers a broker could find its port taken by another worker's broker or client. Here each
worker walks its own slice of the ports below the ephemeral range, which no bind(0) or connect()
hands out, and never offers the same port twice; a port something already holds is skipped.
"""

from __future__ import annotations

import os
import random
import socket
from pathlib import Path

LOWEST = 10000  # above the well-known and most registered service ports
FALLBACK_EPHEMERAL = (32768, 60999)  # Linux's default


def ephemeral_range() -> tuple[int, int]:
    """The ports the kernel gives bind(0) and connect() (Linux: ip_local_port_range)."""
    try:
        low, high = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return int(low), int(high)
    except (OSError, ValueError):
        return FALLBACK_EPHEMERAL


def worker_slice(worker: str | None, workers: int, ephemeral: tuple[int, int]) -> range:
    """The ports of ``worker`` ("gw0", "gw1", ...; None when not under xdist) out of ``workers``:
    an equal share of those outside the ephemeral range (below it, else above it)."""
    low, high = ephemeral
    start, stop = (LOWEST, low) if low - LOWEST >= 1000 * workers else (high + 1, 65536)
    index = int(worker.removeprefix("gw")) if worker else 0
    if not 0 <= index < workers:
        raise ValueError(f"worker {worker!r} is not one of {workers}")
    size = (stop - start) // workers
    return range(start + index * size, start + (index + 1) * size)


class _Walk:
    """This process's slice, from a random start (two test runs on one machine, with the same
    worker names, rarely walk the same ports), round and round."""

    def __init__(self) -> None:
        self.ports = worker_slice(os.environ.get("PYTEST_XDIST_WORKER"),
                                  int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")), ephemeral_range())
        self.position = random.randrange(len(self.ports))

    def next_free(self) -> int:
        for _ in range(len(self.ports)):
            port = self.ports[self.position]
            self.position = (self.position + 1) % len(self.ports)
            with socket.socket() as sock:
                try:
                    sock.bind(("127.0.0.1", port))
                except OSError:
                    continue  # in use, or in TIME_WAIT
                return port
        raise RuntimeError(f"no free loopback port in {self.ports}")


_walk: _Walk | None = None


def free_port() -> int:
    """A loopback TCP port that nothing holds now and that this process has not handed out
    lately (not before the rest of its slice)."""
    global _walk
    if _walk is None:
        _walk = _Walk()
    return _walk.next_free()
