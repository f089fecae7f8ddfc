"""The corpus of hostile and odd videos (issue 34): DIB AVIs as older capture software writes
them (edgedsm_lab.bench.dib writes them byte by byte) and files built to break a reader.

``hostile_avis(folder)`` writes each hostile file and returns {case: path}; every one must be
refused by every entry point with one line and exit 65, never a signal or a traceback.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from edgedsm_lab.bench.dib import GREY_PALETTE, colour_palette, colours, dib_avi, expected, indices

__all__ = ["GREY_PALETTE", "colour_palette", "colours", "dib_avi", "expected", "hostile_avis", "indices"]


def cut_ffv1(folder: Path, count: int = 40) -> Path:
    """An FFV1 AVI of ``count`` 48x64 grey frames written by FFmpeg (PyAV's muxer), cut at 60 %:
    its first frames decode, the cut shows only when the reader gets there."""
    import av

    frames = indices(count, 48, 64, 8, seed=3)
    whole = folder / "ffv1-whole.avi"
    with av.open(str(whole), "w") as container:
        stream = container.add_stream("ffv1", rate=25)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "gray"
        for image in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="gray")))
        container.mux(stream.encode(None))
    cut = folder / "ffv1-cut.avi"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 6 // 10])
    whole.unlink()
    return cut


def hostile_avis(folder: Path) -> dict[str, Path]:
    """Hostile AVIs in ``folder``: {what is wrong with it: its path}."""
    frames = indices(40, 48, 64, 8)
    data = dib_avi(folder / "good.avi", frames, 8).read_bytes()
    (folder / "good.avi").unlink()
    files = {"empty": b"", "garbage": np.random.default_rng(1).integers(0, 256, 5000, np.uint8).tobytes(),
             "riff only": data[:12], "headers only": data[:data.index(b"movi") + 4],
             "cut in the frames": data[: len(data) * 6 // 10], "cut in a frame": data[: len(data) // 2 + 777]}
    paths = {}
    for name, content in files.items():
        paths[name] = folder / f"{name.replace(' ', '-')}.avi"
        paths[name].write_bytes(content)
    small = indices(3, 7, 13, 8)
    paths["2^31 frames"] = dib_avi(folder / "many.avi", small, 8, claim_frames=2 ** 31)
    paths["100000x100000"] = dib_avi(folder / "huge.avi", small, 8, claim_size=(100_000, 100_000))
    paths["16000x16000"] = dib_avi(folder / "big.avi", np.repeat(small[..., None], 3, axis=3), 24,
                                   claim_size=(16_000, 16_000))
    paths["45000x4"] = dib_avi(folder / "wide.avi", small, 8, claim_size=(45_000, 4))
    paths["45000x4, no count"] = dib_avi(folder / "wide-uncounted.avi", small, 8, claim_size=(45_000, 4),
                                         claim_frames=0)
    paths["FFV1 cut in the frames"] = cut_ffv1(folder)
    return paths
