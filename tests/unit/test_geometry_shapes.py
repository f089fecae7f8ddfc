"""One region-shape model (edgedsm.geometry) for the daemon's [[regions]] and a scene's
[[activity.regions]]; degenerate or non-finite geometry is refused with its key path."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm import geometry
from edgedsm.config import load_config
from edgedsm.errors import ConfigError
from edgedsm.sim import load_scene, region_masks
from edgedsm.sim.scene import PolygonRegion, RectRegion

REGION = "[camera]\nuri = 'sim:'\n[[regions]]\nname = 'r'\nwet_above = 2\ndry_below = 1\n"
SCENE = "[scene]\nsize = 32\n[activity]\ntau_c = 5\n[[activity.regions]]\ntau_c = 1\n"


def _config(tmp_path, extra: str):
    path = tmp_path / "c.toml"
    path.write_text(REGION + extra)
    return load_config(path)


def _scene(tmp_path, extra: str):
    path = tmp_path / "s.toml"
    path.write_text(SCENE + extra)
    return load_scene(path)


def test_daemon_and_scene_regions_share_the_shape_models(tmp_path):
    config = _config(tmp_path, "shape = 'rect'\nx = 2\ny = 3\nwidth = 4\nheight = 5\n")
    scene = _scene(tmp_path, "shape = 'rect'\nx = 2\ny = 3\nwidth = 4\nheight = 5\n")
    region, scene_region = config.regions[0], scene.activity.regions[0]
    assert isinstance(region, geometry.Rect) and isinstance(scene_region, geometry.Rect)
    assert issubclass(RectRegion, geometry.Rect) and issubclass(PolygonRegion, geometry.Polygon)
    mask = region.mask((16, 16), tmp_path)
    assert mask.sum() == 20 and mask[3:8, 2:6].all()
    assert np.array_equal(mask[:16, :16], scene_region.draw((16, 16)))


def test_a_region_without_shape_is_the_whole_frame(tmp_path):
    region = _config(tmp_path, "").regions[0]
    assert region.shape == "full" and region.mask((4, 6), tmp_path).sum() == 24


def test_shapes_known_to_one_file_work_in_the_other(tmp_path):
    # a ring in the daemon, a polygon in a scene: one model, so both files know every shape
    ring = _config(tmp_path, "shape = 'ring'\ncx = 8\ncy = 8\ninner_radius = 3\nouter_radius = 6\n").regions[0]
    area = ring.mask((16, 16), tmp_path).sum()
    assert abs(area - np.pi * (36 - 9)) < 12
    scene = _scene(tmp_path, "shape = 'polygon'\npoints = [[0, 0], [16, 0], [0, 16]]\nname = 'tri'\n")
    tri = region_masks(scene)["tri"]
    assert tri.sum() == 17 * 18 // 2  # OpenCV fills the vertices and edges too: rows 0..16, 17 - row px each


@pytest.mark.parametrize(("geometry_text", "message"), [
    ("shape = 'polygon'\npoints = [[3, 3], [3, 3], [3, 3]]", r"regions\.0: Value error, the polygon has no area"),
    ("shape = 'polygon'\npoints = [[0, 0], [1, 1], [2, 2]]", r"regions\.0: Value error, the polygon has no area"),
    ("shape = 'polygon'\npoints = [[0, 0], [nan, 1], [2, 0]]", r"regions\.0\.points\.1\.0: Input should be a finite"),
    ("shape = 'polygon'\npoints = [[0, 0], [1, 1]]", r"regions\.0\.points: List should have at least 3"),
    ("shape = 'polygon'\npoints = [[0, 0, 1], [1, 1], [1, 0]]", r"regions\.0\.points\.0: Tuple should have at most 2"),
    ("shape = 'circle'\ncx = inf\nradius = 2", r"regions\.0\.cx: Input should be a finite number"),
    ("shape = 'rect'\nx = 1\nwidth = 0\nheight = 2", r"regions\.0\.width: Input should be greater than 0"),
    ("shape = 'rect'\nwidth = 2\nheight = 2\nradius = 3", r"regions\.0\.radius: unknown key"),
    ("radius = 3", r"regions\.0\.radius: unknown key"),
    ("shape = 'hexagon'", r"regions\.0: shape must be one of full, rect, circle"),
    ("shape = 'ring'\ninner_radius = 5\nouter_radius = 5", r"regions\.0: Value error, outer_radius must be larger"),
])
def test_bad_geometry_is_refused_with_its_key_path(tmp_path, geometry_text, message):
    with pytest.raises(ConfigError, match=message):
        _config(tmp_path, geometry_text + "\n")


def test_scene_geometry_is_validated_the_same_way(tmp_path):
    with pytest.raises(ConfigError, match=r"activity\.regions\.0: Value error, the polygon has no area"):
        _scene(tmp_path, "shape = 'polygon'\npoints = [[1, 1], [1, 1], [1, 1]]\n")
    with pytest.raises(ConfigError, match=r"activity\.regions\.0\.x: Input should be a finite number"):
        _scene(tmp_path, "shape = 'rect'\nx = nan\nwidth = 2\nheight = 2\n")


def test_bounds_of_each_shape():
    assert geometry.Rect(shape="rect", x=1, y=2, width=3, height=4).bounds() == (1, 2, 4, 6)
    assert geometry.Circle(shape="circle", cx=5, cy=5, radius=2).bounds() == (3, 3, 7, 7)
    assert geometry.Polygon(shape="polygon", points=[(0, 1), (4, 1), (2, 9)]).bounds() == (0, 1, 4, 9)
    x0, y0, x1, y1 = geometry.Text(shape="text", text="IOMT", x=10, y=10, height=20).bounds()
    drawn = geometry.Text(shape="text", text="IOMT", x=10, y=10, height=20).draw((64, 128))
    rows, cols = np.nonzero(drawn)
    assert (x0, y0) == (10, 10) and rows.max() < y1 and cols.max() < x1 and cols.min() >= x0 and rows.min() >= y0
    assert geometry.outside_part((-1, 2, 30, 40), (32, 32)) == "left, bottom"
    assert geometry.outside_part((0, 0, 32, 32), (32, 32)) == ""
