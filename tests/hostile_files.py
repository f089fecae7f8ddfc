"""Hostile non-video files written byte by byte: the corpus of issue 34's file part (the video
part is tests/hostile_video.py).

Each case is a function ``case(directory) -> Path`` that writes one input (a file or an image
folder) and returns the path a user would give (``analyze PATH``, ``replay:PATH``). ``CASES`` maps
a name to (function, exit code a refusal must have, a fragment the one-line message contains).
Headers that lie (a 6-byte TIFF, an .npy claiming 2^40 pixels, a 1 KB deflate TIFF claiming
45000 x 45000, a PNG or BMP claiming 2^32 pixels) are written directly: no library writes a lie, and
nothing here allocates what the header claims. ``mask_cases`` are the image files a region
mask may name.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from edgedsm_lab.bench import peak
from edgedsm_lab.bench.peak import Measured

# -- .npy ------------------------------------------------------------------------------------


def npy_bytes(descr: str, shape: tuple[int, ...], data: bytes = b"", fortran: bool = False,
              header: str | None = None) -> bytes:
    """A version-1.0 .npy file with any header, lies included, followed by ``data``."""
    text = header if header is not None else (
        f"{{'descr': {descr!r}, 'fortran_order': {fortran}, 'shape': {shape!r}, }}")
    text += " " * ((64 - (10 + len(text) + 1) % 64) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text.encode("latin1") + data


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def npy_empty(d: Path) -> Path:
    return _write(d / "empty.npy", b"")


def npy_garbage(d: Path) -> Path:
    return _write(d / "garbage.npy", bytes(range(256)) * 4)


def npy_magic_only(d: Path) -> Path:
    return _write(d / "magic.npy", b"\x93NUMPY\x01\x00")


def npy_header_not_a_dict(d: Path) -> Path:
    return _write(d / "notdict.npy", npy_bytes("", (), header="__import__('os').system('true')"))


def npy_huge_shape(d: Path) -> Path:
    return _write(d / "huge.npy", npy_bytes("|u1", (10, 2 ** 20, 2 ** 20), b"\0" * 4096))


def npy_huge_count(d: Path) -> Path:
    return _write(d / "count.npy", npy_bytes("|u1", (2 ** 40, 8, 8), b"\0" * 4096))


def npy_negative_shape(d: Path) -> Path:
    return _write(d / "negative.npy", npy_bytes("|u1", (4, -8, 8), b"\0" * 256))


def npy_zero_width(d: Path) -> Path:
    return _write(d / "zerowidth.npy", npy_bytes("|u1", (4, 8, 0)))


def npy_zero_frames(d: Path) -> Path:
    return _write(d / "zeroframes.npy", npy_bytes("|u1", (0, 8, 8)))


def npy_pickled_objects(d: Path) -> Path:
    payload = np.empty(3, dtype=object)
    payload[:] = [1, "two", None]
    path = d / "pickle.npy"
    np.save(path, payload, allow_pickle=True)
    return path


def npy_structured(d: Path) -> Path:
    path = d / "structured.npy"
    np.save(path, np.zeros((3, 4, 4), dtype=[("a", "<u2"), ("b", "<f4")]))
    return path


def npy_fortran(d: Path) -> Path:
    path = d / "fortran.npy"
    np.save(path, np.asfortranarray(np.arange(3 * 4 * 5, dtype=np.uint8).reshape(3, 4, 5)))
    return path


def npy_truncated(d: Path) -> Path:
    return _write(d / "truncated.npy", npy_bytes("|u1", (100, 16, 16), b"\7" * (10 * 256 + 5)))


def npy_complex(d: Path) -> Path:
    path = d / "complex.npy"
    np.save(path, np.zeros((3, 4, 4), np.complex64))
    return path


def npy_two_d(d: Path) -> Path:
    path = d / "flat.npy"
    np.save(path, np.zeros((4, 4), np.uint8))
    return path


# -- TIFF --------------------------------------------------------------------------------------

#: TIFF tag numbers used below.
WIDTH, LENGTH, BITS, COMPRESSION, PHOTOMETRIC, STRIP_OFFSETS, SAMPLES, ROWS_PER_STRIP, STRIP_COUNTS = \
    256, 257, 258, 259, 262, 273, 277, 278, 279
TILE_WIDTH, TILE_LENGTH, TILE_OFFSETS, TILE_COUNTS = 322, 323, 324, 325


def tiff_bytes(width: int, length: int, data: bytes, *, compression: int = 1, bits: int = 8,
               tile: tuple[int, int] | None = None) -> bytes:
    """A one-page little-endian classic TIFF whose tags claim ``width`` x ``length`` pixels
    (whatever ``data`` really holds), in one strip or one tile."""
    data_offset = 8
    entries: list[tuple[int, int, int, int]] = [  # tag, type (3 short, 4 long), count, value
        (WIDTH, 4, 1, width), (LENGTH, 4, 1, length), (BITS, 3, 1, bits), (COMPRESSION, 3, 1, compression),
        (PHOTOMETRIC, 3, 1, 1), (SAMPLES, 3, 1, 1)]
    if tile is None:
        entries += [(STRIP_OFFSETS, 4, 1, data_offset), (ROWS_PER_STRIP, 4, 1, length),
                    (STRIP_COUNTS, 4, 1, len(data))]
    else:
        entries += [(TILE_WIDTH, 4, 1, tile[1]), (TILE_LENGTH, 4, 1, tile[0]),
                    (TILE_OFFSETS, 4, 1, data_offset), (TILE_COUNTS, 4, 1, len(data))]
    entries.sort()
    body = data + b"\0" * (len(data) % 2)
    ifd_offset = data_offset + len(body)
    ifd = struct.pack("<H", len(entries))
    for tag, kind, count, value in entries:
        packed = struct.pack("<HI", value, 0)[:4] if kind == 3 else struct.pack("<I", value & 0xFFFFFFFF)
        ifd += struct.pack("<HHI", tag, kind, count) + packed
    ifd += struct.pack("<I", 0)
    return b"II*\x00" + struct.pack("<I", ifd_offset) + body + ifd


def tiff_six_bytes(d: Path) -> Path:
    return _write(d / "six.tif", b"II*\x00\x08\x00")


def tiff_empty(d: Path) -> Path:
    return _write(d / "empty.tif", b"")


def tiff_garbage(d: Path) -> Path:
    return _write(d / "garbage.tiff", b"not a tiff at all " * 50)


def tiff_bad_ifd_offset(d: Path) -> Path:
    return _write(d / "ifd.tif", b"II*\x00" + struct.pack("<I", 2 ** 31) + b"\0" * 64)


def tiff_deflate_bomb(d: Path) -> Path:
    """45000 x 45000 zeros claimed, deflate-compressed: the real bomb's header (the real file is
    1.9 MB; the refusal must come from the tags, so a few KB of deflate stream do)."""
    stream = zlib.compressobj(9).compress(b"\0" * 2 ** 20)
    return _write(d / "bomb.tif", tiff_bytes(45000, 45000, stream, compression=8))


def tiff_zero_width(d: Path) -> Path:
    return _write(d / "zerowidth.tif", tiff_bytes(0, 16, b"\0" * 16))


def tiff_huge_tile(d: Path) -> Path:
    return _write(d / "tile.tif", tiff_bytes(64, 64, zlib.compress(b"\0" * 4096), compression=8,
                                             tile=(2 ** 16 - 16, 2 ** 16 - 16)))


def tiff_truncated_strip(d: Path) -> Path:
    """A 64 x 64 page whose strip is cut: 100 bytes of the 4096 its byte count claims."""
    data = tiff_bytes(64, 64, b"\5" * 4096)
    return _write(d / "cut.tif", data[:8 + 100])  # the IFD (after the strip) is cut off too


def tiff_strip_beyond_end(d: Path) -> Path:
    """The strip's byte count claims 4096 bytes where the file holds 100."""
    data = bytearray(tiff_bytes(64, 64, b"\5" * 100))
    at = data.index(struct.pack("<HHII", STRIP_COUNTS, 4, 1, 100))
    data[at:at + 12] = struct.pack("<HHII", STRIP_COUNTS, 4, 1, 4096)
    return _write(d / "beyond.tif", bytes(data))


# -- image folders -----------------------------------------------------------------------------

def png_bytes(width: int, height: int, depth: int = 8, colour: int = 0, idat: bytes = b"") -> bytes:
    """A PNG whose IHDR claims ``width`` x ``height`` (chunks with valid CRCs)."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat or zlib.compress(b"\0" * 64)) \
        + chunk(b"IEND", b"")


def bmp_bytes(width: int, height: int, bits: int = 24) -> bytes:
    """A BMP whose BITMAPINFOHEADER claims ``width`` x ``height`` (negative: top-down), no pixels."""
    info = struct.pack("<IiiHHIIiiII", 40, width, height, 1, bits, 0, 0, 2835, 2835, 0, 0)
    return b"BM" + struct.pack("<IHHI", 14 + len(info), 0, 0, 14 + len(info)) + info


def _folder(d: Path, name: str, files: dict[str, bytes]) -> Path:
    folder = d / name
    folder.mkdir()
    for file, data in files.items():
        (folder / file).write_bytes(data)
    return folder


def _good_png() -> bytes:
    raw = b"".join(b"\0" + bytes(range(16)) for _ in range(16))  # 16 x 16 grey, filter byte 0
    return png_bytes(16, 16, idat=zlib.compress(raw))


def folder_png_huge(d: Path) -> Path:
    return _folder(d, "pnghuge", {"f_000.png": png_bytes(2 ** 16, 2 ** 16)})


def folder_png_huge_second(d: Path) -> Path:
    return _folder(d, "pnghuge2", {"f_000.png": _good_png(), "f_001.png": png_bytes(40000, 40000, 16, 6)})


def folder_bmp_huge(d: Path) -> Path:
    return _folder(d, "bmphuge", {"f_000.bmp": bmp_bytes(50000, -50000)})


def folder_png_zero(d: Path) -> Path:
    return _folder(d, "pngzero", {"f_000.png": png_bytes(0, 16)})


def folder_png_garbage(d: Path) -> Path:
    return _folder(d, "garbage", {"f_000.png": b"\x89PNG\r\n\x1a\n" + b"\xff" * 40})


def folder_empty_png(d: Path) -> Path:
    return _folder(d, "emptypng", {"f_000.png": b""})


def folder_tiff_six_bytes(d: Path) -> Path:
    return _folder(d, "tiny", {"f_000.tif": b"II*\x00\x08\x00"})


def _cut_image(d: Path, suffix: str) -> Path:
    """A folder of two 64 x 64 images written by OpenCV, the first cut in half (a copy that stopped)."""
    import cv2

    folder = d / f"cut_{suffix}"
    folder.mkdir()
    image = np.random.default_rng(3).integers(0, 256, (64, 64), dtype=np.uint8)
    for index in range(2):
        assert cv2.imwrite(str(folder / f"f_{index:03d}.{suffix}"), image)
    first = folder / f"f_000.{suffix}"
    first.write_bytes(first.read_bytes()[: first.stat().st_size // 2])
    return folder


def folder_cut_png(d: Path) -> Path:
    return _cut_image(d, "png")


def folder_cut_jpg(d: Path) -> Path:
    return _cut_image(d, "jpg")


def folder_cut_bmp(d: Path) -> Path:
    return _cut_image(d, "bmp")


def folder_cut_pgm(d: Path) -> Path:
    return _cut_image(d, "pgm")


def folder_cut_tif(d: Path) -> Path:
    return _cut_image(d, "tif")


def folder_no_images(d: Path) -> Path:
    return _folder(d, "nothing", {"readme.txt": b"no frames here"})


def missing(d: Path) -> Path:
    return d / "no-such-file.npy"


#: name -> (writer, exit code, a fragment of the message); every case is refused.
CASES: dict[str, tuple[Callable[[Path], Path], int, str]] = {
    "npy_empty": (npy_empty, 65, "not a valid .npy"),
    "npy_garbage": (npy_garbage, 65, "not a valid .npy"),
    "npy_magic_only": (npy_magic_only, 65, "not a valid .npy"),
    "npy_header_not_a_dict": (npy_header_not_a_dict, 65, "not a valid .npy"),
    "npy_huge_shape": (npy_huge_shape, 65, "1,099,511,627,776 pixels"),
    "npy_huge_count": (npy_huge_count, 65, "truncated"),
    "npy_negative_shape": (npy_negative_shape, 65, "not a frame size"),
    "npy_zero_width": (npy_zero_width, 65, "not a frame size"),
    "npy_zero_frames": (npy_zero_frames, 65, "claims 0 frames"),
    "npy_pickled_objects": (npy_pickled_objects, 65, "pickled"),
    "npy_structured": (npy_structured, 65, "structured"),
    "npy_fortran": (npy_fortran, 65, "Fortran order"),
    "npy_truncated": (npy_truncated, 65, "truncated"),
    "npy_complex": (npy_complex, 65, "not grey levels"),
    "npy_two_d": (npy_two_d, 65, "expected a (N, H, W) stack"),
    "tiff_six_bytes": (tiff_six_bytes, 65, "TIFF"),
    "tiff_empty": (tiff_empty, 65, "TIFF"),
    "tiff_garbage": (tiff_garbage, 65, "TIFF"),
    "tiff_bad_ifd_offset": (tiff_bad_ifd_offset, 65, "TIFF"),
    "tiff_deflate_bomb": (tiff_deflate_bomb, 65, "2,025,000,000 pixels"),
    "tiff_zero_width": (tiff_zero_width, 65, "TIFF"),
    "tiff_huge_tile": (tiff_huge_tile, 65, "tiles"),
    "tiff_truncated_strip": (tiff_truncated_strip, 65, "TIFF"),
    "tiff_strip_beyond_end": (tiff_strip_beyond_end, 65, "page 0"),
    "folder_png_huge": (folder_png_huge, 65, "4,294,967,296 pixels"),
    "folder_png_huge_second": (folder_png_huge_second, 65, "1,600,000,000 pixels"),
    "folder_bmp_huge": (folder_bmp_huge, 65, "2,500,000,000 pixels"),
    "folder_png_zero": (folder_png_zero, 65, "not a frame size"),
    "folder_png_garbage": (folder_png_garbage, 65, "f_000.png"),
    "folder_empty_png": (folder_empty_png, 65, "cannot be read as an image"),
    "folder_tiff_six_bytes": (folder_tiff_six_bytes, 65, "cannot be read as an image"),
    "folder_cut_png": (folder_cut_png, 65, "f_000.png: cannot be read as an image"),
    "folder_cut_jpg": (folder_cut_jpg, 65, "f_000.jpg: cannot be read as an image"),
    "folder_cut_bmp": (folder_cut_bmp, 65, "f_000.bmp: cannot be read as an image"),
    "folder_cut_pgm": (folder_cut_pgm, 65, "f_000.pgm: cannot be read as an image"),
    "folder_cut_tif": (folder_cut_tif, 65, "f_000.tif: cannot be read as an image"),
    "folder_no_images": (folder_no_images, 65, "no images"),
    "missing": (missing, 66, "no such file"),
}


def mask_cases(d: Path) -> dict[str, Path]:
    """Region-mask images: a PNG and a BMP claiming more than 2^30 pixels, an empty file, garbage."""
    made = {"png_huge": png_bytes(2 ** 16, 2 ** 15), "bmp_huge": bmp_bytes(40000, 40000),
            "empty": b"", "garbage": b"\x89PNG\r\n\x1a\n" + b"\xff" * 40}
    paths = {}
    for name, data in made.items():
        paths[name] = d / f"mask_{name}.{'bmp' if 'bmp' in name else 'png'}"
        paths[name].write_bytes(data)
    return paths


# -- measuring a refusal -----------------------------------------------------------------------

def measure(command: list[str], timeout: float = 60.0, **popen: Any) -> Measured:
    """Run ``command`` (its first item an absolute path): its exit, output and its own peak RSS,
    not the test process's (:func:`edgedsm_lab.bench.peak.measure`); a timeout fails the test."""
    try:
        return peak.measure(command, timeout, **popen)
    except TimeoutError as exc:
        raise AssertionError(str(exc)) from None


def run_measured(command: list[str], timeout: float = 60.0, **popen: Any) -> tuple[int, str, float]:
    """Run ``command`` (its first item an absolute path): (its exit code, negative for a signal
    as Popen gives it; its stderr; its own peak RSS in MiB). Killed, with its session, at the timeout."""
    done = measure(command, timeout, **popen)
    return done.code, done.err, done.rss / 2 ** 20
