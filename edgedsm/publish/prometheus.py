"""The Prometheus sink: the daemon's latest numbers as metrics, and whether frames flow (health).

It keeps the latest :class:`~edgedsm.messages.Stats`, the frame and engine probes of the
pipeline and the MQTT link's health, and turns them into metric families when scraped (a
custom collector: what is exposed is always the latest message, never a stale label set).
Served by :mod:`edgedsm.publish.http_server`; names and meanings in ``docs/integration.md``.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Protocol, get_args

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from edgedsm.frames import Frame
from edgedsm.messages import DROP_CAUSES, Alert, MapFrame, RegionSignal, SignalName, StateReport, Stats, TauStatus
from edgedsm.publish.http_server import MetricsServer
from edgedsm.publish.units import unit_of

#: The five drying states, each a label value of ``edgedsm_region_state``.
STATES = ("warming_up", "wet", "drying", "dry", "fault")
LASER_STATES = ("on", "off", "unknown")
TAU_STATUSES = get_args(TauStatus)
#: The five signal verdicts, each a label value of ``edgedsm_region_signal``.
SIGNALS = get_args(SignalName)
#: Engine pushes the ms/frame gauge is averaged over.
ENGINE_FRAMES = 64


class LinkHealth(Protocol):
    """What the metrics read from the MQTT sink (``MqttSink`` has them all)."""

    @property
    def connected(self) -> bool: ...

    @property
    def pending_alerts(self) -> int: ...

    @property
    def refusal(self) -> str | None:
        """The broker's refusal of the daemon's credentials, None while it accepts them."""

    @property
    def last_error(self) -> str | None:
        """The latest connection problem, None while all is well."""


class MetricsSink:
    """Implements :class:`edgedsm.publish.sink.Sink`; :meth:`frame_taken` and :meth:`frame_pushed`
    are the pipeline's probes (wired by the daemon).

    ``stale_after_s``: :meth:`healthy` is False when no frame was taken for this long (or none
    yet), or while the broker refuses the MQTT link's credentials (nothing is published: the
    service does not do its job). ``link``: the MQTT sink, for ``edgedsm_mqtt_connected``,
    ``edgedsm_alerts_pending`` and the MQTT part of ``/healthz``.
    """

    def __init__(self, stale_after_s: float, link: LinkHealth | None = None,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self.stale_after_s = stale_after_s
        self.link = link
        self._monotonic = monotonic
        self._lock = threading.Lock()
        self._stats: Stats | None = None
        self._report: StateReport | None = None
        self._frames_seen = 0
        self._last_frame_t: float | None = None
        self._push_s: deque[float] = deque(maxlen=ENGINE_FRAMES)
        self._push_total_s = 0.0
        self._pushes = 0
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(_Collector(self))
        self.server: MetricsServer | None = None

    def serve(self, address: tuple[str, int]) -> MetricsSink:
        """Serve ``/metrics`` and ``/healthz`` at ``address`` (ConfigError naming ``http.listen``
        when it cannot listen there); stopped by :meth:`close`."""
        self.server = MetricsServer(address, self.exposition, self.healthy).start()
        return self

    # -- pipeline probes (the daemon wires them; pipeline thread) -----------------------------------
    def frame_taken(self, frame: Frame, count: int) -> None:
        """A frame arrived (``PipelineProbes.frame_taken``): frames flow."""
        with self._lock:
            self._last_frame_t = self._monotonic()

    def frame_pushed(self, frame: Frame, ended: float, cost_s: float) -> None:
        """A frame went through the engine (``PipelineProbes.frame_pushed``) in ``cost_s``."""
        with self._lock:
            self._push_s.append(cost_s)
            self._push_total_s += cost_s
            self._pushes += 1

    # -- the Sink protocol ---------------------------------------------------------------------------
    def publish_state(self, report: StateReport) -> None:
        # the stats carry every region's state at every evaluation; the report adds time to dry
        with self._lock:
            self._report = report

    def publish_alert(self, alert: Alert) -> None:
        return None

    def publish_stats(self, stats: Stats) -> None:
        with self._lock:
            if self._stats is not None and stats.frames > self._stats.frames:
                self._last_frame_t = self._monotonic()  # frames flow, even without the probes wired
            self._stats = stats

    def publish_map(self, frame: MapFrame) -> None:
        return None

    def flush(self, timeout_s: float) -> bool:
        return True

    def close(self, timeout_s: float) -> None:
        if self.server is not None:
            self.server.close()
            self.server = None

    # -- reading -------------------------------------------------------------------------------------
    def healthy(self) -> tuple[bool, str]:
        """(frames flow and the broker takes the credentials, one line saying so) for ``/healthz``.
        A broker down or unreachable is said but not unhealthy: measuring goes on, alerts are
        kept for it, and restarting the daemon would not bring the broker back."""
        with self._lock:
            last = self._last_frame_t
        link = self.link
        mqtt = ""
        if link is not None:
            refusal = link.refusal
            if refusal is not None:
                return False, f"MQTT: {refusal}"
            mqtt = "; MQTT connected" if link.connected else f"; MQTT not connected: {link.last_error or 'connecting'}"
        if last is None:
            return False, "no frame yet" + mqtt
        age = self._monotonic() - last
        if age > self.stale_after_s:
            return False, f"no frame for {age:.1f} s (more than {self.stale_after_s:g} s)" + mqtt
        return True, f"frames flowing (last {age:.1f} s ago)" + mqtt

    def exposition(self) -> bytes:
        """The text exposition format of every metric."""
        return generate_latest(self.registry)

    def families(self) -> Iterator[GaugeMetricFamily | CounterMetricFamily]:
        with self._lock:
            stats, report = self._stats, self._report
            pushes, push_total = self._pushes, self._push_total_s
            recent = list(self._push_s)
        yield from _stats_families(stats)
        time_to_dry = GaugeMetricFamily("edgedsm_region_time_to_dry_seconds",
                                        "extrapolated time until the region is dry (as of the last state report)",
                                        labels=["region"])
        for region, state in sorted(report.regions.items()) if report is not None else ():
            if state.time_to_dry_s is not None:
                time_to_dry.add_metric([region], state.time_to_dry_s)
        yield time_to_dry
        engine = GaugeMetricFamily("edgedsm_engine_ms_per_frame",
                                   f"engine cost of one frame, ms (mean of the last {ENGINE_FRAMES} frames)")
        engine.add_metric([], 1000 * sum(recent) / len(recent) if recent else math.nan)
        yield engine
        seconds = CounterMetricFamily("edgedsm_engine_push_seconds", "engine time spent on frames, s")
        seconds.add_metric([], push_total)
        yield seconds
        pushed = CounterMetricFamily("edgedsm_engine_frames", "frames pushed into the engine")
        pushed.add_metric([], pushes)
        yield pushed
        healthy = GaugeMetricFamily("edgedsm_healthy", "1 while frames flow and the broker takes the credentials "
                                    "(what /healthz answers 200 to)")
        healthy.add_metric([], 1.0 if self.healthy()[0] else 0.0)
        yield healthy
        if self.link is not None:
            connected = GaugeMetricFamily("edgedsm_mqtt_connected", "1 while connected to the MQTT broker")
            connected.add_metric([], 1.0 if self.link.connected else 0.0)
            yield connected
            pending = GaugeMetricFamily("edgedsm_alerts_pending", "alerts not yet acknowledged by the broker")
            pending.add_metric([], float(self.link.pending_alerts))
            yield pending


def _stats_families(stats: Stats | None) -> Iterator[GaugeMetricFamily | CounterMetricFamily]:
    """Metric families of the latest stats: the counters from start (0 before the first stats,
    every drop cause: an ``increase()`` has a series before the first drop), the gauges once
    the first stats came."""
    frames = CounterMetricFamily("edgedsm_frames", "frames taken off the camera queue since the pipeline started")
    frames.add_metric([], 0 if stats is None else stats.frames)
    yield frames
    dropped = CounterMetricFamily("edgedsm_frames_dropped", "frames dropped since the pipeline started, by cause",
                                  labels=["cause"])
    drops = dict.fromkeys(DROP_CAUSES, 0) if stats is None else stats.drops
    for cause, count in sorted(drops.items()):
        dropped.add_metric([cause], count)
    yield dropped
    if stats is None:
        return
    for name, help_text, value in (("edgedsm_fps", "frames per second over the last 64 frames", stats.fps),
                                   ("edgedsm_ready", "1 once the estimator window is full", float(stats.ready)),
                                   ("edgedsm_laser_on", "1 while the laser is confirmed on",
                                    float(stats.laser == "on")),
                                   ("edgedsm_ambient_level", "mean of the latest dark frames, grey levels",
                                    math.nan if stats.ambient_level is None else stats.ambient_level)):
        gauge = GaugeMetricFamily(name, help_text)
        gauge.add_metric([], value)
        yield gauge
    laser = GaugeMetricFamily("edgedsm_laser_state", "1 for the laser's current state", labels=["state"])
    for state in LASER_STATES:
        laser.add_metric([state], float(stats.laser == state))
    yield laser
    activity = GaugeMetricFamily("edgedsm_region_activity", "the value the region's drying thresholds judge (above "
                                 "the camera's noise floor with estimator.noise_floor; τc in s for a region judged "
                                 "on it), in its estimator's unit", labels=["region", "estimator", "unit"])
    for region, judged in sorted(stats.activity.items()):
        if judged.value is not None:  # None: held, the light cannot be judged
            activity.add_metric([region, judged.estimator, judged.unit], judged.value)
    yield activity
    means = GaugeMetricFamily("edgedsm_region_map_mean", "the plain region mean of each map (no noise floor "
                              "removed), in the map's unit", labels=["region", "map", "unit"])
    for region, maps in sorted(stats.regions.items()):
        for name, map_stats in sorted(maps.items()):
            if map_stats.mean is not None:
                means.add_metric([region, name, unit_of(name)], map_stats.mean)
    yield means
    yield from _tau_families(stats)
    yield from _kinetics_families(stats)
    yield from _signal_families(stats)
    states = GaugeMetricFamily("edgedsm_region_state", "1 for the region's current drying state",
                               labels=["region", "state"])
    for region, current in sorted(stats.states.items()):
        for state in STATES:
            states.add_metric([region, state], float(current == state))
    yield states


class _Collector(Collector):
    def __init__(self, sink: MetricsSink) -> None:
        self.sink = sink

    def collect(self) -> Iterator[GaugeMetricFamily | CounterMetricFamily]:
        return self.sink.families()


def _tau_families(stats: Stats) -> Iterator[GaugeMetricFamily]:
    """τc per region in seconds, its status (a bound when above or below) and the Δt it was put in
    seconds with (nothing while τc is not estimated)."""
    if not stats.tau_c:
        return
    seconds = GaugeMetricFamily("edgedsm_region_tau_c_seconds", "region correlation time τc from its pooled "
                                "correlations, s (a bound when its status is above or below)", labels=["region"])
    status = GaugeMetricFamily("edgedsm_region_tau_c_status", "1 for the status of the region's τc",
                               labels=["region", "status"])
    for region, tau in sorted(stats.tau_c.items()):
        seconds.add_metric([region], tau.tau_c_s)
        for name in TAU_STATUSES:
            status.add_metric([region, name], float(tau.status == name))
    yield seconds
    yield status
    if stats.frame_interval_s is not None:
        interval = GaugeMetricFamily("edgedsm_frame_interval_seconds", "frame interval Δt that puts τc in seconds")
        interval.add_metric([], stats.frame_interval_s)
        yield interval


def _kinetics_families(stats: Stats) -> Iterator[GaugeMetricFamily]:
    """Each region's decorrelation time over decades (``[kinetics]``; docs/kinetics.md) in the
    registry's unit, its status as a label: τ when ``ok``, the bound when ``above`` / ``below``, no
    sample where there is no number (dark, saturated, not speckle, warming up)."""
    if not stats.kinetics:
        return
    unit = unit_of("kinetics")
    tau = GaugeMetricFamily("edgedsm_region_kinetics_seconds", f"region decorrelation time τ over decades, {unit} "
                            "(a bound when its status is above or below)", labels=["region", "status"])
    for region, reading in sorted(stats.kinetics.items()):
        value = reading.tau_s if reading.tau_s is not None else reading.bound_s
        if value is not None:
            tau.add_metric([region, reading.status], value)
    yield tau


#: The numbers of a region's signal (``RegionSignal``) as gauges: name, help text, field; a field
#: that is None (no noise model yet) leaves the region out of that gauge.
SIGNAL_GAUGES = (
    ("edgedsm_region_above_noise", "region activity above the camera's noise floor, in the judged estimator's "
     "units (a region judged on τc: the signal's share of the variance)", "above_noise"),
    ("edgedsm_region_above_noise_spread", "1-σ spread of the above-noise activity around 0 for noise alone",
     "above_noise_spread"),
    ("edgedsm_region_noise_floor", "the judged estimator's value for a static surface under this light",
     "noise_floor"),
    ("edgedsm_region_mean_intensity", "mean intensity of the region's noise patch, grey levels", "mean"),
    ("edgedsm_region_dark_fraction", "share of the patch's pixels within 3 noise σ of the dark level",
     "dark_fraction"),
    ("edgedsm_region_saturated_fraction", "share of the patch's samples (pixels × frames) at full scale",
     "saturated_fraction"),
    ("edgedsm_region_speckle_contrast", "spatial speckle contrast of the patch's last frame, noise removed",
     "speckle_contrast"),
    ("edgedsm_region_intensity_change", "mean intensity now / when the window first filled", "intensity_change"),
)


def _signal_families(stats: Stats) -> Iterator[GaugeMetricFamily]:
    """Each region's signal quality (1 for the current verdict, 0 for the other four) and its light
    and activity against the noise (docs/noise.md; nothing while estimator.noise_floor is off)."""
    if not stats.signal:
        return
    regions: list[tuple[str, RegionSignal]] = sorted(stats.signal.items())
    verdict = GaugeMetricFamily("edgedsm_region_signal", "1 for the region's current signal quality (ok, low, "
                                "dark, saturated, not_speckle)", labels=["region", "signal"])
    for region, signal in regions:
        for name in SIGNALS:
            verdict.add_metric([region, name], float(signal.signal == name))
    yield verdict
    for metric, help_text, field in SIGNAL_GAUGES:
        gauge = GaugeMetricFamily(metric, help_text, labels=["region"])
        for region, signal in regions:
            value = getattr(signal, field)
            if value is not None:
                gauge.add_metric([region], value)
        yield gauge
