"""The engine's budget before frames flow: whether its arrays fit in memory (refused with the
config keys to change when not), how many kernel threads a frame deserves, and the warm-up that
loads every compiled kernel an evaluation uses."""

from __future__ import annotations

import numpy as np

from edgedsm.analysis import RegionBox
from edgedsm.config import DaemonConfig
from edgedsm.config.estimator import DESCRIPTOR_ACTIVITIES
from edgedsm.daemon.signal_judge import warm_up as warm_up_noise
from edgedsm.daemon.tau import TauRegions, engine_estimators
from edgedsm.errors import ConfigError
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.region_stats import RegionLayout, RegionPlan, region_moments
from edgedsm.estimators.snapshot import maps_from
from edgedsm.estimators.streaming import PARALLEL_MIN_PIXELS, TAU_BATCH
from edgedsm.estimators.tau_pooled import pooled_covariances
from edgedsm.frames import Frame

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


def check_engine_memory(frame: Frame, bytes_per_pixel: float, pixels: int | None = None) -> None:
    """Refuse, with the config keys to change, an engine that cannot fit in memory (``pixels``:
    what the engine sees, when not the whole frame; ``bytes_per_pixel``: engine_bytes_per_pixel)."""
    needed = (pixels or frame.pixels.size) * bytes_per_pixel
    free = available_memory()
    if free is not None and needed > 0.8 * free:
        raise ConfigError(f"estimator.window: the estimator for {frame.shape[1]}x{frame.shape[0]} frames needs "
                          f"{needed / 2**30:.1f} GiB (its window, sums and their copies); this machine has "
                          f"{free / 2**30:.1f} GiB available (use a shorter window or max_lag, mode = 'tumbling' "
                          "or 'exponential', or area = 'regions')")


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


def _warm_up(config: DaemonConfig, parallel: bool) -> None:
    """Load the ``parallel`` or the serial variants of the kernels (:func:`warm_up`)."""
    est = config.estimator
    tau = TauRegions(config)
    deep = config.camera.pixel_format not in (None, "Mono8")
    side = WARM_UP_SIDES[parallel]
    window = est.lag + 2
    if tau.on:  # long enough for every τc kernel (sliding batches need N >= K + TAU_BATCH)
        window = max(window, est.lags + TAU_BATCH + 2)
    engine = SlidingWindow((side, side), window=window, lag=est.lag, q=est.engine_q, bits=16 if deep else 8,
                           estimators=engine_estimators(config), mode=est.mode, threads=est.threads,
                           max_lag=est.lags if tau.on else None)
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
    if tau.on:  # the pooled-covariance kernels of the regions and the block map
        sums = engine.tau_snapshot()
        tau.map_seconds(sums, 1.0, block=2)
        pooled_covariances(sums.window, sums.total, sums.total_sq, sums.products, sums.edges, sums.ends,
                           np.flatnonzero(mask), sums.lags)
