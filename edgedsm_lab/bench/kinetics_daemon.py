"""The kinetics' cost as the daemon runs it (docs/kinetics.md, "Cost in the daemon at 2048²").

Two regions covering the frame (its left and right halves), every ``step`` of ``[kinetics]``:
the pipeline thread's push of every region (:meth:`KineticsRegions.push`) and its read at each
evaluation (:meth:`KineticsRegions.read`), against the default S1+S2+S3 push of the same frames
(N = 200, m = 10, sliding), best and median of the rounds, random 8-bit frames.

    python -m edgedsm_lab.bench.kinetics_daemon [--size 2048] [--steps 1 2 4 6 8] [--rounds 12]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence

import numpy as np

from edgedsm.config.kinetics import KineticsSection
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.noise import NoiseModel
from edgedsm.measurement.kinetics import KineticsRegions

DT = 0.1  # s: the frame interval the ages are counted at
LONGEST_FRAMES = 4096  # the longest age (57 slots at 4 per octave)
FULL_LONGEST_FRAMES = 1024  # at step 1 (46 slots): 4 bytes per pixel per slot at full resolution


def _times(call: Callable[[int], object], rounds: int) -> tuple[float, float]:
    """Best and median seconds of ``rounds`` calls (the round's index passed)."""
    spent = []
    for index in range(rounds):
        started = time.perf_counter()
        call(index)
        spent.append(time.perf_counter() - started)
    return min(spent), float(np.median(spent))


def measure(size: int, steps: Sequence[int], rounds: int = 12, seed: int = 0) -> list[dict[str, float]]:
    """One row per step: kept pixels, memory (bytes), push and read (s, best and median), and
    the push's share of the default push."""
    rng = np.random.default_rng(seed)
    frames = [rng.integers(0, 256, (size, size), dtype=np.uint8) for _ in range(4)]
    left = np.zeros((size, size), bool)
    left[:, : size // 2] = True
    masks = {"left": left, "right": ~left}
    engine = SlidingWindow((size, size), window=200, lag=10, q=1.0, bits=8, estimators=("s1", "s2", "s3"))
    for index in range(210):
        engine.push(frames[index % 4])
    default = _times(lambda i: engine.push(frames[i % 4]), rounds)
    rows = []
    for step in steps:
        longest = FULL_LONGEST_FRAMES if step == 1 else LONGEST_FRAMES
        kinetics = KineticsRegions(KineticsSection(enabled=True, longest_age_s=longest * DT, step=step), masks,
                                   NoiseModel(gain=0.25))
        for index in range(70):
            kinetics.push(frames[index % 4], DT)
        push = _times(lambda i, k=kinetics: k.push(frames[i % 4], None), rounds)
        read = _times(lambda _, k=kinetics: k.read(DT), max(3, rounds // 2))
        rows.append({"step": step, "pixels": sum(int(m.sum()) for m in kinetics.masks.values()),
                     "slots": int(next(iter(kinetics.regions.values())).lower.size),
                     "memory": kinetics.memory_bytes, "push_best": push[0], "push_median": push[1],
                     "read_best": read[0], "read_median": read[1], "default_best": default[0],
                     "default_median": default[1], "share_best": push[0] / default[0],
                     "share_median": push[1] / default[1]})
        del kinetics
    return rows


def table(rows: list[dict[str, float]]) -> str:
    """The rows as docs/kinetics.md's table."""
    lines = ["| `step` | kept pixels | slots | memory | push (ms) | × default push | read (ms) |",
             "|---:|---:|---:|---:|---:|---:|---:|"]
    for row in rows:
        lines.append(f"| {row['step']} | {row['pixels']:,} | {row['slots']} | {row['memory'] / 2**20:.0f} MiB | "
                     f"{row['push_best'] * 1e3:.2f} | {row['share_best']:.3f}–{row['share_median']:.3f} | "
                     f"{row['read_best'] * 1e3:.1f}–{row['read_median'] * 1e3:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048, help="frame side in pixels (default 2048)")
    parser.add_argument("--steps", type=int, nargs="+", default=[1, 2, 4, 6, 8], help="[kinetics] steps")
    parser.add_argument("--rounds", type=int, default=12, help="pushes timed per step (default 12)")
    args = parser.parse_args(argv)
    rows = measure(args.size, args.steps, args.rounds)
    print(f"default S1+S2+S3 push of {args.size}²: best {rows[0]['default_best'] * 1e3:.2f} ms, "
          f"median {rows[0]['default_median'] * 1e3:.2f} ms")
    print(table(rows), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
