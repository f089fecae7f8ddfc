"""One grey-level frame out of a colour image: a colour channel, or the luma. Pure numpy.

A colour camera under a laser sees the speckle in the channel of the laser's colour (red for a
He-Ne or a 650 nm diode): that channel alone is the measurement, and ``--channel red`` picks it.
``luma`` mixes the three with the ITU-R BT.601 weights (Rec. 601, the weights of JPEG and of
OpenCV's ``COLOR_BGR2GRAY``)::

    Y = 0.299 R + 0.587 G + 0.114 B

rounded to the nearest integer and kept in the image's own type (a 16-bit image gives a 16-bit
luma). OpenCV stores colour as B, G, R; TIFF, numpy stacks and most other tools as R, G, B:
the caller says which (``order``). A fourth channel (alpha) is ignored.
"""

from __future__ import annotations

import numpy as np

CHANNELS = ("red", "green", "blue", "luma")
#: ITU-R BT.601 luma weights of R, G, B.
BT601 = (0.299, 0.587, 0.114)
_INDEX = {"rgb": {"red": 0, "green": 1, "blue": 2}, "bgr": {"red": 2, "green": 1, "blue": 0}}


def select_channel(image: np.ndarray, channel: str, order: str) -> np.ndarray:
    """The 2-D ``channel`` of an (H, W, 3 or 4) ``image`` whose channels come in ``order``
    ("rgb" or "bgr"); a contiguous array of the image's dtype."""
    if order not in _INDEX:
        raise ValueError(f"colour order must be 'rgb' or 'bgr', not {order!r}")
    if channel not in CHANNELS:
        raise ValueError(f"channel must be one of {', '.join(CHANNELS)}, not {channel!r}")
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"a colour image is (H, W, 3 or 4), not {image.shape}")
    index = _INDEX[order]
    if channel != "luma":
        return np.ascontiguousarray(image[:, :, index[channel]])
    mixed = (BT601[0] * image[:, :, index["red"]].astype(np.float32)
             + BT601[1] * image[:, :, index["green"]].astype(np.float32)
             + BT601[2] * image[:, :, index["blue"]].astype(np.float32))
    if image.dtype.kind == "f":
        return mixed.astype(image.dtype)
    top = np.iinfo(image.dtype).max
    return np.clip(np.rint(mixed), 0, top).astype(image.dtype)
