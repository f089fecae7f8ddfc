"""`edgedsm bench soak`'s schedule: which fault is injected at which turn (the soak itself, with
its real parts, is tests/faults/test_soak.py)."""

from __future__ import annotations

import argparse

import pytest

from edgedsm_lab.bench.soak import FAULTS, add_arguments, fault_due


def _kills(kill_every: int, rounds: int) -> list[int]:
    kinds = list(FAULTS)
    return [turn // len(kinds) for turn in range(rounds * len(kinds))
            if kinds[turn % len(kinds)] == "daemon SIGKILL" and fault_due("daemon SIGKILL", turn, kill_every)]


def test_every_fault_every_round_by_default() -> None:
    kinds = list(FAULTS)
    assert all(fault_due(kinds[turn % len(kinds)], turn, 1) for turn in range(4 * len(kinds)))
    assert _kills(1, 4) == [0, 1, 2, 3]


def test_a_sigkill_every_kth_round_lets_one_process_live_through_the_others() -> None:
    assert _kills(3, 8) == [0, 3, 6]
    assert _kills(1000, 50) == [0]  # one daemon process through 49 rounds of the other faults
    kinds = list(FAULTS)
    others = [kind for kind in kinds if kind != "daemon SIGKILL"]
    assert all(fault_due(kind, turn, 1000) for turn in range(50 * len(kinds)) for kind in others)


def test_kill_every_below_one_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert parser.parse_args(["--kill-every", "5"]).kill_every == 5
    with pytest.raises(SystemExit) as info:
        parser.parse_args(["--kill-every", "0"])
    assert info.value.code == 2 and "must be at least 1" in capsys.readouterr().err


def test_kill_every_not_a_number_is_refused_in_words(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    with pytest.raises(SystemExit) as info:
        parser.parse_args(["--kill-every", "often"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "a whole number of rounds, got 'often'" in err and "_rounds" not in err
