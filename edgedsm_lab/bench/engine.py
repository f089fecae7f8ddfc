"""Streaming-engine benchmark: what exactness costs in time, per window mode and kernel.

Measures, side by side in one run (N = 200 frames, lag m = 10, all three maps, 8-bit frames),
and the cost of the correlation time τc (K = 2m lags) alone and beside the three maps:

  1. a streaming memory bandwidth (read-modify-write of two large float64 arrays, the access
     pattern of the engine's sums, and a plain copy; the best is kept);
  2. per frame size, mode (sliding, tumbling, exponential) and kernel (numba, numpy):
     ms per pushed frame, Mpx/s, bytes of state per pixel, the bytes one push must move per
     pixel and the ratio of the measured time to that traffic at the measured bandwidth
     (1.0 = as fast as memory allows), the cost of ``maps()``, the speed-up against
     recomputing the maps from the window with the float64 batch reference, and the largest
     difference of the maps from that reference;
  3. the map noise at constant activity: spatial spread (standard deviation / mean) of S1, S2
     and S3 on simulated speckle (τc = 20 frames) against N, for the sliding and the
     exponential window, so N and the mode can be chosen knowingly.

Frames are synthetic 8-bit speckle (exponential intensities, mean 60 grey levels) cycled
from a pool; the engines are first filled with N frames (steady state: every push adds and
removes), then timed frame by frame; tables give the median. numba runs first and its state
is handed to the numpy engine (the kernels are bit-identical, which is checked), so the slow
fallback is only timed, not filled. The machine's load average is printed: other work on it
slows every row alike only on average, so compare rows of one run.

Examples:
  edgedsm bench engine                                # 1024² and 2048², a few minutes
  edgedsm bench engine --paper-size                   # also 4096 x 2168, the paper's camera
  edgedsm bench engine --quick                        # 256² and 512², about 30 s
  edgedsm bench engine --output docs/bench-engine.md  # also markdown, and a PNG plot
"""

from __future__ import annotations

import argparse
import functools
import gc
import importlib.util
import math
import os
import statistics
import time
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from edgedsm.estimators import SlidingWindow, all_maps
from edgedsm.estimators.correlation_time import longest_lag
from edgedsm_lab.bench.engine_bits import bench_bits, bits_table, needed_bytes
from edgedsm_lab.bench.engine_report import MODES, Row, noise_table, plot, speed_table
from edgedsm_lab.bench.report import Report, add_output_argument, load_average

HELP = "streaming engine vs batch recompute: ms/frame, memory, bandwidth bound, error, map noise"

PAPER_SIZE = (2168, 4096)  # rows x columns of the paper's camera
POOL = 16  # distinct frames cycled through the engines
EXACT_SAMPLE = 400  # pixels whose S2 is also computed in exact arithmetic


# -- measurements --------------------------------------------------------------------------
def measure_bandwidth(megabytes: int = 512, repeats: int = 5) -> tuple[float, str]:
    """Best streaming bandwidth in bytes/s, and how it was obtained.

    Read-modify-write a[i] += b[i] over two float64 arrays (numba, all threads; 3 x 8 bytes
    moved per element, as the engine's sums are read and written) and np.copyto (2 x 8).
    """
    n = megabytes * 2**20 // 16
    a = np.ones(n)
    b = np.ones(n)
    results: dict[str, float] = {}

    def best(step: Callable[[], object], moved: int) -> float:
        step()
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            step()
            times.append(time.perf_counter() - start)
        return moved / min(times)

    results["numpy copy"] = best(lambda: np.copyto(a, b), 16 * n)
    update = _numba_update()
    if update is not None:
        import numba

        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)  # all of them
        results[f"numba a += b ({numba.get_num_threads()} threads)"] = best(
            lambda: update(a, b), 24 * n)
    name = max(results, key=lambda key: results[key])
    detail = ", ".join(f"{key} {value / 1e9:.1f} GB/s" for key, value in results.items())
    return results[name], f"best of {detail} ({2 * 8 * n / 2**20:.0f} MiB arrays)"


@functools.cache
def _numba_update() -> Callable[[np.ndarray, np.ndarray], None] | None:
    """a[i] += b[i] over all threads (numba), or None without numba."""
    if not importlib.util.find_spec("numba"):
        return None
    import numba

    @numba.njit(parallel=True)
    def update(x: np.ndarray, y: np.ndarray) -> None:  # pragma: no cover - compiled
        for i in numba.prange(x.size):
            x[i] += y[i]

    return update


def speckle_pool(shape: tuple[int, int], seed: int = 7) -> list[np.ndarray]:
    """Synthetic 8-bit speckle frames: exponential intensities (mean 60) clipped at 255."""
    rng = np.random.default_rng(seed)
    return [np.minimum(rng.exponential(60.0, shape), 255.0).astype(np.uint8)
            for _ in range(POOL)]


def window_stack(pool: list[np.ndarray], first: int, count: int) -> np.ndarray:
    return np.stack([pool[j % POOL] for j in range(first, first + count)])


def handover(source: SlidingWindow, target: SlidingWindow) -> None:
    """Give ``target`` (another kernel) the state of ``source``: same layout, same sums."""
    for name, array in source._arrays.items():
        np.copyto(target._arrays[name], array)
    target.frames_seen = source.frames_seen
    target.blocks_completed = source.blocks_completed
    target._moments.weights = source._moments.weights  # exponential mode: Σλ^k over frames and pairs


def timed_pushes(engine: SlidingWindow, pool: list[np.ndarray], first: int,
                 count: int) -> list[float]:
    times = []
    for j in range(first, first + count):
        start = time.perf_counter()
        engine.push(pool[j % POOL])
        times.append(time.perf_counter() - start)
    return times


def time_maps(engine: SlidingWindow, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        engine.maps()
        times.append(time.perf_counter() - start)
    return min(times)


def max_errors(maps: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> dict[str, float]:
    return {name: float(np.max(np.abs(maps[name] - reference[name]))) for name in maps}


def exact_s2(samples: np.ndarray, lag: int) -> np.ndarray:
    """S2 of Eq. 2 (q = 0) in exact integer arithmetic for a (N, P) window of P pixels.

    Every denominator a+b divides L = lcm(1..2·max), so Σ|a-b|·(L/(a+b)) is an exact
    integer; only the final quotient is rounded (once, correctly) to float64.
    """
    values = samples.astype(np.int64)
    common = math.lcm(*range(1, 2 * int(values.max()) + 2))
    pairs = values.shape[0] - lag
    out = np.empty(values.shape[1])
    for p in range(values.shape[1]):
        column = values[:, p].tolist()
        total = sum(abs(a - b) * (common // (a + b)) for a, b in
                    zip(column[:pairs], column[lag:], strict=True) if a + b)
        out[p] = float(Fraction(total, common * pairs))
    return out


#: The field's streaming descriptors (docs/descriptors.md), each timed beside S1+S2+S3.
DESCRIPTOR_SETS = tuple(("s1", "s2", "s3", name) for name in ("contrast", "fujii", "im", "gd", "band_ratio"))
#: The paper's maps each alone, against S1 (what S2's exact term costs: issue 38).
SINGLE_MAPS = (("s1",), ("s2",), ("s3",))


def bench_tau(shape: tuple[int, int], window: int, lag: int, kernel: str, threads: int | None,
              pool: list[np.ndarray], log: Callable[[str], None]) -> list[dict[str, Any]]:
    """Sliding pushes with τc (K = 2m), alone and beside S1, S2, S3, and with each streaming
    descriptor beside S1, S2, S3 (q = 0: Fujii's): ms/frame and maps() ms."""
    lags = max(1, min(2 * lag, longest_lag(window)))  # K = 2m, as the tables before the N/2 default
    out = []
    for estimators in (*SINGLE_MAPS, ("s1", "s2", "s3"), ("tau_c",), ("s1", "s2", "s3", "tau_c"), *DESCRIPTOR_SETS):
        engine = SlidingWindow(shape, window, lag, bits=8, kernel=kernel, threads=threads,
                               estimators=estimators, max_lag=lags)
        for j in range(window):
            engine.push(pool[j % POOL])
        times = timed_pushes(engine, pool, window, window)
        maps_ms = time_maps(engine, 1 if "tau_c" in estimators else 3) * 1e3  # the first loads the kernel
        out.append({"shape": shape, "estimators": "+".join(estimators), "K": lags,
                    "ms": min(times) * 1e3, "median_ms": statistics.median(times) * 1e3,
                    "maps_ms": maps_ms, "state": engine.bytes_per_pixel, "traffic": engine.traffic_per_pixel})
        log(f"  sliding {kernel} {out[-1]['estimators']}: {out[-1]['ms']:.2f} ms/frame")
        del engine
        gc.collect()
    return out


def tau_table(rows: list[dict[str, Any]], bandwidth: float, which: str = "tau") -> list[str]:
    """The rows of ``which`` set of estimators: "tau" (τc, with S1+S2+S3 alone), "descriptors" (each
    beside S1+S2+S3) or "maps" (S1, S2, S3 each alone, and together); each push's time against
    S1+S2+S3's, S1's, and its own memory-bandwidth bound (moved bytes at ``bandwidth`` B/s)."""
    chosen = {"tau": {"s1+s2+s3", "tau_c", "s1+s2+s3+tau_c"},
              "descriptors": {"+".join(names) for names in DESCRIPTOR_SETS},
              "maps": {"+".join(names) for names in (*SINGLE_MAPS, ("s1", "s2", "s3"))}}[which]
    lines = [f"| frame | estimators (sliding{', K' if which == 'tau' else ''}) | ms/frame best (median) | "
             "x S1+S2+S3 | x S1 | state B/px | moved B/px | x bandwidth bound | maps() ms |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for row in rows:
        if row["estimators"] not in chosen:
            continue
        base = next(r for r in rows if r["shape"] == row["shape"] and r["estimators"] == "s1+s2+s3")
        s1 = next(r for r in rows if r["shape"] == row["shape"] and r["estimators"] == "s1")
        lags = f" (K = {row['K']})" if which == "tau" and "tau_c" in row["estimators"] else ""
        bound_ms = row["traffic"] * row["shape"][0] * row["shape"][1] / bandwidth * 1e3
        lines.append(f"| {row['shape'][1]}x{row['shape'][0]} | {row['estimators']}{lags} | "
                     f"{row['ms']:.2f} ({row['median_ms']:.2f}) | {row['ms'] / base['ms']:.2f} | "
                     f"{row['ms'] / s1['ms']:.2f} | {row['state']:.0f} | {row['traffic']:.0f} | "
                     f"{row['ms'] / bound_ms:.2f} | {row['maps_ms']:.0f} |")
    return lines


def bench_size(shape: tuple[int, int], window: int, lag: int, kernels: list[str],
               numpy_frames: int, bandwidth: float, threads: int | None,
               log: Callable[[str], None]) -> tuple[list[Row], dict[str, float]]:
    """All modes and kernels at one frame size (see the module docstring); also the S2
    errors of the engine and of the float64 batch against exact arithmetic on a sample."""
    pool = speckle_pool(shape)
    # the reference window: after 2N pushes the sliding window and the tumbling block are
    # both frames N..2N-1
    stack = window_stack(pool, window, window)
    start = time.perf_counter()
    reference = all_maps(stack, lag)
    batch_ms = (time.perf_counter() - start) * 1e3
    rng = np.random.default_rng(1)
    sample = rng.integers(0, shape[0] * shape[1], EXACT_SAMPLE)
    exact = exact_s2(stack.reshape(window, -1)[:, sample], lag)
    del stack
    check = {"batch": float(np.max(np.abs(reference["s2"].ravel()[sample] - exact)))}
    log(f"  {shape[0]}x{shape[1]}: batch recompute {batch_ms:.0f} ms")
    rows: list[Row] = []
    first = kernels[0]
    for mode in MODES:
        lead = SlidingWindow(shape, window, lag, bits=8, mode=mode, kernel=first, threads=threads)
        for j in range(window):  # fill: from here on every push adds and removes
            lead.push(pool[j % POOL])
        times = timed_pushes(lead, pool, window, window)
        maps = lead.maps()
        errors = max_errors(maps, reference)
        if mode == "sliding":
            check["engine"] = float(np.max(np.abs(maps["s2"].ravel()[sample] - exact)))
            check["bound"] = lead.s2_bound
        rows.append(_row(shape, lead, times, time_maps(lead), bandwidth, batch_ms, errors,
                         "error = model difference" if mode == "exponential" else ""))
        log(f"  {mode} {lead.kernel}: {rows[-1].ms:.2f} ms/frame")
        position = 2 * window  # next frame of the stream
        for kernel in kernels[1:]:
            other = SlidingWindow(shape, window, lag, bits=8, mode=mode, kernel=kernel,
                                  threads=threads)
            handover(lead, other)
            times = timed_pushes(other, pool, position, numpy_frames)
            timed_pushes(lead, pool, position, numpy_frames)
            position += numpy_frames
            same = all(np.array_equal(x, y) for x, y in
                       zip(lead._arrays.values(), other._arrays.values(), strict=True))
            note = f"state bit-identical to {first}: {'yes' if same else 'NO'}"
            rows.append(_row(shape, other, times, time_maps(other), bandwidth, batch_ms, None,
                             note))
            log(f"  {mode} {other.kernel}: {rows[-1].ms:.2f} ms/frame")
            del other
        if mode == "sliding" and first == "numba" and threads is None:
            single = SlidingWindow(shape, window, lag, bits=8, mode=mode, kernel="numba",
                                   threads=1)
            handover(lead, single)
            times = timed_pushes(single, pool, position, max(numpy_frames, 20))
            rows.append(_row(shape, single, times, time_maps(single), bandwidth, batch_ms,
                             None, "1 thread"))
            del single
        del lead
        gc.collect()
    return rows, check


def _row(shape: tuple[int, int], engine: SlidingWindow, times: list[float], maps_s: float,
         bandwidth: float, batch_ms: float, errors: dict[str, float] | None,
         note: str) -> Row:
    pixels = shape[0] * shape[1]
    traffic = engine.traffic_per_pixel
    return Row(shape, engine.mode, engine.kernel, min(times) * 1e3,
               statistics.median(times) * 1e3, maps_s * 1e3,
               engine.bytes_per_pixel, traffic, traffic * pixels / bandwidth * 1e3, batch_ms,
               errors, note)


def noise_study(size: int, frames: int, windows: list[int], lag: int
                ) -> list[dict[str, Any]]:
    """Spatial spread (std/mean) of each map at constant activity (τc = 20) against N."""
    from edgedsm.sim import Simulator, scene_from_dict

    scene = scene_from_dict({"scene": {"size": size, "frames": frames, "seed": 1},
                             "activity": {"tau_c": 20.0},
                             "detector": {"n_max": 1000, "bits": 8}})
    stack = np.stack(list(Simulator(scene).frames()))
    out = []
    for window in windows:
        row: dict[str, Any] = {"N": window}
        for mode in ("sliding", "exponential"):
            engine = SlidingWindow(stack.shape[1:], window, lag, bits=8, mode=mode)
            for frame in stack:
                engine.push(frame)
            for name, values in engine.maps().items():
                row[(mode, name)] = float(values.std() / values.mean())
                row[(mode, name, "mean")] = float(values.mean())
        out.append(row)
    return out


# -- report --------------------------------------------------------------------------------
def _available_bytes() -> int:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def _needed_bytes(shape: tuple[int, int], window: int) -> int:
    """Ring + batch window stack (uint8) + float64 temporaries of the batch reference."""
    return shape[0] * shape[1] * (2 * window + 250)


def run(args: argparse.Namespace) -> int:
    quick = args.quick
    window, lag = args.window, args.lag
    sizes: list[tuple[int, int]] = [(s, s) for s in (args.sizes or ([256, 512] if quick
                                                                    else [1024, 2048]))]
    if args.paper_size:
        sizes.append(PAPER_SIZE)
    numpy_frames = args.numpy_frames or (10 if quick else 30)
    kernels = ["numba", "numpy"] if importlib.util.find_spec("numba") else ["numpy"]
    def log(line: str) -> None:
        print(line, flush=True)

    load_start = load_average()
    started = time.perf_counter()
    measurements = [measure_bandwidth(128 if quick else 512)]
    rows: list[Row] = []
    tau_rows: list[dict[str, Any]] = []
    bits_rows: list[dict[str, Any]] = []
    checks: dict[tuple[int, int], dict[str, float]] = {}
    skipped = []
    for shape in sizes:
        if _needed_bytes(shape, window) > 0.8 * _available_bytes():
            skipped.append(f"{shape[1]}x{shape[0]} (needs ~{_needed_bytes(shape, window) / 2**30:.1f} "
                           f"GiB, {_available_bytes() / 2**30:.1f} GiB available)")
            continue
        # re-measured before every size: the highest seen is the (strictest) bound
        measurements.append(measure_bandwidth(128 if quick else 512))
        size_rows, checks[shape] = bench_size(shape, window, lag, kernels, numpy_frames,
                                              measurements[-1][0], args.threads, log)
        rows += size_rows
        tau_rows += bench_tau(shape, window, lag, kernels[0], args.threads, speckle_pool(shape), log)
        bits_rows += [row for bits in args.map_bits if needed_bytes(shape, window) < 0.8 * _available_bytes()
                      for row in bench_bits(shape, window, lag, bits, kernels[0], args.threads, log)]
    bandwidth, how = max(measurements, key=lambda item: item[0])
    for row in rows:
        row.bound_ms = row.traffic_bytes * row.pixels / bandwidth * 1e3
    noise_windows = [25, 50, 100, 200] if quick else [25, 50, 100, 200, 400, 800]
    noise_frames = args.noise_frames or (400 if quick else 1600)
    noise = noise_study(64 if quick else 128, noise_frames,
                        [n for n in noise_windows if n <= noise_frames], lag)
    load_end = load_average()
    elapsed = time.perf_counter() - started

    command = "edgedsm bench engine" + (" --quick" if quick else "") + \
        (" --paper-size" if args.paper_size else "")
    report = Report("Streaming engine benchmark")
    emit = report.line
    emit(report.machine(command, "numba", load=load_start, load_after=load_end)
         + f" Other work on the machine slows rows at random; {elapsed:.0f} s in all.")
    emit()
    emit(f"Measured memory bandwidth: **{bandwidth / 1e9:.1f} GB/s**, the highest of "
         f"{len(measurements)} measurements, one before each frame size ({how}; all: "
         f"{', '.join(f'{value / 1e9:.0f}' for value, _ in measurements)} GB/s). N = {window}, "
         f"m = {lag}, q = 0, 8-bit frames, all three maps. *ms/frame*: the best of the timed "
         f"pushes ({window} for the first kernel, {numpy_frames} for the others) in steady "
         f"state, their median in brackets. *moved B/px*: bytes one push must read or write "
         f"per pixel (frame, ring slots, each sum read and written); *x bandwidth bound* = "
         f"best ms/frame divided by moved bytes / best bandwidth (1.0 = memory-bound). *speed-up*: the float64 batch "
         f"recompute of all three maps from the window (`all_maps`) against one push, and "
         f"against a push followed by `maps()` (turning the sums into float maps). *max abs "
         f"error*: against that batch reference on the same window (sliding, and tumbling "
         f"whose last block is the same frames); S1 in grey levels. For the exponential mode "
         f"it is the difference between the two estimators, not a rounding error.")
    emit()
    report.extend(speed_table(rows))
    emit()
    emit(f"S2 against exact rational arithmetic on {EXACT_SAMPLE} sampled pixels of the "
         f"sliding window (max abs error): " + "; ".join(
             f"{shape[1]}x{shape[0]}: engine {c['engine']:.1e} (stated bound "
             f"{c['bound']:.1e}), float64 batch reference {c['batch']:.1e}"
             for shape, c in checks.items()) + ". The S2 differences in the table are the "
         "batch reference's own rounding.")
    if skipped:
        emit()
        emit("Skipped for lack of memory: " + "; ".join(skipped) + ".")
    target = [r for r in rows if r.size == (2048, 2048) and r.mode == "sliding"
              and r.note == "" and r.errors is not None]
    if target:
        r = target[0]
        emit()
        emit(f"Targets at 2048², N = 200, m = 10, all three maps ({r.kernel}, sliding): "
             f"speed-up against the batch recompute **{r.batch_ms / r.ms:.0f}x** per map update "
             f"(target >= 100x: {'met' if r.batch_ms / r.ms >= 100 else 'NOT met'}; with "
             f"`maps()` on every frame {r.batch_ms / (r.ms + r.maps_ms):.0f}x); time "
             f"**{r.ms / r.bound_ms:.2f}x** the memory-bandwidth bound (target <= 2x: "
             f"{'met' if r.ms / r.bound_ms <= 2 else 'NOT met'}).")
    if tau_rows:
        emit()
        emit("## Each map alone")
        emit()
        emit(f"Sliding window, {kernels[0]} kernel, q = 0, S1, S2 and S3 each alone and together, in the same run: "
             f"*x S1* is what a map costs against S1's push (S2's exact fixed-point term is read from a 256x256 "
             f"table on 8-bit data: docs/engine.md, \"S2's term\"; target S2 <= 2x S1, and the three maps <= 1.5x "
             f"their bandwidth bound).")
        emit()
        for line in tau_table(tau_rows, bandwidth, "maps"):
            emit(line)
        if bits_rows:
            emit()
            emit("The same at the deeper bit depths, q = 1 (the engines take turns push by push; `--map-bits`):")
            emit()
            report.extend(bits_table(bits_rows))
        emit()
        emit("## Correlation time τc")
        emit()
        emit(f"Sliding window, {kernels[0]} kernel, the estimators named, K lags of τc (K = 2m). "
             f"*x S1+S2+S3*: best ms/frame against the engine with the three maps only, in the same "
             f"run. *moved B/px* and *x bandwidth bound* as in the first table, for that set of estimators. "
             f"τc keeps K exact lag-product sums per pixel (int32 for 8-bit data); maps() "
             f"includes the per-pixel fit of τc.")
        emit()
        for line in tau_table(tau_rows, bandwidth):
            emit(line)
        emit()
        emit("## The field's streaming descriptors")
        emit()
        emit(f"Sliding window, {kernels[0]} kernel, each descriptor beside S1+S2+S3 (docs/descriptors.md; K "
             f"does not apply): contrast and Fujii reuse S3's and S2's sums, IM keeps one more sum, GD's "
             f"update reads the whole ring (O(N) per pixel per push: its moved bytes count the N frames).")
        emit()
        for line in tau_table(tau_rows, bandwidth, "descriptors"):
            emit(line)
    emit()
    emit("## Map noise at constant activity")
    emit()
    emit(f"Spatial spread (standard deviation / mean over the map) of S1, S2, S3 on simulated "
         f"speckle ({64 if quick else 128}² px, τc = 20 frames everywhere, N_max = 1000, 8 bit, "
         f"{noise_frames} frames, m = {lag}), after the whole stream. With one activity "
         f"everywhere, this spread is pure estimator noise: it sets the smallest activity "
         f"contrast a map of window N can show. The exponential window of the same N "
         f"averages about as many frames but weighs them unevenly.")
    emit()
    report.extend(noise_table(noise))
    if args.output:
        path = Path(args.output)
        path.parent.mkdir(parents=True, exist_ok=True)
        picture = path.with_suffix(".png")
        if plot(rows, noise, picture):
            report.lines += ["", f"![ms per frame and map noise]({picture.name})"]
            print(f"wrote {picture}")
        report.save(path)
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="256² and 512² frames, a shorter noise study (about 30 s)")
    parser.add_argument("--sizes", type=int, nargs="+", metavar="PX",
                        help="square frame sizes in pixels per side (default 1024 2048)")
    parser.add_argument("--paper-size", action="store_true",
                        help="also 4096 x 2168, the paper's camera (needs ~2 GiB)")
    parser.add_argument("--window", type=int, default=200, metavar="N",
                        help="window N in frames (default 200)")
    parser.add_argument("--lag", type=int, default=10, metavar="m",
                        help="lag m in frames (default 10)")
    parser.add_argument("--threads", type=int, metavar="T",
                        help="numba threads (default: all; a 1-thread sliding row is added)")
    parser.add_argument("--numpy-frames", type=int, metavar="n",
                        help="timed pushes of the numpy kernel (default 30; 10 with --quick)")
    parser.add_argument("--noise-frames", type=int, metavar="n",
                        help="simulated frames for the noise study (default 1600; 400 quick)")
    parser.add_argument("--map-bits", type=int, nargs="*", default=[12, 16], metavar="B",
                        help="bit depths of the 'Each map alone' rows beyond 8 (default 12 16; none: --map-bits)")
    add_output_argument(parser, "docs/bench-engine.md", extra=", and FILE.png when matplotlib is installed")
