"""Decoding of raw camera buffers into 2-D monochrome arrays (pure numpy, no device needed).

GenICam pixel formats handled (PFNC codes, also used by GigE Vision / USB3 Vision):

=============  ==========  ====  ===========================================================
name           code        bits  layout
=============  ==========  ====  ===========================================================
Mono8          0x01080001   8    one byte per pixel
Mono10         0x01100003  10    little-endian uint16 per pixel, LSB-aligned
Mono12         0x01100005  12    little-endian uint16 per pixel, LSB-aligned
Mono14         0x01100025  14    little-endian uint16 per pixel, LSB-aligned
Mono16         0x01100007  16    little-endian uint16 per pixel
Mono12Packed   0x010C0006  12    GigE Vision legacy packing, 2 pixels in 3 bytes (below)
Mono12p        0x010C0047  12    PFNC LSB-first bit stream, 2 pixels in 3 bytes (below)
=============  ==========  ====  ===========================================================

The two packed 12-bit formats put the same two pixels A and B into three bytes B0 B1 B2 but
with different bit layouts (a camera that sends one and a decoder that assumes the other
gives plausible-looking but wrong images, hence the tests with hand-made bytes)::

    Mono12Packed:  B0 = A[11:4]            Mono12p:  B0 = A[7:0]
                   B1 = B[3:0] << 4 | A[3:0]          B1 = B[3:0] << 4 | A[11:8]
                   B2 = B[11:4]                       B2 = B[11:4]

Lines are packed back to back (an odd width lets a pixel pair straddle two lines) unless the
camera reports line padding, in which case every line starts on a fresh byte.
"""

from __future__ import annotations

import numpy as np

from edgedsm.errors import DeviceError

#: PFNC pixel format codes of the monochrome formats edgedsm measures with.
PIXEL_FORMAT_CODES: dict[int, str] = {
    0x01080001: "Mono8",
    0x01100003: "Mono10",
    0x01100005: "Mono12",
    0x01100025: "Mono14",
    0x01100007: "Mono16",
    0x010C0006: "Mono12Packed",
    0x010C0047: "Mono12p",
}

#: Bytes per pixel of the unpacked formats.
_UNPACKED_BYTES = {"Mono8": 1, "Mono10": 2, "Mono12": 2, "Mono14": 2, "Mono16": 2}
_PACKED12 = ("Mono12Packed", "Mono12p")


def packed12_size(pixels: int) -> int:
    """Bytes that ``pixels`` 12-bit pixels occupy when packed (1.5 bytes each, rounded up)."""
    return (3 * pixels + 1) // 2


def unpack_mono12_packed(data: bytes | np.ndarray, count: int) -> np.ndarray:
    """Unpack ``count`` pixels of GigE Vision Mono12Packed into uint16 (see module docstring)."""
    return _unpack12(_groups(data, count, "Mono12Packed"), "Mono12Packed").reshape(-1)[:count]


def unpack_mono12p(data: bytes | np.ndarray, count: int) -> np.ndarray:
    """Unpack ``count`` pixels of PFNC Mono12p (LSB-first bit stream) into uint16."""
    return _unpack12(_groups(data, count, "Mono12p"), "Mono12p").reshape(-1)[:count]


def _unpack12(groups: np.ndarray, pixel_format: str) -> np.ndarray:
    """Byte triples (..., 3) to pixel pairs (..., 2) as uint16, in either 12-bit layout."""
    b0, b1, b2 = (groups[..., i].astype(np.uint16) for i in range(3))
    out = np.empty((*groups.shape[:-1], 2), dtype=np.uint16)
    if pixel_format == "Mono12Packed":
        out[..., 0] = (b0 << 4) | (b1 & 0x0F)
    else:
        out[..., 0] = b0 | ((b1 & 0x0F) << 8)
    out[..., 1] = (b2 << 4) | (b1 >> 4)  # the second pixel is laid out alike in both
    return out


def _as_bytes(data: bytes | np.ndarray) -> np.ndarray:
    if isinstance(data, np.ndarray):
        return data.reshape(-1).view(np.uint8)
    return np.frombuffer(data, dtype=np.uint8)


def _pad3(raw: np.ndarray) -> np.ndarray:
    """Zero-pad the last axis to a multiple of 3 bytes (an odd pixel count ends mid-group)."""
    extra = -raw.shape[-1] % 3
    if not extra:
        return raw
    return np.concatenate([raw, np.zeros((*raw.shape[:-1], extra), dtype=np.uint8)], axis=-1)


def _groups(data: bytes | np.ndarray, count: int, name: str) -> np.ndarray:
    """The first ``packed12_size(count)`` bytes as rows of 3 (the last one zero-padded)."""
    if count < 0:
        raise DeviceError(f"{name}: negative pixel count {count}")
    raw = _as_bytes(data)
    need = packed12_size(count)
    if raw.size < need:
        raise DeviceError(f"{name}: {raw.size} bytes hold fewer than the {count} pixels expected "
                          f"({need} bytes)")
    return _pad3(raw[:need]).reshape(-1, 3)


def image_size(pixel_format: str, width: int, height: int, line_padding: int = 0) -> int:
    """Bytes a ``width`` x ``height`` image takes in ``pixel_format`` with ``line_padding``."""
    if pixel_format in _PACKED12:
        if line_padding:
            return height * (packed12_size(width) + line_padding)
        return packed12_size(width * height)
    return height * (width * _UNPACKED_BYTES[pixel_format] + line_padding)


def decode_image(data: bytes | np.ndarray, pixel_format: str, width: int, height: int,
                 line_padding: int = 0) -> np.ndarray:
    """Turn a raw image buffer into a C-contiguous (height, width) uint8 or uint16 array.

    ``line_padding`` is the number of bytes after each line (Aravis' ``x_padding``). Mono8
    without padding comes back as a read-only view on ``data`` (no copy); all other cases
    are fresh arrays. Too few bytes raise ``DeviceError`` (the caller drops the buffer).
    """
    if pixel_format not in PIXEL_BITS:
        raise DeviceError(f"pixel format {pixel_format!r} cannot be decoded; edgedsm measures with "
                          f"{', '.join(PIXEL_BITS)}")
    if width < 1 or height < 1 or line_padding < 0:
        raise DeviceError(f"invalid image geometry {width}x{height} with line padding {line_padding}")
    raw = _as_bytes(data)
    need = image_size(pixel_format, width, height, line_padding)
    if raw.size < need:
        raise DeviceError(f"{pixel_format} {width}x{height}: buffer holds {raw.size} bytes, "
                          f"{need} expected")
    if pixel_format in _PACKED12:
        if not line_padding:  # one bit stream across lines
            pairs = _unpack12(_pad3(raw[:need]).reshape(-1, 3), pixel_format)
            return pairs.reshape(-1)[:width * height].reshape(height, width)
        stride = packed12_size(width) + line_padding
        lines = _pad3(raw[:need].reshape(height, stride)[:, :packed12_size(width)])
        pairs = _unpack12(lines.reshape(height, -1, 3), pixel_format)
        return np.ascontiguousarray(pairs.reshape(height, -1)[:, :width])
    size = _UNPACKED_BYTES[pixel_format]
    stride = width * size + line_padding
    lines = raw[:height * stride].reshape(height, stride)[:, :width * size]
    if size == 1:
        return lines if not line_padding else np.ascontiguousarray(lines)
    # GenICam data are little-endian; .astype gives native order and a contiguous copy.
    return np.ascontiguousarray(lines).view("<u2").astype(np.uint16)


#: Significant bits of each format ``decode_image`` handles.
PIXEL_BITS: dict[str, int] = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono14": 14, "Mono16": 16,
                              "Mono12Packed": 12, "Mono12p": 12}
