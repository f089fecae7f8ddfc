"""Decoding of raw camera buffers, the packed 12-bit formats checked against hand-made bytes."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.devices.camera.pixels import (
    PIXEL_FORMAT_CODES,
    decode_image,
    image_size,
    packed12_size,
    unpack_mono12_packed,
    unpack_mono12p,
)
from edgedsm.errors import DeviceError

# Two pixels A = 0xABC, B = 0x123 packed by hand in each layout (see the module docstring).
A, B = 0xABC, 0x123
MONO12_PACKED_AB = bytes([0xAB, 0x3C, 0x12])  # A[11:4], B[3:0]<<4 | A[3:0], B[11:4]
MONO12P_AB = bytes([0xBC, 0x3A, 0x12])        # A[7:0],  B[3:0]<<4 | A[11:8], B[11:4]


def test_mono12_packed_by_hand():
    assert unpack_mono12_packed(MONO12_PACKED_AB, 2).tolist() == [A, B]


def test_mono12p_by_hand():
    assert unpack_mono12p(MONO12P_AB, 2).tolist() == [A, B]


def test_the_two_layouts_differ_on_the_same_bytes():
    assert unpack_mono12p(MONO12_PACKED_AB, 2).tolist() == [0xCAB, B]
    assert unpack_mono12_packed(MONO12P_AB, 2).tolist() == [0xBCA, B]


def test_extremes_and_more_pixels_by_hand():
    # pixels 0x000, 0xFFF, 0x801, 0x7FE
    packed = bytes([0x00, 0xF0, 0xFF, 0x80, 0xE1, 0x7F])
    lsb = bytes([0x00, 0xF0, 0xFF, 0x01, 0xE8, 0x7F])
    assert unpack_mono12_packed(packed, 4).tolist() == [0x000, 0xFFF, 0x801, 0x7FE]
    assert unpack_mono12p(lsb, 4).tolist() == [0x000, 0xFFF, 0x801, 0x7FE]


def test_odd_pixel_count_uses_half_a_group():
    assert packed12_size(1) == 2 and packed12_size(3) == 5
    assert unpack_mono12_packed(bytes([0xAB, 0x0C]), 1).tolist() == [A]
    assert unpack_mono12p(bytes([0xBC, 0x0A]), 1).tolist() == [A]
    three = MONO12P_AB + bytes([0x56, 0x04])  # third pixel 0x456
    assert unpack_mono12p(three, 3).tolist() == [A, B, 0x456]


def _pack(values: np.ndarray, layout: str) -> bytes:
    """Reference packer written bit by bit, independent of the vectorised unpacker."""
    out = bytearray()
    for i in range(0, len(values), 2):
        a = int(values[i])
        b = int(values[i + 1]) if i + 1 < len(values) else 0
        if layout == "Mono12Packed":
            group = [a >> 4, ((b & 0xF) << 4) | (a & 0xF), b >> 4]
        else:
            group = [a & 0xFF, ((b & 0xF) << 4) | (a >> 8), b >> 4]
        out += bytes(group if i + 1 < len(values) else group[:2])
    return bytes(out)


@pytest.mark.parametrize("layout", ["Mono12Packed", "Mono12p"])
@pytest.mark.parametrize(("width", "height"), [(4, 3), (5, 3), (1, 1), (7, 2)])
def test_images_round_trip_through_a_bitwise_packer(layout, width, height):
    values = np.random.default_rng(width * 10 + height).integers(0, 4096, size=width * height, dtype=np.uint16)
    data = _pack(values, layout)
    assert len(data) == packed12_size(width * height) == image_size(layout, width, height)
    image = decode_image(data, layout, width, height)
    assert image.dtype == np.uint16 and image.shape == (height, width) and image.flags.c_contiguous
    np.testing.assert_array_equal(image, values.reshape(height, width))


@pytest.mark.parametrize("layout", ["Mono12Packed", "Mono12p"])
def test_packed_lines_with_padding_start_on_a_fresh_byte(layout):
    width, height, padding = 3, 2, 2
    values = np.array([[1, 2, 4095], [2048, 7, 99]], dtype=np.uint16)
    data = b"".join(_pack(row, layout) + b"\xee" * padding for row in values)
    assert len(data) == image_size(layout, width, height, padding)
    np.testing.assert_array_equal(decode_image(data, layout, width, height, padding), values)


def test_unpacked_formats_are_little_endian_and_padding_is_skipped():
    data = bytes([0x01, 0x02, 0xFF, 0x03, 0xAA, 0xBB])  # two Mono10 pixels + 2 bytes of line padding
    image = decode_image(data, "Mono10", 2, 1, line_padding=2)
    assert image.dtype == np.uint16 and image.tolist() == [[0x0201, 0x03FF]]
    mono8 = decode_image(bytes([1, 2, 9, 3, 4, 9]), "Mono8", 2, 2, line_padding=1)
    assert mono8.tolist() == [[1, 2], [3, 4]] and mono8.flags.c_contiguous
    mono16 = decode_image(np.array([0x1234, 0xFFFF], dtype="<u2").tobytes(), "Mono16", 2, 1)
    assert mono16.tolist() == [[0x1234, 0xFFFF]]


def test_mono8_without_padding_is_not_copied():
    data = bytes(range(12))
    image = decode_image(data, "Mono8", 4, 3)
    assert image.base is not None and not image.flags.writeable  # a view on the bytes
    assert image[2, 3] == 11


def test_short_buffers_and_unknown_formats_are_refused():
    with pytest.raises(DeviceError, match="fewer than the 4 pixels"):
        unpack_mono12p(bytes(5), 4)
    with pytest.raises(DeviceError, match="buffer holds 5 bytes, 6 expected"):
        decode_image(bytes(5), "Mono12Packed", 2, 2)
    with pytest.raises(DeviceError, match="buffer holds 7 bytes"):
        decode_image(bytes(7), "Mono16", 2, 2)
    with pytest.raises(DeviceError, match="RGB8"):
        decode_image(bytes(12), "RGB8", 2, 2)
    with pytest.raises(DeviceError, match="invalid image geometry"):
        decode_image(bytes(4), "Mono8", 0, 2)


def test_pixel_format_codes_match_pfnc_and_aravis_names():
    assert PIXEL_FORMAT_CODES[0x01080001] == "Mono8"
    assert PIXEL_FORMAT_CODES[0x010C0006] == "Mono12Packed"  # ARV_PIXEL_FORMAT_MONO_12_PACKED
    assert PIXEL_FORMAT_CODES[0x010C0047] == "Mono12p"
    # the code's middle byte is the bits per pixel on the wire
    for code, name in PIXEL_FORMAT_CODES.items():
        wire_bits = 12 if name in ("Mono12Packed", "Mono12p") else 8 if name == "Mono8" else 16
        assert (code >> 16) & 0xFF == wire_bits
