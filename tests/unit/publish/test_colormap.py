"""Colour maps for viewers: linear indices, the colour bar, the PNG."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edgedsm.publish.colormap import BAR_WIDTH, COLORMAPS, GAP, colour_indices, encode_colour_png, render_colour_map
from edgedsm.publish.errors import MapCodecError


def test_indices_run_linearly_from_the_minimum_to_the_maximum() -> None:
    values = np.array([[0.10, 0.20], [0.30, 0.35]])
    indices, low, high = colour_indices(values)
    assert (low, high) == (0.10, 0.35)
    assert indices.tolist() == [[0, 102], [204, 255]]


def test_a_constant_map_is_index_zero() -> None:
    indices, low, high = colour_indices(np.full((3, 4), 0.7))
    assert (low, high) == (0.7, 0.7) and not indices.any()


def test_non_finite_values_are_refused() -> None:
    with pytest.raises(MapCodecError, match="finite"):
        colour_indices(np.array([[0.0, np.nan]]))


def test_the_picture_is_the_map_in_colours_with_a_bar_from_max_at_top_to_min_at_bottom() -> None:
    values = np.tile(np.linspace(0.0, 1.0, 100), (80, 1))
    picture = render_colour_map(values, colormap="viridis", max_size=None)
    assert picture.shape[0] == 80 and picture.shape[2] == 3
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], COLORMAPS["viridis"])[:, 0]
    assert (picture[10, 0] == lut[0]).all() and (picture[10, 99] == lut[255]).all()
    bar = picture[:, 100 + GAP + BAR_WIDTH // 2]
    assert (bar[0] == lut[255]).all() and (bar[-1] == lut[0]).all()


def test_the_png_is_8_bit_colour_and_downsampled_like_the_exact_map() -> None:
    values = np.random.default_rng(1).random((600, 1200))
    png = encode_colour_png(values, max_size=300)
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    assert image.shape[0] == 150 and image.shape[1] > 300


def test_an_unknown_colour_map_is_refused() -> None:
    with pytest.raises(MapCodecError, match="unknown colour map"):
        render_colour_map(np.zeros((4, 4)), colormap="rainbow")
