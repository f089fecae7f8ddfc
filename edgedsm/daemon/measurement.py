"""The measurement, on the pipeline thread: the streaming engine for the camera's frames and
the region masks, and at each evaluation a :class:`~edgedsm.daemon.handover.Snapshot` of what the
evaluator needs.

The pipeline thread pushes frames into the engine and, on the states and stats cadence, reduces
the engine's live sums to region statistics between two pushes
(:func:`edgedsm.estimators.region_stats.region_moments`: one pass over the rows the regions cover,
each pixel's maps computed once whatever the regions holding it, no float maps and no copy of
the sums). States need the activity map's region means only; the full statistics (count, mean,
deviation, percentile sample of every map) come on the stats cadence. Only on the maps cadence
are the sums copied (``engine.snapshot()``), into buffers the next copy reuses.

With ``estimator.area = "regions"`` the engine sees only the bounding box of all regions (frames
are cropped before the push): the cost follows the regions, and the published maps cover that
box (the snapshot's ``origin`` gives its top-left corner in camera pixels).
"""

from __future__ import annotations

import logging
import time
from collections import Counter

import numpy as np

from edgedsm.config import DaemonConfig, check_regions
from edgedsm.daemon.engine_budget import check_memory, kernel_threads, make_engine
from edgedsm.daemon.handover import Snapshot, Status
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.daemon.tau import TauRegions
from edgedsm.errors import FrameError
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.region_box import RegionBox, bounding_box
from edgedsm.estimators.region_stats import Moments, RegionLayout, RegionPlan
from edgedsm.estimators.snapshot import EngineSnapshot, MapBuffers, TauSnapshot
from edgedsm.frames import Frame, FrameFormat
from edgedsm.measurement.core import reduce
from edgedsm.measurement.kinetics import KineticsRegions
from edgedsm.messages import RegionKinetics
from edgedsm.noise_patches import NoisePatches

log = logging.getLogger(__name__)

#: The frame interval the kinetics' memory is checked at before frames tell it (no
#: ``camera.frame_interval_s``): 30 frames a second.
KINETICS_BUDGET_INTERVAL_S = 1.0 / 30.0
#: Frames whose timestamps give the interval that fixes the kinetics' longest age in frames
#: (without ``camera.frame_interval_s``): the median of this many steps, not one step's jitter.
KINETICS_INTERVAL_FRAMES = 16


def full_mask(box: RegionBox, shape: tuple[int, int]) -> np.ndarray:
    """A region's boolean mask over the whole of ``shape`` (the engine's coordinates)."""
    mask = np.zeros(shape, bool)
    mask[box.rows, box.cols] = box.mask
    return mask


def kinetics_bytes(config: DaemonConfig, masks: dict[str, np.ndarray]) -> dict[str, int]:
    """The kinetics' reference frames for ``masks`` (none without), by the config key bounding
    them, at the configured frame interval or KINETICS_BUDGET_INTERVAL_S."""
    if not masks:
        return {}
    interval = config.camera.frame_interval_s or KINETICS_BUDGET_INTERVAL_S
    return {"kinetics.longest_age_s": KineticsRegions.bytes_for(config.kinetics, masks, interval)}


class Measurement:
    """The engine and the region masks of one camera (pipeline thread only)."""

    def __init__(self, config: DaemonConfig, tau: TauRegions, map_buffers: MapBuffers, counters: Counter[str],
                 probes: PipelineProbes | None = None) -> None:
        self.config = config
        self.tau = tau  # shared with the evaluator, which forms τc from the sums taken here
        self.counters = counters
        self.probes = probes or PipelineProbes()
        self.engine: SlidingWindow | None = None
        self.format: FrameFormat | None = None  # the camera's word before frames flow; the first frame's
        self._settled = False  # a frame came: the format is fixed, later misfits are refused
        self.regions: dict[str, RegionBox] = {}  # in the engine's coordinates
        self._layout = RegionLayout.of({})  # the same, prepared for region_moments
        self.crop: tuple[slice, slice] | None = None  # estimator.area = "regions": the box the engine sees
        self._buffers: EngineSnapshot | None = None  # the latest copy of the sums, overwritten by the next
        self._map_buffers = map_buffers  # the evaluator's float maps: reserved here with the engine
        self._tau_buffers: TauSnapshot | None = None
        self.noise: NoisePatches | None = None  # estimator.noise_floor: each region's last frames
        self.kinetics: KineticsRegions | None = None  # [kinetics]: each region's reference frames
        #: seconds the last kinetics read took (pipeline thread; O(slots × region pixels))
        self.kinetics_read_s = 0.0
        self._interval_frames = 0  # frames seen while the kinetics waited for the interval

    @property
    def frame_shape(self) -> tuple[int, int] | None:
        return self.format.shape if self.format is not None else None

    @property
    def settled(self) -> bool:
        """A frame came: the format is fixed (until :meth:`release`)."""
        return self._settled

    def prepare(self, fmt: FrameFormat, *, frame: bool = True) -> None:
        """The engine and the region masks for frames of ``fmt``, its arrays written: before frames
        flow with the camera's word (``frame=False``), then at the first frame (before the laser
        goes on), which decides: a camera that told another format gets them built again. A region
        outside the frame or a window too big for memory is a ``ConfigError``."""
        if self._settled:
            return
        if fmt != self.format or self.engine is None:
            self._drop_engine()  # its memory first
            self._make_engine(fmt)
        self._settled = frame

    def push(self, frame: Frame, dark: np.ndarray | None) -> bool:
        """Push one frame (ambient-corrected with ``dark`` when configured); False if refused."""
        if self.engine is None:  # the first frame fixes the shape; later misfits are refused
            self.prepare(frame.format)
        assert self.engine is not None
        pixels = frame.pixels
        if self.crop is not None and pixels.shape == frame.shape:
            pixels = np.ascontiguousarray(pixels[self.crop])
            dark = dark[self.crop] if dark is not None and dark.shape == frame.shape else None
        if self.config.estimator.ambient_correction and dark is not None and dark.shape == pixels.shape:
            # ambient-corrected S2: the dark level is subtracted before normalising (saturating at 0)
            pixels = np.subtract(pixels, np.minimum(pixels, dark))
        try:
            self.engine.push(pixels)
            self.tau.interval.saw(frame)
            if self.noise is not None:
                self.noise.push(pixels)
            if self.kinetics is not None:  # the interval fixes the longest age in frames, once
                self.kinetics.push(pixels, None if self.kinetics.built else self._kinetics_interval())
        except FrameError as exc:
            self.counters["dropped_invalid"] += 1
            log.warning("frame %d dropped: %s", frame.seq, exc)
            if self.probes.frame_dropped is not None:
                self.probes.frame_dropped(frame, "invalid")
            return False
        return True

    @property
    def ready(self) -> bool:
        return self.engine is not None and self.engine.ready

    def restart(self) -> None:
        """Empty the estimator window (the engine and its arrays are kept)."""
        if self.engine is not None:
            self.engine.reset()
        if self.noise is not None:
            self.noise.reset()
        if self.kinetics is not None:
            self.kinetics.reset()

    def _make_engine(self, fmt: FrameFormat) -> None:
        est = self.config.estimator
        threads = kernel_threads(self.config, fmt.shape[0] * fmt.shape[1])
        check_regions(self.config, fmt.shape)  # the rule check-config applies, before anything is allocated
        masks = {r.name: r.mask(fmt.shape, self.config.base_dir) for r in self.config.regions}
        regions = {name: RegionBox.of(mask) for name, mask in masks.items()}
        shape = fmt.shape
        if est.area == "regions" and masks:
            rows, cols = self.crop = bounding_box(list(masks.values()))
            regions = {name: box.shifted(rows, cols) for name, box in regions.items()}
            shape = (rows.stop - rows.start, cols.stop - cols.start)

        # the same arrays for a few pixels first: a window (or queues) too big for memory is refused
        # before anything large is allocated (the rule check-config and the start apply: preflight)
        kinetics_masks = {name: full_mask(box, shape) for name, box in regions.items()} \
            if self.config.kinetics.enabled else {}
        check_memory(self.config, fmt.shape, fmt.bits, pixels=shape[0] * shape[1],
                     extra=kinetics_bytes(self.config, kinetics_masks))
        self.engine = make_engine(self.config, shape, fmt.bits, threads)
        # its pages written now: faulted in during the window's filling, they would slow the pushes
        # that fill it (seconds at large frames where a virtual machine's host backs memory lazily)
        self.engine.fault_in()
        # the arrays of the maps evaluation (a copy of the sums, the float maps) written once now,
        # before frames flow: their fresh pages would otherwise stall both threads at the first maps
        self._buffers = self.engine.snapshot_buffers(est.maps)
        self._map_buffers.reserve(self._buffers)
        self.regions = regions
        self._layout = RegionLayout.of({name: RegionPlan.of(box, shape) for name, box in regions.items()})
        self.tau.prepare(regions, shape)
        if est.noise_floor and regions:
            self.noise = NoisePatches(regions, est.window, est.noise_patch, fmt.dtype, fmt.bits)
        if kinetics_masks:
            noise = self.config.camera.noise
            self.kinetics = KineticsRegions(self.config.kinetics, kinetics_masks, noise.model() if noise else None,
                                            top=float(2**fmt.bits - 1))
        self.format = fmt

    def snapshot(self, status: Status, maps_due: bool, stats_due: bool, generation: int) -> Snapshot:
        """Region statistics from the live sums now (and a copy of the sums when maps are due).

        The copy reuses the buffers of the previous one: the caller hands a new snapshot over only
        once the evaluator is done with the previous one. Without ``stats_due`` only what the
        drying states need (no stats message, no maps).
        """
        started = time.perf_counter()
        ready = self.ready
        engine = tau = None
        moments: dict[str, dict[str, Moments]] = {}
        publish_maps = ready and maps_due and stats_due
        if ready and self.engine is not None:
            wanted = self._snapshot_estimators(stats_due)
            if wanted:
                # the live sums, read between two pushes on the thread that pushes: no copy
                moments = reduce(self.engine, self._layout, wanted, spread=stats_due)  # the core's reduction
            if publish_maps:
                engine = self._buffers = self.engine.snapshot(self.config.estimator.maps, into=self._buffers)
            tau = self.tau.take(self.engine, stats_due, self._tau_buffers)
            self._tau_buffers = tau or self._tau_buffers
        origin = None if self.crop is None else (self.crop[1].start, self.crop[0].start)
        patches = self.noise.take() if ready and stats_due and self.noise is not None else {}
        snapshot = Snapshot(status, ready, engine, publish_maps=publish_maps, publish_stats=stats_due, tau=tau,
                            regions=moments, generation=generation, origin=origin, patches=patches,
                            kinetics=self._read_kinetics(status.fps))
        if self.probes.snapshot_taken is not None:
            self.probes.snapshot_taken(snapshot, time.perf_counter() - started)
        return snapshot

    def _kinetics_interval(self) -> float | None:
        """The interval to build the kinetics with: the configured one, else the frames' once
        KINETICS_INTERVAL_FRAMES of them were seen (None until then: the frames wait)."""
        self._interval_frames += 1
        if self.config.camera.frame_interval_s is None and self._interval_frames < KINETICS_INTERVAL_FRAMES:
            return None
        return self.tau.interval.seconds()

    def _read_kinetics(self, fps: float) -> dict[str, RegionKinetics]:
        """Each region's kinetics now, on this thread (the reference frames are the pushes'): at the
        evaluation cadence only, it costs O(slots × region pixels) (docs/kinetics.md, "In the daemon")."""
        if self.kinetics is None:
            return {}
        started = time.perf_counter()
        out = self.kinetics.read(self.tau.interval.seconds(fps))
        self.kinetics_read_s = time.perf_counter() - started
        return out

    def _snapshot_estimators(self, stats_due: bool) -> list[str]:
        """The S maps an evaluation needs: all for the stats; for the states alone, the judged one
        if a region is judged on it (none when every region is judged on τc)."""
        est = self.config.estimator
        if stats_due:
            return list(est.maps)
        judged_on_activity = any(not region.on_tau for region in self.config.regions)
        if est.activity not in est.maps or not judged_on_activity:
            return []
        # S3 above the noise needs the region's S1 too (noise_summary.above_of)
        return ["s1", "s3"] if est.activity == "s3" and est.noise_floor else [est.activity]

    def release(self) -> None:
        """Drop the engine and the copies of its sums: the window's ring is the bulk of the
        daemon's memory (N frames), released now rather than when the garbage collector gets to
        the pipeline (a reload builds a new one at once)."""
        self._drop_engine()
        self._settled = False  # the format is kept: the shape a reload checks its regions against
        self._map_buffers = MapBuffers()  # the evaluator lets go of its pooled maps too

    def _drop_engine(self) -> None:
        """Let go of the engine and of every array built with it (copies of its sums, the regions'
        noise patches and kinetics references)."""
        self.engine = self._buffers = self._tau_buffers = self.noise = self.kinetics = None
