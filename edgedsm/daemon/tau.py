"""τc in the daemon: the frame interval that puts it in seconds, when the snapshot of its sums is
taken, and which regions' values the evaluator asks for (docs/tau_c.md, "In the daemon"). The
values and the map themselves are the measurement core's (:mod:`edgedsm.measurement.tau`): the
daemon wires, it does not compute them.

Where the work runs. The pipeline thread copies the integer sums τc is formed from
(:meth:`SlidingWindow.tau_snapshot`: ΣI, ΣI², the lag products at the multi-tau lags (9 for
K = 20), and the window's first and last K frames or the tumbling edge sums; a memory copy). Forming the
covariances from them costs about 1.5 µs per pixel and the per-pixel fit about 5 µs: far too
much for the pipeline thread, which must keep pushing frames. So the snapshot carries the sums,
and the evaluator thread hands them to the core, which forms each region's pooled covariances (its
pixels only) and fits once per region (the region's τc from its pooled correlations, not the mean
of per-pixel τ), and the map only when maps are due.

The frame interval Δt. A paced camera exposes on its own clock: its configured
``camera.frame_interval_s`` *is* the time between the frames the engine correlates. The rate
measured on the host (``fps``) is the rate frames leave the queue: it jitters with scheduling
and transport, and for the simulator running faster than real time (tests, ``time_scale``)
it is a different clock altogether. So Δt is the configured interval when there is one; when the
camera runs at its default rate, it is the median step of the frames' own timestamps (the
camera's clock where it has one, divided by the sequence step so that a lost frame does not
count twice), and only when those say nothing, 1/fps.
"""

from __future__ import annotations

import itertools
from collections import deque

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.correlation_time import tau_threshold_problem
from edgedsm.estimators.region_box import RegionBox
from edgedsm.estimators.snapshot import TauSnapshot
from edgedsm.frames import Frame
from edgedsm.measurement.spec import engine_estimators as spec_estimators
from edgedsm.measurement.tau import region_taus
from edgedsm.messages import RegionTau, TauStatus

#: Frame timestamps the interval is the median step of.
INTERVAL_FRAMES = 64


def engine_estimators(config: DaemonConfig) -> tuple[str, ...]:
    """What the daemon's engine keeps sums for: S1, S2, S3, the activity when it is one of the
    field's descriptors (``estimator.maps``), and τc when configured or needed."""
    return spec_estimators(config.estimator, config.tau_c_on)


class FrameInterval:
    """Δt in seconds (see the module docstring): the configured interval, else the median step of
    the frames' timestamps, else 1/fps."""

    def __init__(self, configured_s: float | None) -> None:
        self.configured_s = configured_s
        self._stamps: deque[tuple[int, int]] = deque(maxlen=INTERVAL_FRAMES)  # (seq, t_ns)

    def saw(self, frame: Frame) -> None:
        """Remember a pushed frame's sequence number and timestamp (pipeline thread)."""
        if self.configured_s is None:
            self._stamps.append((frame.seq, frame.t_ns))

    def seconds(self, fps: float = 0.0) -> float | None:
        """Δt now (None: not known yet)."""
        if self.configured_s is not None:
            return self.configured_s
        stamps = list(self._stamps)
        steps = [(t1 - t0) / (s1 - s0) for (s0, t0), (s1, t1) in itertools.pairwise(stamps)
                 if s1 > s0 and t1 > t0]
        if steps:
            return float(np.median(steps)) * 1e-9
        return 1.0 / fps if fps > 0 else None


class TauRegions:
    """The regions' pixels in the engine's coordinates and what τc needs to publish them."""

    def __init__(self, config: DaemonConfig) -> None:
        self.config = config
        self.interval = FrameInterval(config.camera.frame_interval_s)
        self.pixels: dict[str, np.ndarray] = {}  # region -> flat indices in the engine's frame
        self.status: dict[str, TauStatus] = {}  # the latest status of each region (evaluator thread)
        self._checked_s: float | None = None  # the Δt the thresholds were last checked at

    def threshold_problems(self, interval_s: float) -> dict[str, str]:
        """Regions whose τc thresholds cannot be told apart at the measured Δt, and why: checked
        the first time Δt is known and again when it moves by more than 10 % (a configured
        ``camera.frame_interval_s`` is checked with the config instead)."""
        if self.config.camera.frame_interval_s is not None:
            return {}
        if self._checked_s is not None and abs(interval_s - self._checked_s) <= 0.1 * self._checked_s:
            return {}
        self._checked_s = interval_s
        problems = {}
        for region in self.config.regions:
            if region.wet_below_s is None or region.dry_above_s is None:
                continue
            problem = tau_threshold_problem(region.wet_below_s, region.dry_above_s, region.hysteresis,
                                            self.config.estimator.lags, interval_s)
            if problem:
                problems[region.name] = f"at the measured frame interval {interval_s:.4g} s, {problem}"
        return problems

    @property
    def on(self) -> bool:
        return self.config.tau_c_on

    @property
    def judged(self) -> set[str]:
        """Regions whose drying state is judged on τc (seconds thresholds judge the kinetics instead
        under ``estimator.activity = 'kinetics'``)."""
        if self.config.estimator.activity == "kinetics":
            return set()
        return {r.name for r in self.config.regions if r.on_tau}

    def prepare(self, regions: dict[str, RegionBox], shape: tuple[int, int]) -> None:
        """The flat pixel indices of each region in the engine's ``shape`` (its coordinates)."""
        self.pixels = {}
        for name, box in regions.items():
            full = np.zeros(shape, bool)
            full[box.rows, box.cols] = box.mask
            self.pixels[name] = np.flatnonzero(full)

    def take(self, engine: SlidingWindow, stats_due: bool, into: TauSnapshot | None) -> TauSnapshot | None:
        """The sums, when an evaluation needs τc: for the stats, or for a region judged on it."""
        if not self.on or not engine.ready or not (stats_due or self.judged):
            return None
        return engine.tau_snapshot(into=into)

    def regions(self, snapshot: TauSnapshot, interval_s: float, names: set[str] | None = None) -> dict[str, RegionTau]:
        """Each region's (or each of ``names``') τc in seconds from its pooled correlations: the
        measurement core's (:func:`edgedsm.measurement.tau.region_taus`), remembering each status."""
        pixels = {name: flat for name, flat in self.pixels.items() if names is None or name in names}
        out = region_taus(snapshot, pixels, interval_s)
        self.status.update({name: tau.status for name, tau in out.items()})
        return out
