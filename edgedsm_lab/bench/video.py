"""Video decoders side by side: PyAV against OpenCV's FFmpeg backend, on the videos labs record.

Speckle frames (uniform random grey levels, every frame different) are written as

  raw grey 8-bit AVI   an uncompressed bottom-up 8-bit DIB with a grey palette, what older capture
                       software writes (edgedsm_lab.bench.dib; FFmpeg writes only top-down DIBs)

and with PyAV's muxer as

  FFV1 gray16le MKV    (lossless 16-bit grey: a 12-bit camera's frames, values 0..4095)
  MJPG AVI             (lossy, yuvj420p)
  H.264 MP4            (lossy, yuv420p, libx264 at its default quality)

and each file is decoded, in a child process of its own (a decoder that aborts takes only that
child), by

  OpenCV (BGR)           ``cv2.VideoCapture`` as it comes: B, G, R of 8 bits, channel 0 kept
  OpenCV (unconverted)   ``CAP_PROP_CONVERT_RGB = 0``, how edgedsm's reader opened every video
                         until issue 34 (it kept 16-bit grey, and aborted on DIB AVIs)
  PyAV                   ``frame.to_ndarray(format="gray" | "gray16le")``: the format asked for
  edgedsm (PyAV)         ``edgedsm.frameio.open_frames``: the reader as analyze and replay use it

The table gives frames/s (one run each, the decode of the whole file: on a shared machine the
ratios mean more than the absolute rates), the ratio to OpenCV (BGR), the dtype, and whether
the frames came back exact: for the lossless files every value equal; for the lossy ones the
mean absolute error against what was written (what any decoder of them gives), "no" where the
values differ from the lossless source in kind (16 bits cut to 8).

Example:
  edgedsm bench video --size 512 --frames 300 --output docs/bench-video.md
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from edgedsm_lab.bench.dib import dib_avi
from edgedsm_lab.bench.report import Report, add_output_argument, cpu_sample, load_average, machine_use, others_share

HELP = "video decoders: PyAV against OpenCV on raw, FFV1 16-bit, MJPG and H.264 (frames/s, exactness)"
#: name: (file, codec, pixel format the encoder stores, what the source array is)
FORMATS = {
    "raw grey 8-bit AVI": ("raw8.avi", "dib", "pal8", "gray"),
    "FFV1 gray16le MKV": ("ffv1-16.mkv", "ffv1", "gray16le", "gray16le"),
    "MJPG AVI": ("mjpg.avi", "mjpeg", "yuvj420p", "gray"),
    "H.264 MP4": ("h264.mp4", "libx264", "yuv420p", "gray"),
}
DECODERS = ("OpenCV (BGR)", "OpenCV (unconverted)", "PyAV", "edgedsm (PyAV)")
CHILD_TIMEOUT_S = 600.0


def speckle(count: int, size: int, deep: bool, seed: int = 0) -> np.ndarray:
    """``count`` frames of ``size``² uniform random grey levels (0..4095 in uint16 when ``deep``)."""
    rng = np.random.default_rng(seed)
    if deep:
        return rng.integers(0, 4096, (count, size, size), dtype=np.uint16)
    return rng.integers(0, 256, (count, size, size), dtype=np.uint8)


def write_video(path: Path, frames: np.ndarray, codec: str, pix_fmt: str, source: str, rate: int = 25) -> Path:
    """Write ``frames`` with PyAV's muxer (FFmpeg's encoders)."""
    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=rate)
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], pix_fmt
        for image in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format=source)))
        container.mux(stream.encode(None))
    return path


# -- the child: one decoder on one file ------------------------------------------------------------

def _opencv(path: Path, unconverted: bool) -> tuple[list[np.ndarray], float]:
    import cv2

    started = time.perf_counter()
    params = [cv2.CAP_PROP_CONVERT_RGB, 0] if unconverted else []
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, params)
    frames = []
    while True:
        ok, image = capture.read()
        if not ok:
            break
        frames.append(image[:, :, 0] if image.ndim == 3 else image)
    capture.release()
    return frames, time.perf_counter() - started


def _pyav(path: Path) -> tuple[list[np.ndarray], float]:
    import av

    started = time.perf_counter()
    frames = []
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        for frame in container.decode(stream):
            deep = max(part.bits for part in frame.format.components) > 8
            frames.append(frame.to_ndarray(format="gray16le" if deep else "gray"))
    return frames, time.perf_counter() - started


def _edgedsm(path: Path) -> tuple[list[np.ndarray], float]:
    from edgedsm.frameio import open_frames

    started = time.perf_counter()
    with open_frames(path, "luma") as reader:
        frames = list(reader.frames())
    return frames, time.perf_counter() - started


def child(decoder: str, path: str, source: str) -> None:
    """Decode ``path`` with ``decoder``; print one JSON line: frames/s, dtype and the error
    against the frames in ``source`` (.npy)."""
    run = {"OpenCV (BGR)": lambda p: _opencv(p, False), "OpenCV (unconverted)": lambda p: _opencv(p, True),
           "PyAV": _pyav, "edgedsm (PyAV)": _edgedsm}[decoder]
    frames, seconds = run(Path(path))
    want = np.load(source, mmap_mode="r")
    got = np.stack(frames) if frames else np.zeros((0,), np.uint8)
    result: dict[str, object] = {"frames": len(frames), "seconds": seconds, "dtype": str(got.dtype)}
    if got.shape == want.shape:
        error = np.abs(got.astype(np.int64) - want.astype(np.int64))
        result.update(exact=bool(error.max() == 0), mae=float(error.mean()))
    else:
        result.update(exact=False, mae=None, shape=list(got.shape))
    print(json.dumps(result))


def measure_one(decoder: str, path: Path, source: Path) -> dict[str, object]:
    """Run ``child`` in a process of its own; its result, or how it died."""
    env = {**os.environ, "OPENCV_FFMPEG_LOGLEVEL": "-8", "OPENCV_LOG_LEVEL": "ERROR"}
    try:
        done = subprocess.run([sys.executable, "-m", "edgedsm_lab.bench.video", "--child", decoder, str(path),
                               str(source)], capture_output=True, text=True, timeout=CHILD_TIMEOUT_S, env=env)
    except subprocess.TimeoutExpired:
        return {"died": f"no result in {CHILD_TIMEOUT_S:g} s"}
    if done.returncode < 0:
        return {"died": signal.Signals(-done.returncode).name}
    if done.returncode != 0 or not done.stdout.strip():
        return {"died": f"exit {done.returncode}: {done.stderr.strip().splitlines()[-1:] or ''}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


# -- the report ------------------------------------------------------------------------------------

def _exactness(result: dict[str, object], lossless: bool) -> str:
    if "died" in result:
        return "—"
    if result.get("mae") is None:
        return f"no (shape {result.get('shape')})"
    if result["exact"]:
        return "bit-exact"
    if lossless:
        return f"no (mean error {result['mae']:.3g})"
    return f"mean error {result['mae']:.3g}"


def rows_for(name: str, results: dict[str, dict[str, object]], count: int) -> list[list[str]]:
    base = results["OpenCV (BGR)"]
    base_fps = base["frames"] / base["seconds"] if "died" not in base and base.get("seconds") else None
    lossless = FORMATS[name][1] in ("dib", "ffv1")
    rows = []
    for decoder in DECODERS:
        result = results[decoder]
        if "died" in result:
            rows.append([name, decoder, f"died: {result['died']}", "—", "—", "—"])
            continue
        fps = result["frames"] / result["seconds"]
        ratio = f"{fps / base_fps:.2f}" if base_fps else "—"
        frames = f"{result['frames']}" + ("" if result["frames"] == count else f" of {count}")
        rows.append([name, decoder, f"{fps:.0f} ({frames} frames)", ratio, str(result["dtype"]),
                     _exactness(result, lossless)])
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--size", type=int, default=512, metavar="PX", help="frame size, square (512)")
    parser.add_argument("--frames", type=int, default=300, metavar="N", help="frames per video (300)")
    add_output_argument(parser, "docs/bench-video.md")


def run(args: argparse.Namespace) -> int:
    import av
    import cv2

    load = load_average()
    before = cpu_sample()
    table: list[list[str]] = []
    with tempfile.TemporaryDirectory(prefix="edgedsm-bench-video-") as tmp:
        folder = Path(tmp)
        for name, (file, codec, pix_fmt, source) in FORMATS.items():
            frames = speckle(args.frames, args.size, deep=source == "gray16le")
            np.save(folder / f"{file}.npy", frames)
            path = (dib_avi(folder / file, frames, 8) if codec == "dib"
                    else write_video(folder / file, frames, codec, pix_fmt, source))
            print(f"{name}: {path.stat().st_size / 1e6:.1f} MB", file=sys.stderr)
            results = {decoder: measure_one(decoder, path, folder / f"{file}.npy") for decoder in DECODERS}
            table += rows_for(name, results, args.frames)
    others = others_share(before, cpu_sample())
    report = Report("Video decoders: PyAV against OpenCV")
    report.line(report.machine("edgedsm bench video", "av", "cv2", load=load)
                + f" PyAV {av.__version__} (FFmpeg {av.ffmpeg_version_info}"
                  f" bundled), OpenCV {cv2.__version__}. {machine_use(others, load)}")
    report.line()
    report.line(f"{args.size}x{args.size} speckle, {args.frames} frames per video (the raw AVI a bottom-up "
                f"8-bit DIB with a grey palette, the others written with PyAV's muxer); "
                f"each decoder in a process of its own, one run, decoding the whole file (frames/s; "
                f"the ratio to OpenCV's default decode). Exactness against the frames written: "
                f"lossless files must come back bit-exact.")
    report.line()
    report.table(["video", "decoder", "frames/s", "× OpenCV", "dtype", "exact"], table, align="llrrll")
    report.line()
    if args.output:
        report.save(args.output)
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--child":
        child(sys.argv[2], sys.argv[3], sys.argv[4])
    else:
        raise SystemExit("usage: edgedsm bench video [--size PX] [--frames N] [--output FILE.md]")
