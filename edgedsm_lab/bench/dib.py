"""Uncompressed DIB AVIs written byte by byte, as older lab capture software writes them (FFmpeg
writes only top-down ones, and no palettes): for ``edgedsm bench video`` and the tests' corpus of
hostile videos (tests/hostile_video.py: truncated files, lying headers, garbage).

``dib_avi(path, frames, bits=..., palette=..., top_down=...)`` writes a RIFF AVI whose one video
stream stores each frame as a Windows DIB (BITMAPINFOHEADER, BI_RGB): rows padded to 4 bytes,
bottom-up unless ``top_down`` (a negative height), pixels as

- 8, 4 or 1 bit: palette indices (``frames`` holds indices; ``palette`` is (n, 3) R, G, B);
- 16 bit: RGB555 (``frames`` is (count, H, W, 3) R, G, B of 0..31 each);
- 24 bit: B, G, R bytes (``frames`` is (count, H, W, 3) R, G, B).

The expected decoded image of every frame (row 0 the top row) is what ``expected`` returns.
No library writes these: the bytes are the format's, so a test can name what the pixels must be.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

GREY_PALETTE = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)


def colour_palette(size: int, seed: int = 7) -> np.ndarray:
    """A palette of ``size`` distinct R, G, B entries, not grey."""
    rng = np.random.default_rng(seed)
    palette = rng.integers(0, 256, (size, 3), dtype=np.uint8)
    palette[:, 0] = (np.arange(size) * 37 + 11) % 256  # distinct reds, never all channels equal
    palette[:, 1] = 255 - palette[:, 0]
    return palette


def _chunk(fourcc: bytes, data: bytes) -> bytes:
    return fourcc + struct.pack("<I", len(data)) + data + (b"\0" if len(data) % 2 else b"")


def _list(kind: bytes, body: bytes) -> bytes:
    return _chunk(b"LIST", kind + body)


def _row_bytes(width: int, bits: int) -> int:
    return ((width * bits + 31) // 32) * 4


def _pack_rows(frame: np.ndarray, bits: int) -> bytes:
    """One frame's pixel rows, top row first, in the DIB's pixel layout (each row padded)."""
    height, width = frame.shape[:2]
    stride = _row_bytes(width, bits)
    out = np.zeros((height, stride), np.uint8)
    if bits == 8:
        out[:, :width] = frame
    elif bits in (4, 1):
        per = 8 // bits
        padded = np.zeros((height, -(-width // per) * per), np.uint8)
        padded[:, :width] = frame
        groups = padded.reshape(height, -1, per).astype(np.uint16)
        packed = np.zeros(groups.shape[:2], np.uint16)
        for k in range(per):  # the first pixel in the byte's most significant bits
            packed |= groups[:, :, k] << (8 - bits * (k + 1))
        out[:, :packed.shape[1]] = packed.astype(np.uint8)
    elif bits == 16:
        r, g, b = (frame[:, :, i].astype(np.uint16) for i in range(3))
        value = (r << 10) | (g << 5) | b
        out[:, :2 * width] = value.astype("<u2").view(np.uint8).reshape(height, 2 * width)
    elif bits == 24:
        out[:, :3 * width] = frame[:, :, ::-1].reshape(height, 3 * width)
    else:
        raise ValueError(f"bits must be 1, 4, 8, 16 or 24, not {bits}")
    return out.tobytes()


def dib_avi(path: Path, frames: np.ndarray, bits: int = 8, palette: np.ndarray | None = None,
            top_down: bool = False, fps: int = 25, claim_frames: int | None = None,
            claim_size: tuple[int, int] | None = None, handler: bytes = b"DIB ") -> Path:
    """Write ``frames`` as an uncompressed DIB AVI (see the module docstring). ``claim_frames``
    and ``claim_size`` (width, height) put other numbers in the headers than the data has."""
    count, height, width = frames.shape[:3]
    if bits <= 8 and palette is None:
        palette = GREY_PALETTE[:: 256 // (1 << bits)][: 1 << bits] if bits < 8 else GREY_PALETTE
    colours = 0 if bits > 8 else len(palette)
    head_w, head_h = claim_size if claim_size is not None else (width, height)
    image_size = _row_bytes(width, bits) * height
    total = claim_frames if claim_frames is not None else count
    avih = struct.pack("<IIIIIIIIII16x", 1_000_000 // fps, image_size * fps, 0, 0x10, total, 0, 1,
                       image_size, head_w, head_h)
    strh = struct.pack("<4s4sIHHIIIIIIIIhhhh", b"vids", handler, 0, 0, 0, 0, 1, fps, 0, total, image_size,
                       0xFFFFFFFF, 0, 0, 0, min(head_w, 32767), min(head_h, 32767))
    shown_size = image_size if claim_size is None else 0  # BI_RGB may leave it 0; a claim's would overflow
    bmih = struct.pack("<IiiHHIIiiII", 40, head_w, -head_h if top_down else head_h, 1, bits, 0, shown_size,
                       2835, 2835, colours, colours)
    if colours:
        quads = np.zeros((colours, 4), np.uint8)
        quads[:, 0], quads[:, 1], quads[:, 2] = palette[:, 2], palette[:, 1], palette[:, 0]  # B, G, R, 0
        bmih += quads.tobytes()
    strl = _list(b"strl", _chunk(b"strh", strh) + _chunk(b"strf", bmih))
    hdrl = _list(b"hdrl", _chunk(b"avih", avih) + strl)
    movi_body, index = b"", b""
    for frame in frames:
        rows = _pack_rows(frame, bits)
        if not top_down:  # bottom-up: the last row of the image comes first
            stride = _row_bytes(width, bits)
            rows = b"".join(rows[i * stride:(i + 1) * stride] for i in reversed(range(height)))
        index += struct.pack("<4sIII", b"00db", 0x10, 4 + len(movi_body), len(rows))
        movi_body += _chunk(b"00db", rows)
    body = b"AVI " + hdrl + _list(b"movi", movi_body) + _chunk(b"idx1", index)
    path.write_bytes(b"RIFF" + struct.pack("<I", len(body)) + body)
    return path


def expected(frames: np.ndarray, bits: int, palette: np.ndarray | None = None) -> np.ndarray:
    """What the frames written by ``dib_avi`` look like: (count, H, W, 3) R, G, B, row 0 on top
    (palette entries looked up; RGB555 as FFmpeg widens 5 bits to 8: v << 3 | v >> 2)."""
    if bits <= 8:
        if palette is None:
            palette = GREY_PALETTE[:: 256 // (1 << bits)][: 1 << bits] if bits < 8 else GREY_PALETTE
        return palette[frames]
    if bits == 16:
        wide = frames.astype(np.uint16)
        return ((wide << 3) | (wide >> 2)).astype(np.uint8)
    return frames


def indices(count: int, height: int, width: int, bits: int, seed: int = 0) -> np.ndarray:
    """Random palette indices with a marked top-left corner (orientation shows)."""
    rng = np.random.default_rng(seed)
    top = (1 << bits) - 1
    frames = rng.integers(0, top + 1, (count, height, width), dtype=np.uint8)
    frames[:, 0, 0], frames[:, -1, -1] = top, 0
    return frames


def colours(count: int, height: int, width: int, top: int = 255, seed: int = 0) -> np.ndarray:
    """Random R, G, B frames (0..top each), every frame different."""
    return np.random.default_rng(seed).integers(0, top + 1, (count, height, width, 3), dtype=np.uint8)
