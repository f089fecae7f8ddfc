"""What recording costs the daemon: its highest zero-drop rate with ``[recording]`` continuous
against the same without recording, in one run (``edgedsm bench e2e``'s trials: the daemon's own
``Pipeline`` on replayed simulated speckle, the MQTT sink on a private mosquitto).

Measured, in one run, at one frame size (default 2048², Mono8):

1. the bare engine's rate (the upper bound, as ``bench e2e``);
2. capacity (the replay waits for the daemon) without and with recording, in the order
   without, with, with, without, so that the machine's drift cancels in their ratio;
3. the highest paced rate with zero drops **without recording** (bisection from 97 % of the
   lower capacity without recording);
4. the same **recording continuously** (``Recorder`` handed to the pipeline as the daemon does,
   zstd, files of ``segment_s`` on the disk of ``--dir``, retention at ``--max-gb``), judged on
   the measurement's drops (the recorder's counted beside them); bisection down from rate 3;
5. the highest paced rate at which **every frame is on disk too** (neither the measurement nor
   the recorder dropped a frame).

The ratios printed (rates 4 and 5 ÷ rate 3, and the capacities') are measured in this run; with
the frames written, the MB/s on disk and the frames still queued for the disk when a trial stopped.

With ``--timeline``, what re-analysing an archive costs instead: ``analyze --timeline`` on the
paper's series, its peak RSS and its time against decoding + the bare engine
(:mod:`edgedsm_lab.bench.timeline_archive`; docs/recording.md).

Examples:
  edgedsm bench recording --quick                       # 2048² Mono8, a few minutes
  edgedsm bench recording -o docs/bench-recording.md
  edgedsm bench recording --timeline --timeline-dir /work/scratch/big600   # the paper's series
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

from edgedsm.config import RecordingSection
from edgedsm.daemon.recording import Recorder
from edgedsm_lab.bench import timeline_archive
from edgedsm_lab.bench.e2e import PIXEL_FORMATS, best_zero_drop, search_rate
from edgedsm_lab.bench.e2e_trial import (
    Trial,
    bare_engine,
    daemon_config,
    make_recording,
    parse_size,
    quiet_daemon_logs,
    run_trial,
)
from edgedsm_lab.bench.report import Report, add_output_argument, cpu_sample, load_average, machine_use, others_share

HELP = ("what continuous [recording] costs the daemon's zero-drop rate (with ÷ without, one run); "
        "--timeline: analyze --timeline on an archive, peak RSS and time")
DESCRIPTION = __doc__
SEGMENT_S = 10.0
FLUSH_S = 60.0  # how long the disk may take to catch up after a trial (reported)


@dataclass
class Recorded:
    """One trial recording: the pipeline's trial and what the recorder did."""

    trial: Trial
    measurement_drops: int  # frames the measurement's queue dropped
    written: int  # frames on disk, backlog included
    dropped: int  # frames the recorder dropped during the trial
    queued: int  # frames waiting for the disk when the trial stopped
    mb: float  # MB written

    @property
    def measured(self) -> bool:
        """Paced and the measurement kept up without a drop (the recorder's drops counted apart)."""
        return self.trial.sustained

    @property
    def sustained(self) -> bool:
        """... and every frame is on disk."""
        return self.trial.sustained and self.dropped == 0

    disk_s: float = float("nan")  # the trial's whole time (window filling and stopping included)
    mb_by_stop: float = float("nan")  # MB written by the time the trial stopped

    @property
    def mb_s(self) -> float:
        """MB/s written to disk over the trial's whole time."""
        return self.mb_by_stop / self.disk_s

    @property
    def mb_per_frame(self) -> float:
        return self.mb / self.written if self.written else float("nan")


def recorded_trial(label: str, config_for: object, rate: float | None, seconds: float, directory: Path,
                   max_bytes: int, index: int) -> Recorded:
    section = RecordingSection(mode="continuous", segment_s=SEGMENT_S, max_bytes=max_bytes)
    folder = directory / f"trial-{index}"
    recorder = Recorder(section, folder, "bench", source="bench")
    try:
        started = time.monotonic()
        trial = run_trial(label, config_for(rate or 0.0), rate=rate, seconds=seconds,  # type: ignore[operator]
                          recorder=recorder)
        disk_s, mb_by_stop = time.monotonic() - started, recorder.files.bytes_written / 1e6
        stats = recorder.stats()
        recorder.flush(FLUSH_S)
    finally:
        recorder.close(5.0)
    files = recorder.files
    result = Recorded(trial, trial.drops, files.written, stats.frames_dropped, stats.queued,
                      files.bytes_written / 1e6, disk_s, mb_by_stop)
    for path in folder.glob("*.tif"):
        path.unlink()
    return result


def measure(shape: tuple[int, int], pixel_format: str, workdir: Path, record_dir: Path, port: int, *,
            seconds: float, max_trials: int, max_bytes: int) -> tuple[list[float], list[Trial], list[Recorded]]:
    bits = PIXEL_FORMATS[pixel_format]
    say(f"{shape[1]}x{shape[0]} {pixel_format}: replay of simulated speckle ...")
    recording = make_recording(workdir / "frames.npy", shape, bits)
    counter = iter(range(10**6))

    def config_for(rate: float):  # type: ignore[no-untyped-def]
        return daemon_config(recording, port, workdir / f"state-{next(counter)}", rate, bits, shape)

    plain_trials: list[Trial] = []
    bare = [bare_engine(recording, seconds, bits)]
    say(f"  bare engine: {bare[0]:.1f} frames/s")
    step = 5.0 if bare[0] >= 250 else 1.0 if bare[0] >= 50 else 0.5

    def plain(rate: float) -> Trial:
        trial = run_trial("without recording", config_for(rate), rate=rate, seconds=seconds)
        say(f"  without recording at {rate:g}/s: {trial.fps:.1f} processed, {trial.drops} dropped"
            f"{' (sustained)' if trial.sustained else ''}")
        return trial

    recorded: list[Recorded] = []

    def with_recording(rate: float, every_frame: bool) -> Trial:
        result = recorded_trial("recording", config_for, rate, seconds, record_dir, max_bytes, len(recorded))
        recorded.append(result)
        say(f"  recording at {rate:g}/s: {result.trial.fps:.1f} processed, {result.trial.drops} dropped, "
            f"recorder {result.written} written / {result.dropped} dropped, {result.mb_s:.0f} MB/s"
            f"{' (measurement sustained)' if result.measured else ''}{' (every frame on disk)' * result.sustained}")
        # search_rate judges Trial.sustained: for every frame on disk, the recorder's drops count too
        return replace(result.trial, drops=result.trial.drops + result.dropped) if every_frame else result.trial

    # capacity (the source waits), ABBA so that the machine's drift cancels: without, with, with, without
    capacity: list[tuple[str, float]] = []
    for recorded_now in (False, True, True, False):
        if recorded_now:
            result = recorded_trial("capacity, recording", config_for, None, seconds, record_dir, max_bytes,
                                    len(recorded))
            recorded.append(result)
            capacity.append(("recording", result.trial.fps))
            say(f"  capacity recording: {result.trial.fps:.1f} frames/s, recorder {result.written} written / "
                f"{result.dropped} dropped")
        else:
            trial = run_trial("capacity", config_for(0.0), rate=None, seconds=seconds)
            plain_trials.append(trial)
            capacity.append(("without", trial.fps))
            say(f"  capacity without recording: {trial.fps:.1f} frames/s")
    without = [fps for kind, fps in capacity if kind == "without"]
    start = step * max(1, math.floor(0.97 * min(without) / step))
    plain_trials += search_rate(plain, start=start, ceiling=max(without) * 1.05, max_trials=max_trials,
                                resolution=step, step=step)
    best = best_zero_drop(plain_trials)
    base = best.rate if best is not None and best.rate else step
    measured = search_rate(lambda rate: with_recording(rate, False), start=base, ceiling=base + step,
                           max_trials=max_trials, resolution=step, step=step)
    kept = best_zero_drop(measured)
    # every frame on disk: from the best rate found with any recorder drop, or half the rate without
    top = kept.rate if kept is not None and kept.rate else base
    start = step * max(1, math.floor(top / step)) if any(r.sustained for r in recorded) else \
        step * max(1, math.floor(0.5 * top / step))
    search_rate(lambda rate: with_recording(rate, True), start=start, ceiling=top + step, max_trials=max_trials,
                resolution=step, step=step)
    bare.append(bare_engine(recording, seconds, bits))
    recording.unlink()
    return bare, plain_trials, recorded


def _rate(trial: Trial) -> str:
    return "capacity" if trial.rate is None else f"{trial.rate:g}"


def _sustained(rate: float | None, sustained: bool) -> str:
    return "—" if rate is None else "yes" if sustained else "no"


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


def say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    if getattr(args, "timeline", False):  # an archive through analyze --timeline instead
        return timeline_archive.run(args)
    from edgedsm.localbroker import LocalBroker

    seconds = args.seconds or (12.0 if args.quick else 20.0)
    max_trials = 3 if args.quick else 4
    load = load_average()
    before = cpu_sample()
    with tempfile.TemporaryDirectory(prefix="edgedsm-bench-recording-") as tmp, quiet_daemon_logs(), \
            LocalBroker() as broker:
        record_dir = Path(args.dir) if args.dir else Path(tmp) / "recordings"
        bare, plain, recorded = measure(args.size, args.pixel_format, Path(tmp), record_dir, broker.port,
                                        seconds=seconds, max_trials=max_trials, max_bytes=int(args.max_gb * 1e9))
    others = others_share(before, cpu_sample())
    best_plain = best_zero_drop(plain)
    clean = [r for r in recorded if r.sustained and r.trial.rate is not None]
    best_rec = max(clean, key=lambda r: r.trial.rate or 0.0) if clean else None
    report = Report("Recording in the daemon: its cost to the zero-drop rate")
    report.line(report.machine("edgedsm bench recording", "numba", "tifffile", "imagecodecs", load=load)
                + f" {machine_use(others, load)}")
    report.line()
    height, width = args.size
    report.line(f"{width}x{height} {args.pixel_format}, {seconds:g} s per trial after the window filled, "
                f"`[recording]` continuous, zstd, files of {SEGMENT_S:g} s, retention at {args.max_gb:g} GB, on "
                f"{'--dir ' + args.dir if args.dir else 'a temporary folder'}. Bare engine {bare[0]:.1f} frames/s "
                f"before the trials, {bare[-1]:.1f} after.")
    report.line()
    rows = [["without recording", _rate(t), f"{t.fps:.1f}", str(t.drops), "", "", "", "", "",
             _sustained(t.rate, t.sustained)] for t in plain]
    rows = [[*row, ""] for row in rows]
    rows += [["recording", _rate(r.trial), f"{r.trial.fps:.1f}", str(r.measurement_drops), str(r.written),
              str(r.dropped), str(r.queued), f"{r.mb_s:.0f}", f"{r.mb_per_frame:.2f}",
              _sustained(r.trial.rate, r.measured), _sustained(r.trial.rate, r.sustained)] for r in recorded]
    report.table(["trial", "requested frames/s", "processed frames/s", "measurement drops", "frames on disk",
                  "recorder drops", "queued for disk at stop", "MB/s to disk (whole trial)", "MB a frame on disk",
                  "measurement sustained",
                  "every frame on disk"], rows)
    report.line()
    cap_plain = [t.fps for t in plain if t.rate is None]
    cap_rec = [r.trial.fps for r in recorded if r.trial.rate is None]
    if cap_plain and cap_rec:
        ratio = _mean(cap_rec) / _mean(cap_plain)
        report.line(f"Capacity (the source waits; without, with, with, without): {_mean(cap_rec):.1f} frames/s "
                    f"recording every frame, {_mean(cap_plain):.1f} without: **{ratio:.0%}**.")
        report.line()
    if best_plain is None or best_plain.rate is None:
        report.line("No zero-drop rate without recording was found: no ratio.")
    else:
        base = best_plain.rate
        measured = [r for r in recorded if r.measured and r.trial.rate is not None]
        best_measured = max(measured, key=lambda r: r.trial.rate or 0.0) if measured else None
        rate = (best_measured.trial.rate or 0.0) if best_measured is not None else 0.0
        lost = f", the recorder dropping {best_measured.dropped} frames" if best_measured is not None else ""
        report.line(f"**Highest zero-drop rate of the measurement: {base:g} frames/s without recording, {rate:g} "
                    f"recording{lost}: {rate / base:.0%}** (measured in this run).")
        report.line()
        rec_rate = best_rec.trial.rate if best_rec is not None and best_rec.trial.rate else 0.0
        report.line(f"**Every frame on disk as well: {rec_rate:g} frames/s, {rec_rate / base:.0%}** of the rate "
                    "without recording.")
    report.line()
    if args.output:
        report.save(args.output)
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--size", type=parse_size, default=(2048, 2048), metavar="WxH", help="frame size (2048x2048)")
    parser.add_argument("--pixel-format", choices=tuple(PIXEL_FORMATS), default="Mono8",
                        help="pixel format of the replayed frames (default Mono8)")
    parser.add_argument("--quick", action="store_true", help="shorter trials (12 s), fewer paced rates")
    parser.add_argument("--seconds", type=float, metavar="S", help="seconds per trial (default 20; quick 12)")
    parser.add_argument("--dir", metavar="DIR", help="where the recordings go (default: a temporary folder); "
                                                     "the disk measured")
    parser.add_argument("--max-gb", type=float, default=4.0, metavar="GB", help="retention budget (default 4 GB)")
    add_output_argument(parser, "docs/bench-recording.md")
    timeline_archive.add_arguments(parser)
