"""Commission a line from a reference run: which estimator, window N and lag m tell this
surface's wet from its dry soonest and at what cost, with thresholds to paste into the daemon
config (docs/commissioning.md).

RUN is a recording that goes from wet to dry (anything `analyze` reads: an `edgedsm record` file,
TIFF, video, an image folder, .npy) or a simulated scene (SCENE.toml, `default`); the regions and
the camera settings come from the daemon config (-c). Before --wet-until the surface is wet, after
--dry-from it is dry (seconds from the first frame, on the recording's own clock,
camera.frame_interval_s, or --dt). Instead of a run and marks, --wet REC and --dry REC take two
recordings. Every candidate (an activity the daemon judges on: S1, S2, S3, Fujii, IM and the
temporal contrast plain and above the noise floor, τc; at each window and lag that fits; the
kinetics once, where the run is one drying on a steady clock; --estimators narrows them, or adds
GD, left out by default for its O(N) push) is scored on every
region: the separation of wet and dry (AUC, d′), when the daemon's state machine with the
proposed thresholds calls it dry, its false transitions, and its cost per frame, measured by the
engine on this PC. Exit 65 when the run cannot answer (too short, marks outside it, or no
candidate separating wet from dry), with the best separation found.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from edgedsm.commands.common import add_progress_flag
from edgedsm.config import check_regions, load_config
from edgedsm.errors import DataError
from edgedsm.frameio import open_frames
from edgedsm.tuning.output import keep_last, report, snippet, summary_json
from edgedsm.tuning.series import DEFAULT_CANDIDATES, TUNABLE
from edgedsm.tuning.session import LAGS, WINDOWS, Run, settings_for, tune

NAME = "tune"
HELP = "choose estimator, window, lag and thresholds from a wet-to-dry reference run (docs/commissioning.md)"
SCENE_SUFFIXES = (".toml",)


def _numbers(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected integers separated by commas, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected integers >= 1, got {text!r}")
    return values


def _estimators(text: str) -> tuple[str, ...]:
    names = tuple(part.strip() for part in text.split(",") if part.strip())
    unknown = [name for name in names if name not in TUNABLE]
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"expected some of {','.join(TUNABLE)} separated by commas, got {text!r}")
    return names


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", nargs="?", metavar="RUN", help="the reference run: a recording or a scene (.toml)")
    parser.add_argument("-c", "--config", required=True, metavar="CONFIG.toml", help="the daemon config: regions, "
                        "camera (frame interval, noise), q, noise patch, dwell")
    parser.add_argument("--wet-until", type=float, metavar="SECONDS", help="the surface is wet before this time")
    parser.add_argument("--dry-from", type=float, metavar="SECONDS", help="the surface is dry after this time")
    parser.add_argument("--wet", metavar="REC", help="a wet reference recording (with --dry, instead of RUN)")
    parser.add_argument("--dry", metavar="REC", help="a dry reference recording (with --wet)")
    parser.add_argument("-o", "--output", metavar="SNIPPET.toml", help="write the [estimator] and [[regions]] "
                        "tables of the recommended candidate here")
    parser.add_argument("--report", metavar="DIR", help="write report.md, activity.png and tradeoff.png here")
    parser.add_argument("--json", action="store_true", help="print every candidate's scores as JSON")
    parser.add_argument("--budget", type=float, default=600.0, metavar="SECONDS",
                        help="time for the search; window settings that would not fit are left out (default 600)")
    parser.add_argument("--windows", type=_numbers, default=WINDOWS, metavar="N,N,...",
                        help=f"windows to try (default {','.join(map(str, WINDOWS))})")
    parser.add_argument("--lags", type=_numbers, default=LAGS, metavar="M,M,...",
                        help=f"lags to try (default {','.join(map(str, LAGS))})")
    parser.add_argument("--estimators", type=_estimators, default=DEFAULT_CANDIDATES, metavar="NAME,NAME,...",
                        help=f"activities to try, among {','.join(TUNABLE)} (default all but gd, whose O(N) "
                             "push makes every pass several times longer: name it to weigh it)")
    parser.add_argument("--dt", type=float, metavar="SECONDS", help="frame interval (default: the recording's "
                        "clock, the scene's, or camera.frame_interval_s)")
    parser.add_argument("--channel", choices=("red", "green", "blue", "luma"), help="channel of a colour input")
    parser.add_argument("--frames", dest="frame_count", type=int, metavar="COUNT",
                        help="frames to simulate when RUN is a scene (default: the scene's)")
    add_progress_flag(parser)


def run(args: argparse.Namespace) -> int:
    with contextlib.ExitStack() as stack:
        return _run(args, stack)


def _run(args: argparse.Namespace, stack: contextlib.ExitStack) -> int:
    config = load_config(args.config)
    two = args.wet is not None or args.dry is not None
    if two == (args.run is not None) or (two and (args.wet is None or args.dry is None)):
        raise DataError("give RUN with --wet-until and --dry-from, or --wet REC and --dry REC")
    if not two and (args.wet_until is None or args.dry_from is None):
        raise DataError(f"{args.run}: --wet-until and --dry-from are needed with a single run")
    reference = _two_runs(args, config) if two else _one_run(args, config, stack)
    first = next(reference.frames())
    check_regions(config, first.shape)
    masks = {region.name: region.mask(first.shape, config.base_dir) for region in config.regions}
    settings = settings_for(reference, args.windows, args.lags)
    bar = _bar(reference.count * len(settings), args.progress)
    try:
        result = tune(reference, config, masks, args.budget, settings, on_frame=bar.update if bar else None,
                      on_pass=(lambda s, i, n: bar.set_description(f"tune {s.label()} ({i + 1}/{n})")) if bar
                      else None, estimators=args.estimators)
    finally:
        if bar is not None:
            bar.close()
    command = "edgedsm tune " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["tune"] else "edgedsm tune"
    written = report(Path(args.report), result, command) if args.report else []
    last = config.device.commissioning_directory(config.base_dir)
    try:  # for the dashboard (docs/commissioning.md); this run's answer stands without it
        keep_last(last, result, command, config)
    except OSError as exc:
        print(f"edgedsm: warning: the dashboard will not show this report: cannot write {last}: "
              f"{exc.strerror or exc} (set device.commissioning_dir)", file=sys.stderr)
    if args.json:
        print(json.dumps(summary_json(result), indent=1, ensure_ascii=False))
    if result.chosen is None:
        raise DataError(f"{reference.name}: {result.reason}")
    if args.output:
        Path(args.output).write_text(snippet(result, config, command), encoding="utf-8")
        written.insert(0, Path(args.output))
    if not args.json:
        print(f"{result.reason}.")
        print(f"{len(result.outcomes)} candidates from {len(result.series)} window settings in {result.seconds:.0f} s"
              + (f" ({len(result.skipped)} left out by --budget {args.budget:g})" if result.skipped else "")
              + (f" -> {', '.join(str(p) for p in written)}" if written else ""))
    return 0


def _bar(total: int, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc="tune", unit="frame", disable=None, leave=False)


def _one_run(args: argparse.Namespace, config, stack: contextlib.ExitStack) -> Run:
    source = args.run
    if source == "default" or Path(source).suffix.lower() in SCENE_SUFFIXES:
        return _scene_run(args, config, stack)
    with open_frames(source, args.channel) as reader:
        for note in reader.notes:
            print(f"edgedsm: warning: {note}", file=sys.stderr)
        count, bits, dt = reader.count, reader.bits, reader.dt
        stamps = reader.stamps()
    if count is None:
        count = sum(1 for _ in _read(source, args.channel))
    times = None
    if stamps is not None and args.dt is None:
        times = (stamps.t_ns[:count] - stamps.t_ns[0]) / 1e9
    dt = args.dt or dt or config.camera.frame_interval_s
    if dt is None and times is None:
        raise DataError(f"{source}: the frame interval is not known: give --dt or camera.frame_interval_s")
    if dt is None:
        dt = float(np.median(np.diff(times))) if times is not None and times.size > 1 else 1.0
    return Run(lambda: _read(source, args.channel), count, bits, dt, times, args.wet_until, args.dry_from, source)


def _scene_run(args: argparse.Namespace, config, stack: contextlib.ExitStack) -> Run:
    """A scene simulated once into a temporary memory-mapped file, read again by every pass."""
    from edgedsm.commands.common import scene_argument
    from edgedsm.sim import Simulator

    scene = scene_argument(args.run)
    count = args.frame_count or scene.scene.frames
    folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="edgedsm-tune-")))
    stack_file = None
    for index, frame in enumerate(Simulator(scene).frames(count)):
        if stack_file is None:
            stack_file = np.lib.format.open_memmap(folder / "run.npy", "w+", frame.dtype, (count, *frame.shape))
        stack_file[index] = frame
    assert stack_file is not None
    stack_file.flush()
    frames = np.load(folder / "run.npy", mmap_mode="r")
    dt = args.dt or scene.scene.dt or config.camera.frame_interval_s or 1.0
    return Run(lambda: iter(frames), count, scene.detector.bits if scene.detector else None, dt, None,
               args.wet_until, args.dry_from, str(args.run))


def _two_runs(args: argparse.Namespace, config) -> Run:
    """The wet recording followed by the dry one: wet until its last frame, dry from the other's first."""
    counts, bits, dts = [], None, []
    for source in (args.wet, args.dry):
        with open_frames(source, args.channel) as reader:
            counts.append(reader.count if reader.count is not None else sum(1 for _ in reader.frames()))
            bits, dts = reader.bits, [*dts, reader.dt]
    dt = args.dt or dts[0] or config.camera.frame_interval_s
    if dt is None:
        raise DataError(f"{args.wet}: the frame interval is not known: give --dt or camera.frame_interval_s")

    def frames() -> Iterator[np.ndarray]:
        yield from _read(args.wet, args.channel)
        yield from _read(args.dry, args.channel)

    return Run(frames, sum(counts), bits, dt, None, (counts[0] - 1) * dt, counts[0] * dt,
               f"{args.wet} + {args.dry}", joined=True)


def _read(source: str, channel: str | None) -> Iterator[np.ndarray]:
    with open_frames(source, channel) as reader:
        yield from reader.frames()
