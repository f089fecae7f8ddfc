"""`edgedsm analyze --timeline`: frames from a recording or a scene, regions from a config, and the
CSV and pictures of :mod:`edgedsm.timeline`.

Frames are pushed one by one into the streaming engine as they are read (``edgedsm.frameio``),
the next one decoded on a thread meanwhile (``edgedsm.frameio.prefetch``): memory holds the
engine's window, never the recording."""

from __future__ import annotations

import argparse
import contextlib
import csv
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from edgedsm.commands.common import progress
from edgedsm.config import DaemonConfig
from edgedsm.config.kinetics import KineticsSection
from edgedsm.errors import EstimatorError
from edgedsm.estimators import registry
from edgedsm.frameio import FrameReader, open_frames
from edgedsm.frameio.prefetch import Prefetched
from edgedsm.plots import pyplot, seconds_axis, seconds_label
from edgedsm.timeline import DESCRIPTORS, PAPER, Timeline, timeline
from edgedsm.validation import validate

SCENE_SUFFIXES = (".toml",)


def add_timeline_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("time histories (--timeline)")
    group.add_argument("--timeline", metavar="OUT_DIR",
                       help="write timeline.csv, timeline.png and histogram.png to OUT_DIR")
    group.add_argument("-c", "--config", metavar="CONFIG.toml", help="take the regions from this daemon config")
    group.add_argument("--every", type=int, metavar="FRAMES", help="frames between samples (default N/4)")
    group.add_argument("--max-lag", type=int, default=20, metavar="K",
                       help="longest lag fitted for τc (default 20; N/2 times slower stages: disjoint sets keep "
                            "the last K frames, K bytes per pixel at 8 bits)")
    group.add_argument("--no-noise-floor", dest="with_noise", action="store_false",
                       help="leave out each region's light and activity above the camera's noise (the columns "
                            "mean_intensity, signal, s1/s2/s3_above_noise; docs/noise.md)")
    group.add_argument("--no-tau-c", dest="with_tau", action="store_false",
                       help="leave τc out: its sums cost about 41 bytes per pixel on disjoint sets (K = 20) and "
                            "250 on overlapping ones, against 45 for S1-S3; the τc columns then read 'off'")
    group.add_argument("--noise-patch", type=int, metavar="SIDE",
                       help="judge each region's noise on a square of SIDE pixels at its centre, as the daemon "
                            "does (estimator.noise_patch; column noise_view), instead of on every pixel of it")
    group.add_argument("--dt", type=float, metavar="SECONDS",
                       help="frame interval (default: the scene's, the config's camera.frame_interval_s, else 1)")
    group.add_argument("--frames", dest="frame_count", type=int, metavar="COUNT",
                       help="frames to simulate when FRAMES is a scene (default: the scene's)")
    group.add_argument("--kinetics", action="store_true",
                       help="each region's decorrelation time over decades (docs/kinetics.md): the columns "
                            "kinetics_tau_s, kinetics_rate_hz, kinetics_status, kinetics_bound_s; settings from "
                            "the config's [kinetics] (on or not), else its defaults; with its [[kinetics.stages]] "
                            "also kinetics_stage, kinetics_stage_at_s, kinetics_next_stage, kinetics_time_to_next_s")
    group.add_argument("--kinetics-longest-s", type=float, metavar="SECONDS",
                       help="the oldest reference frame in seconds (default: the config's "
                            "kinetics.longest_age_s, else 3600)")
    group.add_argument("--histogram", choices=("s1", "s2", "s3", *DESCRIPTORS), default="s2",
                       help="estimator whose map histogram is drawn against time (default s2; a descriptor "
                            "needs its column: --estimator or the config's estimator.activity)")


def open_reader(args: argparse.Namespace) -> FrameReader:
    """The reader of FRAMES with --channel; its notes (a lossy codec, gaps) go to stderr."""
    reader = open_frames(args.frames, getattr(args, "channel", None))
    for note in reader.notes:
        print(f"edgedsm: warning: {note}", file=sys.stderr)
    return reader


def _frames(args: argparse.Namespace, stack: contextlib.ExitStack
            ) -> tuple[Iterator[np.ndarray], int | None, float | None, int | None, np.ndarray | None]:
    """(frames, bits, the source's dt if it knows one, count if known, a recording's frame times
    in seconds from the first frame used), streamed."""
    source = args.frames
    if source == "default" or Path(source).suffix.lower() in SCENE_SUFFIXES:
        from edgedsm.commands.common import scene_argument
        from edgedsm.sim import Simulator

        scene = scene_argument(source)
        count = args.frame_count or scene.scene.frames
        return (Simulator(scene).frames(count), scene.detector.bits if scene.detector else None, scene.scene.dt,
                count, None)
    reader = stack.enter_context(open_reader(args))
    if reader.count is not None and args.start >= reader.count:
        raise EstimatorError(f"--start {args.start} is outside the {reader.count} frames of {source}")
    stop = None if args.frame_count is None else args.start + args.frame_count
    count = reader.count - args.start if reader.count is not None else None
    if count is not None and args.frame_count is not None:
        count = min(count, args.frame_count)
    stamps = reader.stamps()
    times = None
    if stamps is not None and args.dt is None:  # --dt overrides the recording's clock
        used = stamps.t_ns[args.start:stop]
        times = (used - used[0]) / 1e9
    # decoded a frame ahead on a thread while the engine takes this one (docs/recording.md)
    frames = stack.enter_context(Prefetched(reader.frames(args.start, stop)))
    return frames, reader.bits, reader.dt, count, times


def _regions(args: argparse.Namespace, shape: tuple[int, int]
             ) -> tuple[dict[str, np.ndarray], DaemonConfig | None, tuple[str, ...]]:
    """The regions, the config and the descriptor columns: analyze's --estimator and the config's
    estimator.activity when they are streaming descriptors."""
    wanted = {getattr(args, "estimator", None)}
    if args.config is None:
        return {"frame": np.ones(shape, bool)}, None, tuple(name for name in DESCRIPTORS if name in wanted)
    from edgedsm.config import check_regions, load_config

    config = load_config(args.config)
    check_regions(config, shape)
    wanted.add(config.estimator.activity)
    return ({region.name: region.mask(shape, config.base_dir) for region in config.regions},
            config, tuple(name for name in DESCRIPTORS if name in wanted))


def _activity(args: argparse.Namespace, config: DaemonConfig | None) -> str:
    """What the timeline's ``activity`` column judges: --estimator when the daemon can judge on it,
    else the config's estimator.activity, else S2."""
    estimator = getattr(args, "estimator", None)
    if config is not None and config.estimator.activity == "kinetics":
        return "kinetics"  # its regions' seconds thresholds are the kinetics': judged on nothing else
    if estimator in registry.activities():
        return estimator
    return config.estimator.activity if config is not None else "s2"


def _kinetics(args: argparse.Namespace, config: DaemonConfig | None) -> KineticsSection | None:
    """The kinetics' settings of --kinetics (or of a config judging on it): the config's
    ``[kinetics]``, else its defaults, the longest age from --kinetics-longest-s (validated as in
    a config); None: no kinetics columns."""
    judged = config is not None and config.estimator.activity == "kinetics"
    if not getattr(args, "kinetics", False) and not judged:
        return None
    section = config.kinetics if config is not None else KineticsSection()
    longest = getattr(args, "kinetics_longest_s", None)
    data = {**section.model_dump(), "enabled": True, **({"longest_age_s": longest} if longest is not None else {})}
    return validate(KineticsSection, data, "--kinetics")


def _datasheet(args: argparse.Namespace):
    """The camera's noise from analyze's --noise-gain (docs/noise.md), or None: from the frames."""
    gain = getattr(args, "noise_gain", None)
    if gain is None:
        return None
    from edgedsm.estimators.noise import from_datasheet

    return from_datasheet(gain, args.dark_noise, args.dark_mean)


def run_timeline(args: argparse.Namespace) -> int:
    with contextlib.ExitStack() as stack:
        return _run_timeline(args, stack)


def _run_timeline(args: argparse.Namespace, stack: contextlib.ExitStack) -> int:
    window = args.window or 100
    frames, bits, scene_dt, count, times = _frames(args, stack)
    frames = progress(frames, count, "timeline", getattr(args, "progress", True))
    first = next(frames, None)
    if first is None:
        raise EstimatorError(f"{args.frames}: no frames")
    regions, config, descriptors = _regions(args, first.shape)
    split = getattr(args, "split", None)  # the bands' split in Hz: --split, else the config's band_split_hz
    if split is None and config is not None:
        split = config.estimator.band_split_hz
    dt = args.dt or scene_dt or (config.camera.frame_interval_s if config is not None else None) or 1.0

    read = [0]

    def all_frames() -> Iterator[np.ndarray]:
        yield first
        read[0] = 1
        for frame in frames:
            yield frame
            read[0] += 1

    result = timeline(all_frames(), regions, window, args.lag, args.every or max(1, window // 4), dt=dt,
                      max_lag=args.max_lag, histogram_estimator=args.histogram, bits=bits, times_s=times,
                      with_tau=args.with_tau, with_noise=args.with_noise, noise_model=_datasheet(args),
                      descriptors=descriptors, band_split=split, q=getattr(args, "q", 0.0),
                      activity=_activity(args, config), noise_patch=args.noise_patch, config=config,
                      kinetics=_kinetics(args, config))
    out = Path(args.timeline)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "timeline.csv", result)
    title = figure_title(args.frames, window, args.lag)
    plot_activity(out / "timeline.png", result, title, source=str(args.frames))
    plot_histograms(out / "histogram.png", result, title, source=str(args.frames))
    samples = len(result.sample_frames)
    print(f"{samples} samples of {len(regions)} region(s) from {read[0]} frames (Δt = {dt:g} s) -> "
          f"{out / 'timeline.csv'}, {out / 'timeline.png'}, {out / 'histogram.png'}")
    return 0


def write_csv(path: Path, result: Timeline) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(result.columns)
        for row in result.rows:
            writer.writerow([f"{cell:.6g}" if isinstance(cell, float) else cell for cell in row])


def _label(name: str) -> str:
    """A map's axis label with its unit (the registry's; none for the dimensionless)."""
    record = registry.get(name)
    return record.label if record.unit.startswith("1") else f"{record.label} ({record.unit})"


def figure_title(source: str, window: int, lag: int) -> str:
    """A figure's title: the input's file name (its folder would not fit across the figure; the
    whole path goes in the PNG's ``Source`` text), the window and the lag."""
    return f"{Path(source).name or source}: N = {window}, m = {lag}"


def activity_figure(result: Timeline, title: str):
    """timeline.png's figure: each estimator's region means against time, and τc on a log axis."""
    plt = pyplot()
    names = list(dict.fromkeys(row[2] for row in result.rows))
    columns = (*((name, _label(name)) for name in (*PAPER, *result.descriptors)), ("tau_c_s", _label("tau_c")))
    fig, axes = plt.subplots(len(columns), 1, figsize=(8, 9 + 2 * len(result.descriptors)), sharex=True)
    for ax, (column, label) in zip(axes, columns, strict=True):
        for name in names:
            ax.plot(result.series(name, "time_s"), result.series(name, column), label=name)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    if result.kinetics:  # beside the window's τc, which saturates at K·Δt: the kinetics' τ over decades
        for name in names:
            axes[-1].plot(result.series(name, "time_s"), result.series(name, "kinetics_tau_s"), ls="--",
                          label=f"{name} {registry.get('kinetics').label}")
        axes[-1].set_ylabel(f"{registry.get('tau_c').label}, {_label('kinetics')}")
    axes[-1].axhline(result.max_lag * result.dt, color="grey", ls="--", lw=0.8,
                     label=f"K·Δt = {seconds_label(result.max_lag * result.dt)}: longer τc reads as this")
    axes[-1].legend(fontsize=8)
    axes[-1].set_yscale("log")
    seconds_axis(axes[-1].yaxis)
    axes[-1].set_xlabel("time (s)")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Activity against time — {title}")
    fig.tight_layout()
    return fig


def plot_activity(path: Path, result: Timeline, title: str, source: str | None = None) -> None:
    fig = activity_figure(result, title)
    fig.savefig(path, dpi=100, metadata={"Source": source} if source else None)
    pyplot().close(fig)


def plot_histograms(path: Path, result: Timeline, title: str, source: str | None = None) -> None:
    plt = pyplot()
    image = result.histogram_image()
    times = np.asarray(result.sample_times, np.float64)
    edges = result.histogram_edges
    fig, ax = plt.subplots(figsize=(8, 4.5))
    span = (times[0], times[-1] if times[-1] > times[0] else times[0] + result.dt)
    shown = ax.imshow(image, origin="lower", aspect="auto", cmap="magma",
                      extent=(span[0], span[1], edges[0], edges[-1]))
    fig.colorbar(shown, ax=ax, label="probability density")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{result.histogram_estimator.upper()} of the pixels")
    ax.set_title(f"Histogram of the {result.histogram_estimator.upper()} map against time — {title}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100, metadata={"Source": source} if source else None)
    plt.close(fig)
