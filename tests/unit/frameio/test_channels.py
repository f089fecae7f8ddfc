"""Colour channel selection: R, G, B in either order, BT.601 luma at the image's own depth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edgedsm.frameio.channels import BT601, select_channel


def test_each_channel_in_either_order():
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 10, 20, 30
    bgr = rgb[..., ::-1]
    for order, image in (("rgb", rgb), ("bgr", bgr)):
        assert select_channel(image, "red", order).tolist() == [[10] * 3] * 2
        assert select_channel(image, "green", order).tolist() == [[20] * 3] * 2
        assert select_channel(image, "blue", order).tolist() == [[30] * 3] * 2


def test_luma_is_opencv_bt601_for_8_bits():
    image = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    ours = select_channel(image, "luma", "bgr").astype(int)
    theirs = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(int)
    assert np.abs(ours - theirs).max() <= 1  # OpenCV rounds with fixed-point weights
    assert BT601 == (0.299, 0.587, 0.114)


def test_luma_keeps_16_bits_and_alpha_is_ignored():
    rgba = np.zeros((1, 2, 4), np.uint16)
    rgba[0, 0, :3] = (60000, 1000, 100)
    rgba[0, :, 3] = 65535
    luma = select_channel(rgba, "luma", "rgb")
    assert luma.dtype == np.uint16
    assert luma[0, 0] == round(0.299 * 60000 + 0.587 * 1000 + 0.114 * 100)
    assert luma[0, 1] == 0


@pytest.mark.parametrize(("image", "channel", "order", "match"), [
    (np.zeros((2, 2, 3), np.uint8), "purple", "rgb", "channel must be"),
    (np.zeros((2, 2, 3), np.uint8), "red", "rbg", "colour order"),
    (np.zeros((2, 2), np.uint8), "red", "rgb", r"\(H, W, 3 or 4\)"),
])
def test_bad_arguments_are_refused(image, channel, order, match):
    with pytest.raises(ValueError, match=match):
        select_channel(image, channel, order)
