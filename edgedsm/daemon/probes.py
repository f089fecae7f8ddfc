"""Public probe hooks of the pipeline, for benchmarks and tests that measure the real thing.

Every callback is optional, runs on the thread named beside it and must return quickly (it
runs inside the measurement loop; ``edgedsm bench e2e`` holds the pipeline thread in
``frame_taken`` on purpose, to run the bare engine between two of its frames). Times are
monotonic seconds, durations seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from edgedsm.daemon.handover import Snapshot
from edgedsm.frames import Frame
from edgedsm.messages import Stats


@dataclass
class PipelineProbes:
    """Optional callbacks at each step of a frame and of an evaluation."""

    #: capture thread: a frame from the camera, and when it was offered to the queue
    frame_queued: Callable[[Frame, float], None] | None = None
    #: capture or pipeline thread: a frame thrown away, and why ("queue": the oldest of a full
    #: queue; "invalid": refused by the engine)
    frame_dropped: Callable[[Frame, str], None] | None = None
    #: pipeline thread: a frame taken off the queue, and the frame count including it
    frame_taken: Callable[[Frame, int], None] | None = None
    #: pipeline thread: a frame pushed into the engine, when the push ended, and its cost
    frame_pushed: Callable[[Frame, float, float], None] | None = None
    #: pipeline thread: an evaluation's region statistics taken from the engine's sums (and the
    #: sums copied when maps are due), and what that cost this thread
    snapshot_taken: Callable[[Snapshot, float], None] | None = None
    #: evaluator thread: an evaluation finished (statistics, states, messages handed to the sink),
    #: the stats message it published, and how long the evaluation took
    evaluated: Callable[[Stats, float], None] | None = None
    #: evaluator thread: the drying states of an evaluation judged and its alerts handed to the
    #: sink (every evaluation, states-only ones too): the frames it includes, and when (the end
    #: of a frame → alert latency)
    states_evaluated: Callable[[int, float], None] | None = None
