"""Validate a daemon configuration file without starting anything.

Prints every problem with its key path (e.g. ``regions.0.dry_below: ...``) and exits 78
(EX_CONFIG) when the file is bad, 0 with a short summary when it is good. It refuses what
``run`` refuses at its start, by the same rules (``edgedsm.daemon.preflight``): the state
directory, the ``[http]`` listen address, the MQTT TLS files and credentials, and where the
camera's frame size is known without opening a device (a simulated scene's size, a
recording's first frame, a V4L2 width and height) the regions and the memory of the engine and
frame queues against this machine's; the daemon checks the last two again against the real
camera's frames before the laser goes on. ``--schema`` prints the JSON Schema of the
configuration instead (for editors).

Examples:
  edgedsm check-config /etc/edgedsm/line3.toml
  edgedsm check-config --schema > edgedsm-config.schema.json
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from edgedsm.config import DaemonConfig

NAME = "check-config"
HELP = "validate a daemon configuration file (exit 78 when bad)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", nargs="?", metavar="CONFIG", help="daemon configuration (TOML)")
    parser.add_argument("--schema", action="store_true", help="print the JSON Schema of the configuration")
    parser.add_argument("--json", action="store_true",
                        help="print the summary as one JSON object (errors still go to stderr, exit 78)")


def run(args: argparse.Namespace) -> int:
    from edgedsm.config import config_schema, load_config
    from edgedsm.daemon.preflight import preflight_start

    if args.schema:
        print(json.dumps(config_schema(), indent=2))
        return 0
    if args.config is None:
        raise SystemExit("edgedsm check-config: give a CONFIG file (or --schema)")
    config = load_config(args.config)
    frame_shape = preflight_start(config)  # what `run` refuses at its start, by the same rules
    from edgedsm.publish.topics import Topics

    base = Topics.from_settings(config.mqtt).base if config.mqtt else None
    for note in config.notes:
        print(f"edgedsm: note: {note}", file=sys.stderr)
    if args.json:
        print(json.dumps({
            "config": args.config, "ok": True, "device": config.device.name, "topic_base": base,
            "camera": config.camera.uri, "laser": config.laser.uri if config.laser else None,
            "estimator": {"activity": config.estimator.activity, "window": config.estimator.window,
                          "lag": config.estimator.lag, "mode": config.estimator.mode},
            "tau_c": tau_range(config),
            "regions": [region.name for region in config.regions],
            "frame_shape": list(frame_shape) if frame_shape is not None else None,
            "mqtt": f"{config.mqtt.host}:{config.mqtt.port}" if config.mqtt else None,
            "homeassistant": config.homeassistant.discovery_prefix if config.homeassistant else None,
            "http": config.http.listen if config.http else None,
            "recording": recording_budget(config, frame_shape), "noise_floor": noise_floor_setup(config),
            "kinetics": config.kinetics.model_dump() if config.kinetics.enabled else None,
            "notes": config.notes}))
        return 0
    mqtt = f"{config.mqtt.host}:{config.mqtt.port}, topics {base}/..." if config.mqtt else "none (log only)"
    regions = (f"{len(config.regions)} region(s) inside the {frame_shape[1]}x{frame_shape[0]} frame"
               if frame_shape is not None else f"{len(config.regions)} region(s) (frame size known at start)")
    print(f"{args.config}: OK — camera {config.camera.uri}, laser {config.laser.uri if config.laser else 'none'}, "
          f"{config.estimator.activity.upper()} N={config.estimator.window} m={config.estimator.lag} "
          f"({config.estimator.mode}), {regions}, MQTT {mqtt}")
    print(queue_memory(config, frame_shape))
    tau = tau_range(config)
    if tau is not None:
        print(tau_line(tau))
    budget = recording_budget(config, frame_shape)
    if budget is not None:
        print(budget_line(budget))
    print(noise_line(noise_floor_setup(config)))
    if config.kinetics.enabled:
        print(kinetics_line(config))
    return 0


def kinetics_line(config: DaemonConfig) -> str:
    """``[kinetics]`` in one line: its ages and what they keep per pixel (docs/kinetics.md)."""
    from edgedsm.config.kinetics import AUTO_PIXELS

    section, dt = config.kinetics, config.camera.frame_interval_s
    kept = ("every pixel" if section.step == 1 else f"every {section.step}th pixel each way" if section.step
            else f"at most {AUTO_PIXELS:,} pixels a region (the step each way it takes)")
    if dt is None:
        size = "frames kept known once the frame interval is (camera.frame_interval_s unset)"
    else:
        slots = section.slots(dt)
        size = f"{slots} reference frames ({(slots + 1) * 4} bytes per kept pixel) at Δt = {dt:g} s"
    stages = ", ".join(f"{stage.name} at {stage.rate_below_hz:g} Hz" for stage in section.stages) or "none"
    return (f"kinetics: on, τ up to {section.longest_age_s:g} s, {section.per_octave} per octave, {kept}; {size}; "
            f"stages: {stages}")


def noise_floor_setup(config: DaemonConfig) -> dict[str, Any]:
    """How the drying states meet the camera's noise (docs/noise.md, §5c)."""
    est, noise = config.estimator, config.camera.noise
    from edgedsm.estimators.noise_summary import ESTIMATORS as FLOORED

    setup = {"on": est.noise_floor, "model": ("datasheet" if noise is not None else "frames") if est.noise_floor
             else None, "patch_px": est.noise_patch, "intensity_change": est.intensity_change}
    if est.activity not in (*FLOORED, "tau_c"):  # an activity without a floor (band_ratio) is judged as it is
        setup["floorless"] = est.activity
    return setup


def noise_line(setup: dict[str, Any]) -> str:
    if not setup["on"]:
        return "noise floor: off (the states are judged on the plain activity; no signal quality published)"
    model = ("the [camera.noise] datasheet" if setup["model"] == "datasheet"
             else "the frames (until found: the plain activity)")
    judged = f"{setup['floorless']} has none: states judged on it as it is, the light still judged" \
        if setup.get("floorless") else "states judged above it"
    return (f"noise floor: on, {judged}; noise model from {model}; {setup['patch_px']} px patch per "
            f"region; light change warning beyond {setup['intensity_change']:g}×")


def tau_range(config: DaemonConfig) -> dict[str, Any] | None:
    """What τc can measure with this config (None: τc off): K, Δt and the range Δt/3 ... K·Δt in
    seconds (None while Δt is known only from the frames)."""
    from edgedsm.estimators.correlation_time import TAU_FLOOR, tau_lags

    if not config.tau_c_on:
        return None
    lags, dt = config.estimator.lags, config.camera.frame_interval_s
    return {"max_lag": lags, "lags": [int(k) for k in tau_lags(lags)], "frame_interval_s": dt,
            "shortest_s": TAU_FLOOR * dt if dt else None, "longest_s": lags * dt if dt else None}


def tau_line(tau: dict[str, Any]) -> str:
    lags = f"lags {','.join(str(k) for k in tau['lags'])} (longest K = {tau['max_lag']})"
    if tau["frame_interval_s"] is None:
        return (f"τc: {lags}, measured from Δt/3 to {tau['max_lag']}·Δt (Δt from the frames' timestamps at "
                "start; thresholds checked then)")
    return (f"τc: {lags} at Δt = {tau['frame_interval_s']:g} s: measured from {tau['shortest_s']:.3g} s to "
            f"{tau['longest_s']:.3g} s (beyond: reported as a bound)")


def queue_memory(config: DaemonConfig, frame_shape: tuple[int, int] | None) -> str:
    """One line: how many frames the camera→estimator queue holds and the memory that takes."""
    from edgedsm.daemon.capture import queue_capacity

    acq, cam = config.acquisition, config.camera
    bound = f"at most {acq.queue_max_mib} MiB"
    if frame_shape is None:
        return f"queue: {acq.queue_seconds:g} s of frames at the measured rate, {bound} (frame size known at start)"
    frame_bytes = frame_shape[0] * frame_shape[1] * (2 if _deep(config) else 1)
    rate = 1.0 / cam.frame_interval_s if cam.frame_interval_s else None
    if acq.queue_frames is not None:
        frames = acq.queue_frames
        how = "queue_frames"
    elif rate is None:
        most = max(1, acq.queue_max_mib * 2**20 // frame_bytes)
        return (f"queue: {acq.queue_seconds:g} s of frames at the measured rate, {bound} "
                f"({most} frames of {frame_bytes / 2**20:.1f} MiB)")
    else:
        frames = queue_capacity(acq, rate, frame_bytes)
        how = f"{acq.queue_seconds:g} s at {rate:g} frames/s, {bound}"
    return f"queue: {frames} frames of {frame_bytes / 2**20:.1f} MiB = {frames * frame_bytes / 2**20:.0f} MiB ({how})"


def _deep(config: DaemonConfig) -> bool:
    """8-bit data takes one byte a pixel, deeper data two (unpacked on arrival)."""
    return config.camera.pixel_format is not None and config.camera.pixel_format != "Mono8"


def _bits(config: DaemonConfig) -> int:
    from edgedsm.devices.camera.pixels import PIXEL_BITS

    return PIXEL_BITS.get(config.camera.pixel_format or "Mono8", 16)


def recording_budget(config: DaemonConfig, frame_shape: tuple[int, int] | None) -> dict[str, Any] | None:
    """``[recording]``'s disk budget (None without one): its settings, and where the frame size
    and interval are known the raw and expected MB/s (the codec's ratio measured on speckle),
    how long until ``max_bytes`` turns over (hours; alerts mode: clips kept) and the ring's memory."""
    from edgedsm.config.recording import speckle_ratio

    rec = config.recording
    if rec is None:
        return None
    budget: dict[str, Any] = {"mode": rec.mode, "dir": str(config.recording_dir), "codec": rec.codec,
                              "max_bytes": rec.max_bytes, "keep_days": rec.keep_days}
    interval = config.camera.frame_interval_s
    if frame_shape is None or interval is None:
        return budget
    frame_bytes = frame_shape[0] * frame_shape[1] * (2 if _deep(config) else 1)
    ratio = speckle_ratio(rec.codec, _bits(config))
    fps = 1.0 / interval
    kept_fps = {"continuous": fps, "timelapse": min(fps, 1.0 / rec.every_s), "alerts": fps}[rec.mode]
    raw = kept_fps * frame_bytes
    budget.update(frame_bytes=frame_bytes, frames_per_s=fps, ratio=ratio, raw_mb_s=raw / 1e6,
                  disk_mb_s=raw / ratio / 1e6)
    if rec.mode == "alerts":
        ring_frames = min(int(rec.pre_s * fps) + 1, rec.ring_max_mib * 2**20 // frame_bytes)
        clip_bytes = (ring_frames + rec.post_s * fps) * frame_bytes / ratio
        budget.update(ring_frames=ring_frames, ring_mib=ring_frames * frame_bytes / 2**20,
                      ring_s=ring_frames / fps, clip_mb=clip_bytes / 1e6, clips_kept=int(rec.max_bytes // clip_bytes))
    else:
        budget["turnover_h"] = rec.max_bytes / (raw / ratio) / 3600
    return budget


def budget_line(budget: dict[str, Any]) -> str:
    """One line of :func:`recording_budget`."""
    head = (f"recording: {budget['mode']} to {budget['dir']} ({budget['codec']}), max_bytes "
            f"{budget['max_bytes'] / 1e9:.3g} GB, keep_days {budget['keep_days']:g}")
    if "raw_mb_s" not in budget:
        return head + " (MB/s known once the frame size and camera.frame_interval_s are)"
    rate = (f"; {budget['frames_per_s']:g} frames/s of {budget['frame_bytes'] / 1e6:.3g} MB: "
            f"{budget['raw_mb_s']:.3g} MB/s raw, about {budget['disk_mb_s']:.3g} MB/s on disk "
            f"({budget['codec']} ≈ {budget['ratio']:g}× on speckle)")
    if budget["mode"] == "alerts":
        return (head + rate + f" while a clip records; a clip about {budget['clip_mb']:.3g} MB, "
                f"{budget['clips_kept']} kept; ring {budget['ring_frames']} frames = {budget['ring_s']:.3g} s, "
                f"{budget['ring_mib']:.0f} MiB of memory")
    return head + rate + f"; max_bytes turns over after {budget['turnover_h']:.3g} h"
