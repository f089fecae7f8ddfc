"""`analyze --timeline` on an archive in bounded memory (issue 38, part 3): its peak RSS and its
time against decoding the frames and pushing them through the bare engine, in one run.

The paper's series: 600 frames of 4096×2168 (the paper's camera), an 8-bit PNG folder of complex
Gaussian speckle (an AR(1) field per pixel, τc = 10 frames in intensity, mean 60 grey levels, PNG
level 1: :func:`make_series`, 4.9 GB, written once into ``--timeline-dir`` and kept there),
``--window 200 --lag 5 --every 200`` (disjoint sets: the paper's Figs. 10-11 processing). Each
part runs in its own process, one after the other on the same folder (in the page cache after
the first), and its peak RSS is that process's own (``ru_maxrss`` of ``os.wait4``):

1. **decoding alone**: the folder's frames read through ``edgedsm.frameio`` (analyze's reader);
2. **decoding + the bare engine**: each frame decoded, then pushed through the engine
   ``analyze --timeline`` builds (``EngineSpec`` of its ``[estimator]``: S1, S2, S3, tumbling on
   disjoint sets), one after the other in one thread; the seconds spent in the pushes (timed in
   that process) are the bare engine alone;
3. **``analyze --timeline``** with every column it writes by default (S1-S3, each region's τc,
   the light and the activity above the noise), its CSV and both pictures.

Each part runs ``--timeline-rounds`` times (default 2), in the order 1, 2, 3, then 3, 2, 1, so
that a drift of the machine's load cancels in the means. The ratio printed is the mean of 3 ÷
the mean of 2, measured in this run; beside it 3 ÷ (1 + the seconds 2 spent in its pushes).
``--quick``: a small series (512×256, 120 frames, N = 40) for a test of the benchmark itself,
not a figure.

Examples:
  edgedsm bench recording --timeline --timeline-dir /work/scratch/big600     # the paper's series
  edgedsm bench recording --timeline --quick
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from edgedsm_lab.bench import peak
from edgedsm_lab.bench.report import Report, cpu_sample, load_average, machine_use, others_share

#: (height, width, frames, window, lag, every) of the paper's series and of the quick one
PAPER = (2168, 4096, 600, 200, 5, 200)
QUICK = (256, 512, 120, 40, 5, 40)
#: The issue's bounds: peak RSS (GiB) and time ÷ (decoding + the bare engine)
PEAK_GIB, RATIO = 1.5, 1.5
GIB = 2**30


@dataclass(frozen=True)
class Part:
    """One measured process: its wall time (s), its own peak RSS (bytes) and, for "decoding + the
    bare engine", the seconds it spent pushing (the bare engine alone)."""

    name: str
    seconds: float
    peak: int
    push_s: float | None = None


def make_series(folder: Path, count: int, height: int, width: int, tau: float = 10.0, seed: int = 1) -> None:
    """``count`` 8-bit PNG frames of complex Gaussian speckle, img_0000.png ...: per pixel an
    AR(1) field E_t = r·E_{t-1} + √(1-r²)·ε_t, r = exp(-1/(2τ)), whose intensity |E|²·30 (grey
    levels, mean 60) decorrelates as exp(-t/τ) (τ in frames)."""
    import cv2
    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    r = np.float32(np.exp(-1 / (2 * tau)))
    s = np.float32(np.sqrt(1 - r * r))
    real = rng.standard_normal((height, width), dtype=np.float32)
    imag = rng.standard_normal((height, width), dtype=np.float32)
    for index in range(count):
        real = r * real + s * rng.standard_normal((height, width), dtype=np.float32)
        imag = r * imag + s * rng.standard_normal((height, width), dtype=np.float32)
        frame = np.clip((real * real + imag * imag) * np.float32(30.0), 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"img_{index:04d}.png"), frame, [cv2.IMWRITE_PNG_COMPRESSION, 1])


def run_part(part: str, folder: str, window: int, lag: int, every: int) -> None:
    """One part in this process: "decode" (read every frame) or "engine" (read and push each,
    printing the seconds spent in the pushes)."""
    from edgedsm.frameio import open_frames

    engine = None
    pushing = 0.0
    with open_frames(folder) as reader:
        for frame in reader.frames():
            if part == "decode":
                continue
            if engine is None:  # imported here: decoding alone does not load the engine's modules
                from edgedsm.measurement import EngineSpec
                from edgedsm.timeline import analysis_config

                mode = "tumbling" if every % window == 0 else "sliding"
                settings = analysis_config(window, lag, mode=mode)
                engine = EngineSpec.of_sections(settings.estimator).engine(frame.shape, reader.bits)
            started = time.perf_counter()
            engine.push(frame)
            pushing += time.perf_counter() - started
    if part == "engine":
        print(f"push_s {pushing:.6f}")


def measure(name: str, command: list[str], timeout: float) -> Part:
    """Run ``command`` (its first item an absolute path): its wall time and its own peak RSS
    (:func:`edgedsm_lab.bench.peak.measure`); a line "push_s SECONDS" on its stdout is the time
    it spent pushing."""
    try:
        done = peak.measure(command, timeout)
    except TimeoutError:
        raise RuntimeError(f"{name}: did not end within {timeout:.0f} s") from None
    if done.code != 0:
        raise RuntimeError(f"{name}: exit {done.code}: {done.err[-2000:]}")
    pushed = [float(line.split()[1]) for line in done.out.splitlines() if line.startswith("push_s ")]
    return Part(name, done.seconds, done.rss, pushed[-1] if pushed else None)


#: The parts' names, in the order of one round
NAMES = ("decoding alone", "decoding + the bare engine", "analyze --timeline")


def parts(folder: Path, window: int, lag: int, every: int, timeout: float, rounds: int = 2) -> list[Part]:
    """Every part ``rounds`` times, in the order decoding, engine, timeline, then backwards, and so
    on (ABC CBA: a drift of the machine's load cancels in the means)."""
    python = sys.executable
    here = [python, "-c", "import sys; from edgedsm_lab.bench.timeline_archive import run_part; "
            "run_part(sys.argv[1], sys.argv[2], *map(int, sys.argv[3:]))"]
    shape = [str(window), str(lag), str(every)]
    with tempfile.TemporaryDirectory(prefix="edgedsm-bench-timeline-") as out:
        timeline = [python, "-m", "edgedsm", "analyze", str(folder), "--timeline", out, "--window", str(window),
                    "--lag", str(lag), "--every", str(every), "--no-progress"]
        commands = dict(zip(NAMES, ([*here, "decode", str(folder), *shape], [*here, "engine", str(folder), *shape],
                                    timeline), strict=True))
        found = []
        for index in range(rounds):
            for name in NAMES if index % 2 == 0 else NAMES[::-1]:
                found.append(measure(name, commands[name], timeout))
                pushed = f" ({found[-1].push_s:.1f} s pushing)" if found[-1].push_s is not None else ""
                say(f"  {name}: {found[-1].seconds:.1f} s{pushed}, peak RSS {found[-1].peak / GIB:.2f} GiB")
        return found


def say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


def report_lines(found: list[Part], size: tuple[int, ...], others: float | None, load: float | None,
                 load_after: float | None) -> Report:
    """The report: each part's runs and mean, the bare engine alone, and the two figures."""
    height, width, count, window, lag, every = size
    report = Report("`analyze --timeline` on an archive: peak memory and time")
    report.line(report.machine("edgedsm bench recording --timeline", "numba", "cv2", load=load, load_after=load_after)
                + machine_use(others, load))
    report.line()
    report.line(f"{count} frames of {width}x{height}, 8-bit PNG folder; `--window {window} --lag {lag} --every "
                f"{every}`, default columns (S1-S3, each region's τc at K = 20, the light and the activity above "
                "the noise), CSV and both pictures. Each part in its own process, one after the other (in the "
                "order of the runs, then backwards); peak RSS is the process's own.")
    report.line()
    runs = {name: [part for part in found if part.name == name] for name in NAMES}
    seconds = {name: _mean([part.seconds for part in parts]) for name, parts in runs.items()}
    peaks = {name: max(part.peak for part in parts) for name, parts in runs.items()}
    pushing = _mean([part.push_s for part in runs[NAMES[1]] if part.push_s is not None] or [float("nan")])
    rows = [[name, " / ".join(f"{part.seconds:.1f}" for part in runs[name]), f"{seconds[name]:.1f}",
             f"{peaks[name] / GIB:.2f}"] for name in NAMES]
    rows.insert(2, ["(the bare engine alone: its pushes in 2)",
                    " / ".join(f"{part.push_s:.2f}" for part in runs[NAMES[1]] if part.push_s is not None),
                    f"{pushing:.2f}", ""])
    report.table(["part", "wall s, each run", "mean s", "peak RSS GiB"], rows)
    report.line()
    timeline, engine = seconds[NAMES[2]], seconds[NAMES[1]]
    report.line(f"**`analyze --timeline`: peak RSS {peaks[NAMES[2]] / GIB:.2f} GiB (bound {PEAK_GIB:g}), "
                f"{timeline / engine:.2f}× decoding + the bare engine (bound {RATIO:g}×)**, the means of this run; "
                f"{timeline / (seconds[NAMES[0]] + pushing):.2f}× decoding alone plus the bare engine's pushes.")
    return report


def run(args: argparse.Namespace) -> int:
    size = QUICK if args.quick else PAPER
    height, width, count, window, lag, every = size
    load = load_average()
    with tempfile.TemporaryDirectory(prefix="edgedsm-series-") as scratch:
        folder = Path(args.timeline_dir) if args.timeline_dir else Path(scratch) / "series"
        if not folder.is_dir() or not any(folder.iterdir()):
            say(f"writing {count} frames of {width}x{height} to {folder} ...")
            make_series(folder, count, height, width)
        before = cpu_sample()
        found = parts(folder, window, lag, every, timeout=args.timeline_timeout, rounds=args.timeline_rounds)
        others = others_share(before, cpu_sample())
    report = report_lines(found, size, others, load, load_average())
    if args.output:
        report.save(args.output)
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The timeline's options of ``edgedsm bench recording`` (with ``--timeline``)."""
    group = parser.add_argument_group("an archive through analyze --timeline (--timeline)")
    group.add_argument("--timeline", action="store_true",
                       help="measure analyze --timeline on the paper's series (600 frames of 4096x2168, "
                            "N = 200, m = 5, every 200; --quick: 120 of 512x256) instead: peak RSS and time "
                            "against decoding + the bare engine")
    group.add_argument("--timeline-dir", metavar="DIR",
                       help="the series' folder (written there first when empty or missing, 4.9 GB for the "
                            "paper's; default: a temporary folder)")
    group.add_argument("--timeline-rounds", type=int, default=2, metavar="R",
                       help="runs of each part, in the order decoding, engine, timeline, then backwards "
                            "(default 2)")
    group.add_argument("--timeline-timeout", type=float, default=1800.0, metavar="S",
                       help="longest time for one part (default 1800 s)")
