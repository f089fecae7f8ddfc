"""Measure the lossless TIFF codecs a recording could use, on simulated speckle: compression
ratio, and MB/s of writing (compress + write) and reading (read + decompress) on one core.

Writes each candidate as edgedsm records (BigTIFF, one page per frame, appended page by page,
per-page description) into a temporary folder, so the numbers include tifffile's own work.
Prints a markdown table (docs/recording.md quotes one run). Usage:

    PYTHONPATH=$PWD python scripts/recording_codecs.py [--size 512] [--frames 60]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile

from edgedsm.sim import Simulator, scene_from_dict

CANDIDATES = [("none", None, {}), ("zstd", "zstd", {"level": 1}), ("zstd", "zstd", {"level": 3}),
              ("zstd", "zstd", {"level": 9}), ("deflate", "zlib", {"level": 6}),
              ("deflate", "zlib", {"level": 1}), ("lzw", "lzw", {})]


def speckle(size: int, frames: int, bits: int) -> np.ndarray:
    """Simulated speckle (the logo scene's activity, detector at ``bits``), as a camera gives it."""
    scene = scene_from_dict({"scene": {"size": size, "frames": frames, "seed": 1, "speckle_size": 2.0},
                             "activity": {"tau_c": 20.0}, "detector": {"n_max": 1000 if bits == 8 else 4 * 2**bits,
                                                                        "bits": bits}})
    return np.stack(list(Simulator(scene).frames(frames)))


def measure(stack: np.ndarray, codec: str | None, args: dict, folder: Path) -> tuple[float, float, float]:
    """(ratio, write MB/s, read MB/s) of one codec on one stack."""
    path = folder / "rec.tif"
    started = time.perf_counter()
    with open(path, "wb", buffering=0) as handle, tifffile.TiffWriter(handle, bigtiff=True) as writer:
        for seq, frame in enumerate(stack):
            writer.write(frame, description=json.dumps({"seq": seq, "t_ns": seq}), metadata=None,
                         compression=codec, compressionargs=args, contiguous=False)
    written = time.perf_counter() - started
    started = time.perf_counter()
    with tifffile.TiffFile(path) as tif:
        for page in tif.pages:
            page.asarray()
    read = time.perf_counter() - started
    megabytes = stack.nbytes / 1e6
    return stack.nbytes / path.stat().st_size, megabytes / written, megabytes / read


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()
    print(f"| bits | codec | ratio | write MB/s | read MB/s |  ({args.frames} frames of {args.size}², one core)")
    print("|---:|---|---:|---:|---:|")
    for bits in (8, 12, 16):
        stack = speckle(args.size, args.frames, bits)
        with tempfile.TemporaryDirectory() as tmp:
            for name, codec, extra in CANDIDATES:
                ratio, write, read = measure(stack, codec, extra, Path(tmp))
                label = f"{name} {extra.get('level', '')}".strip()
                print(f"| {bits} ({stack.dtype}) | {label} | {ratio:.2f} | {write:.0f} | {read:.0f} |")


if __name__ == "__main__":
    main()
