"""What the pipeline thread hands the evaluator thread at each evaluation: the pipeline's
:class:`Status` beside the maps, and a :class:`Snapshot` of the engine's sums reduced to what the
evaluation needs. Plain frozen data: the only thing the two threads share besides the sink."""

from __future__ import annotations

from dataclasses import dataclass, field

from edgedsm.estimators.region_stats import Moments
from edgedsm.estimators.snapshot import EngineSnapshot, TauSnapshot
from edgedsm.messages import LaserState, RecordingStats, RegionKinetics
from edgedsm.noise_patches import PatchWindow


@dataclass(frozen=True)
class Status:
    """What the pipeline knows beside the maps at one evaluation (monotonic ``now``)."""

    now: float
    frames: int
    fps: float
    laser: LaserState
    drops: dict[str, int]
    camera: dict[str, float | int | str | None]
    ambient_level: float | None
    warning: str | None
    fault: str | None
    recording: RecordingStats | None = None


@dataclass(frozen=True)
class Snapshot:
    """One evaluation's input, handed from the pipeline thread to the evaluator thread."""

    status: Status
    ready: bool
    engine: EngineSnapshot | None = None  # a copy of the sums when maps are published (else None);
    # valid until the next copy, which reuses its buffers
    publish_maps: bool = False
    publish_stats: bool = True  # False: the drying states only (activity means, no stats message)
    tau: TauSnapshot | None = None  # τc's sums, when τc is estimated and this evaluation needs it
    #: region -> map -> moments, from the live sums on the pipeline thread (empty before the window
    #: is full); states only: the judged map's means
    regions: dict[str, dict[str, Moments]] = field(default_factory=dict)
    #: the measurement it belongs to: an evaluation taken before a rebaseline is not judged after it
    generation: int = 0
    #: top-left corner (column, row) of the area the engine sees in camera pixels, when it sees
    #: only the regions' bounding box (``estimator.area = "regions"``); None: the whole frame
    origin: tuple[int, int] | None = None
    #: region -> its noise patch over the last frames (estimator.noise_floor, on the stats cadence)
    patches: dict[str, PatchWindow] = field(default_factory=dict)
    #: region -> its kinetics read on the pipeline thread ([kinetics] on; empty otherwise)
    kinetics: dict[str, RegionKinetics] = field(default_factory=dict)
