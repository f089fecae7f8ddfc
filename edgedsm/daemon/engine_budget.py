"""The engine's budget before frames flow: whether its arrays and the frame queues fit in memory
(refused with the config keys to change when not: :func:`check_memory`, the one memory rule of
``check-config``, the daemon's start and its first frame), how many kernel threads a frame
deserves, and the warm-up that loads every compiled kernel an evaluation uses."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.config.estimator import DESCRIPTOR_ACTIVITIES
from edgedsm.daemon.capture import queue_capacity
from edgedsm.errors import ConfigError
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.region_box import RegionBox
from edgedsm.estimators.region_stats import RegionLayout, RegionPlan, region_moments
from edgedsm.estimators.snapshot import maps_from
from edgedsm.estimators.streaming import PARALLEL_MIN_PIXELS, TAU_BATCH
from edgedsm.frames import sample_dtype
from edgedsm.measurement import EngineSpec
from edgedsm.measurement.judge import warm_up as warm_up_noise
from edgedsm.measurement.kinetics import warm_up as warm_up_kinetics
from edgedsm.measurement.tau import map_seconds, region_fits

#: Frames smaller than this are processed by one kernel thread (unless estimator.threads says).
SMALL_FRAME_PIXELS = 1 << 18
#: Pixels of the probe engine whose arrays give the per-pixel memory of the real one.
PROBE_PIXELS = 8
#: Bytes per pixel of the float maps: two sets of S1, S2, S3 and σ (float64; a second set while
#: a sink still holds the first).
MAP_BYTES_PER_PIXEL = 2 * 4 * 8
#: Sides of the warm-up engines: one at least PARALLEL_MIN_PIXELS (the parallel kernels of large
#: frames), one below (the serial kernels of small ones).
WARM_UP_SIDES = {True: 256, False: 64}


def kernel_threads(config: DaemonConfig, pixels: int) -> int | None:
    """``estimator.threads``, or one thread for a small frame: a parallel pass over it costs more
    in thread wake-ups than it saves, and stalls badly when the capture thread competes for the
    cores (None: the engine's default)."""
    threads = config.estimator.threads
    if threads is None and pixels < SMALL_FRAME_PIXELS:
        return 1
    return threads


def available_memory() -> int | None:
    """Bytes the kernel says can be allocated without swapping (None if unknown)."""
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def engine_bytes_per_pixel(probe: SlidingWindow) -> float:
    """Bytes per pixel the daemon keeps for an engine like ``probe`` (any size, its bit depth
    known): the engine's own arrays (ring and sums, τc's included), the copy of the sums for the
    maps, the float maps, and τc's copy of its sums (estimated as large as the engine's)."""
    own = probe.array_bytes()
    tau = sum(size for name, size in own.items() if name in ("products", "edges", "retired", "total", "total_sq"))
    copies = probe.snapshot_buffers().nbytes + (tau if "tau_c" in probe.estimators else 0)
    pixels = probe.shape[0] * probe.shape[1]
    descriptors = sum(name in DESCRIPTOR_ACTIVITIES for name in probe.estimators)  # one more map each
    return (sum(own.values()) + copies) / pixels + MAP_BYTES_PER_PIXEL + 2 * 8 * descriptors


def make_engine(config: DaemonConfig, shape: tuple[int, int], bits: int, threads: int | None = None) -> SlidingWindow:
    """The daemon's engine for ``config`` over ``shape`` (rows, columns) of ``bits``-bit frames: the
    measurement core's :class:`~edgedsm.measurement.EngineSpec` of the config, the one every user
    of the engine builds (the memory estimate's probe included)."""
    return _spec(config).engine(shape, bits, threads)


def _spec(config: DaemonConfig) -> EngineSpec:
    """The measurement core's engine spec of the config's sections."""
    return EngineSpec.of_sections(config.estimator, tau_c=config.tau_c_on, **config.band_args)


def queue_bytes(config: DaemonConfig, frame_shape: tuple[int, int], bits: int) -> dict[str, int]:
    """The most memory each frame queue of ``config`` holds (by the config key that bounds it):
    the camera's queue (its length before the rate is known, the longest: ``queue_capacity``)
    and ``[recording]``'s disk queue and, in alerts mode, its ring."""
    frame_bytes = frame_shape[0] * frame_shape[1] * sample_dtype(bits).itemsize
    acq = config.acquisition
    key = "acquisition.queue_frames" if acq.queue_frames is not None else "acquisition.queue_max_mib"
    parts = {key: queue_capacity(acq, None, frame_bytes) * frame_bytes}
    rec = config.recording
    if rec is not None:
        parts["recording.queue_max_mib"] = rec.queue_max_mib * 2**20
        if rec.mode == "alerts":
            parts["recording.ring_max_mib"] = rec.ring_max_mib * 2**20
    return parts


def check_memory(config: DaemonConfig, frame_shape: tuple[int, int], bits: int, pixels: int | None = None,
                 extra: Mapping[str, int] | None = None) -> None:
    """Refuse (ConfigError naming the key to change) an engine and frame queues for frames of
    ``frame_shape`` (rows, columns) and ``bits`` that cannot fit in this machine's memory
    (``pixels``: what the engine sees, when not the whole frame; ``extra``: more bytes by the config
    key bounding them, e.g. the kinetics' reference frames); nothing large is allocated."""
    per_pixel = engine_bytes_per_pixel(make_engine(config, (1, PROBE_PIXELS), bits, threads=1))
    check_engine_memory(frame_shape, per_pixel, pixels, {**queue_bytes(config, frame_shape, bits), **(extra or {})})


def check_engine_memory(frame_shape: tuple[int, int], bytes_per_pixel: float, pixels: int | None = None,
                        queues: Mapping[str, int] | None = None) -> None:
    """Refuse, with the config keys to change, an engine (and ``queues``: bytes by the config key
    bounding them) that cannot fit in memory: more than 80 % of what the kernel says is available
    (``pixels``: what the engine sees, when not the whole frame; ``bytes_per_pixel``:
    engine_bytes_per_pixel). The key named is the largest part's."""
    engine = (pixels or frame_shape[0] * frame_shape[1]) * bytes_per_pixel
    queues = {key: size for key, size in (queues or {}).items() if size}
    needed = engine + sum(queues.values())
    free = available_memory()
    if free is None or needed <= 0.8 * free:
        return
    size = f"{frame_shape[1]}x{frame_shape[0]}"
    have = f"this machine has {free / 2**30:.1f} GiB available"
    parts = ", ".join(f"{key} {part / 2**30:.1f} GiB" for key, part in queues.items())
    if not queues or engine >= max(queues.values()):
        with_queues = f"; with the frame queues ({parts}) {needed / 2**30:.1f} GiB" if queues else ""
        raise ConfigError(f"estimator.window: the estimator for {size} frames needs {engine / 2**30:.1f} GiB (its "
                          f"window, sums and their copies){with_queues}; {have} (use a shorter window or max_lag, "
                          "mode = 'tumbling' or 'exponential', or area = 'regions')")
    key = max(queues, key=lambda name: queues[name])
    raise ConfigError(f"{key}: the frame queues and the estimator for {size} frames need {needed / 2**30:.1f} GiB "
                      f"(estimator {engine / 2**30:.1f} GiB, {parts}); {have} (lower {key})")


def kernel_variants(config: DaemonConfig, frame_shape: tuple[int, int] | None) -> tuple[bool, ...]:
    """Which variants of the kernels (parallel or not: PARALLEL_MIN_PIXELS) the engine for frames
    of ``frame_shape`` (rows, columns) runs: both while the size is unknown (None), and where
    ``estimator.area = 'regions'`` crops a large frame to a box that may be small."""
    if frame_shape is None:
        return (False, True)
    if frame_shape[0] * frame_shape[1] < PARALLEL_MIN_PIXELS:
        return (False,)  # an engine never sees more than the frame
    return (False, True) if config.estimator.area == "regions" and config.regions else (True,)


def warm_up(config: DaemonConfig, frame_shape: tuple[int, int] | None = None) -> None:
    """Load every compiled kernel an evaluation of ``config`` on frames of ``frame_shape`` (rows,
    columns; None: not known yet) uses, on small engines, before frames flow: loading them later
    (hundreds of ms, holding the GIL) would stall the pipeline thread and overflow the queue at the
    first push and the first evaluation; compiling them (seconds, on a fresh install) even more."""
    for parallel in kernel_variants(config, frame_shape):
        _warm_up(config, parallel)
    if config.estimator.noise_floor:
        warm_up_noise()
    if config.kinetics.enabled:
        warm_up_kinetics(config.camera.pixel_format not in (None, "Mono8"))


def _warm_up(config: DaemonConfig, parallel: bool) -> None:
    """Load the ``parallel`` or the serial variants of the kernels (:func:`warm_up`)."""
    est = config.estimator
    tau_on = config.tau_c_on
    deep = config.camera.pixel_format not in (None, "Mono8")
    side = WARM_UP_SIDES[parallel]
    window = est.lag + 2
    if tau_on:  # long enough for every τc kernel (sliding batches need N >= K + TAU_BATCH)
        window = max(window, est.lags + TAU_BATCH + 2)
    engine = _spec(config).replaced(window=window).engine((side, side), 16 if deep else 8, est.threads)
    frame = np.zeros((side, side), np.uint16 if deep else np.uint8)
    for _ in range(window + TAU_BATCH + 1):  # past a full batch of lag products
        engine.push(frame)
    mask = np.zeros((side, side), bool)
    mask[1:-1, 1:-1] = True
    layout = RegionLayout.of({name: RegionPlan.of(RegionBox.of(region), (side, side))
                              for name, region in (("all", np.ones_like(mask)), ("inner", mask))})
    maps = est.maps
    maps_from(engine.snapshot(maps))
    wanted = [maps] + ([(est.activity,)] if est.activity in maps else [])
    for names in wanted:
        region_moments(engine.snapshot(names, live=True), layout, names, spread=names is maps, parallel=parallel)
    if tau_on:  # the pooled-covariance kernels of the regions and the block map
        sums = engine.tau_snapshot()
        map_seconds(sums, 1.0, block=2)
        region_fits(sums, {"inner": np.flatnonzero(mask)})
