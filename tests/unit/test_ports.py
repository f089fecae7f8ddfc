"""The loopback ports the tests' brokers and listeners take (tests/ports.py): each pytest-xdist
worker its own slice, outside the kernel's ephemeral range, no port handed out twice."""

from __future__ import annotations

import socket

import pytest

from tests.ports import _Walk, ephemeral_range, free_port, worker_slice


@pytest.mark.parametrize("workers", [1, 2, 3, 4, 8])
def test_worker_slices_are_disjoint_and_outside_the_ephemeral_range(workers: int) -> None:
    ephemeral = (32768, 60999)
    slices = [worker_slice(f"gw{i}", workers, ephemeral) for i in range(workers)]
    ports = [port for ports in slices for port in ports]
    assert len(ports) == len(set(ports)) and len(slices[-1]) >= 1000
    assert all(1024 < port < ephemeral[0] for port in ports)


def test_without_xdist_the_whole_range_is_one_slice() -> None:
    assert worker_slice(None, 1, (32768, 60999)) == range(10000, 32768)


def test_a_wide_ephemeral_range_moves_the_slices_above_it() -> None:
    assert worker_slice("gw0", 2, (1500, 40000)) == range(40001, 52768)
    assert worker_slice("gw1", 2, (1500, 40000)) == range(52768, 65535)
    with pytest.raises(ValueError, match="not one of 2"):
        worker_slice("gw2", 2, (32768, 60999))


def test_free_ports_are_new_bindable_and_skip_a_port_in_use() -> None:
    low, _ = ephemeral_range()
    taken = [free_port() for _ in range(20)]
    assert len(set(taken)) == 20 and all(port < low for port in taken)
    walk = _Walk()
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", walk.ports[walk.position]))
        held = holder.getsockname()[1]
        port = walk.next_free()
    assert port != held
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", port))
