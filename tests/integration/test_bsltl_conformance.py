"""Conformance with the field's reference toolbox: BSLTL 1.3.1 in Octave (Debian ``octave`` and
``octave-bsltl``, installed by scripts/test.sh) computes its descriptors on small deterministic
speckle stacks (8-bit and 12-bit in 16) and on a crop of a real recording (the blueberry video of
tests/data, red channel, read by edgedsm.frameio), and every descriptor edgedsm shares with it must
agree.

Tolerance: 1e-12 relative wherever both sides are finite (the integer sums of S1/AVD, GD, IM,
the THSP and the COM are exact on both sides and must be equal to the last bit; the others
differ by the order of float64 operations, a few ulp). Skewness near 0 is compared with an
absolute 1e-12 as well (a relative error of a value that cancels to ~0 means nothing). Where
BSLTL divides 0 by 0 (contrast of a dark pixel, skewness and kurtosis of a constant one) it
returns NaN and edgedsm its documented 0; the test checks that these are exactly those pixels.

Not compared: BSLTL's frequency filter banks (``firfilterbank``) return filtered data packs,
not band powers (edgedsm.estimators.bands documents the difference).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from edgedsm.estimators import SlidingWindow, s1
from edgedsm.estimators.descriptors import contrast, fujii, gd, im, kurtosis, mhi, skewness
from edgedsm.estimators.thsp import avd, coom, inertia_moment, thsp
from edgedsm.frameio import open_frames

pytestmark = [pytest.mark.integration, pytest.mark.timeout(240)]

N, H, W = 32, 24, 20
ROW, COLUMN = 7, 11  # 0-based; BSLTL's are 1-based
MOTION_THRESHOLD = 20.0
RTOL = 1e-12
OCTAVE_TIMEOUT_S = 180
VIDEO = Path(__file__).resolve().parents[1] / "data" / "blueberry-biospeckle" / "A5LEP.mp4"

SCRIPT = """1;
function put(name, X)
  fid = fopen([name '.f64'], 'w'); fwrite(fid, X.', 'double'); fclose(fid);
end
pkg load bsltl
fid = fopen('stack.raw'); d = fread(fid, Inf, '{kind}=>double'); fclose(fid);
DATA = permute(reshape(d, {w}, {h}, {n}), [2 1 3]);
put('graphavd', graphavd(DATA, 'off'));
put('fujii', fujii(DATA, 'off'));
put('gendiff', gendiff(DATA, 'off'));
put('graphim', graphim(DATA, 'off'));
put('stdcont', stdcont(DATA, 'off'));
put('graphskew', graphskew(DATA, 'off'));
put('graphkurt', graphkurt(DATA, 'off'));
put('graphmhi', graphmhi(DATA, {threshold}, 'off'));
T = thsp(DATA, 1, {row});
put('thsp_row', T);
put('thsp_column', thsp(DATA, 2, {column}));
C = coom(T);
put('coom', C);
put('inertiamoment', inertiamoment(C));
put('avd', avd(C));
"""


def _speckle(dtype: type, top: int) -> np.ndarray:
    """A seeded, fully developed speckle stack (exponential intensities, mean top/5) that
    fluctuates at a rate varying across the frame, plus a dark, a saturated and a constant pixel."""
    rng = np.random.default_rng(24)
    field = rng.exponential(1.0, (N, H, W))
    hold = np.linspace(0.0, 0.95, W)[None, None, :]  # left: new pattern each frame; right: slow
    for k in range(1, N):
        field[k] = hold[0] * field[k - 1] + (1 - hold[0]) * field[k]
    stack = np.clip(np.round(field * top / 5), 0, top).astype(dtype)
    stack[:, 0, 0] = 0
    stack[:, 1, 1] = top
    stack[:, 2, 2] = top // 3
    return stack


def _blueberry() -> np.ndarray:
    """N frames of an H x W crop of the lit fruit (red channel, 8-bit) of the real recording."""
    with open_frames(VIDEO, channel="red") as reader:
        frames = np.stack(list(reader.frames(0, N)))
    rows, cols = frames.shape[1] // 2, frames.shape[2] // 2
    return np.ascontiguousarray(frames[:, rows - H // 2:rows + H // 2, cols - W // 2:cols + W // 2])


def _octave(stack: np.ndarray, folder: Path) -> dict[str, np.ndarray]:
    octave = shutil.which("octave-cli")
    if octave is None:
        pytest.fail("octave-cli is not installed: the BSLTL conformance test needs Debian's octave and "
                    "octave-bsltl (scripts/test.sh installs them: apt-get install octave octave-bsltl)")
    folder.mkdir()
    stack.tofile(folder / "stack.raw")  # C order (N, H, W): Octave reads it as (W, H, N)
    kind = {np.dtype(np.uint8): "uint8", np.dtype(np.uint16): "uint16"}[stack.dtype]
    (folder / "conformance.m").write_text(SCRIPT.format(kind=kind, n=N, h=H, w=W, threshold=MOTION_THRESHOLD,
                                                        row=ROW + 1, column=COLUMN + 1))
    try:
        done = subprocess.run([octave, "--no-gui", "--quiet", "--no-window-system", "conformance.m"], cwd=folder,
                              capture_output=True, text=True, timeout=OCTAVE_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        pytest.fail(f"Octave did not finish the BSLTL script in {OCTAVE_TIMEOUT_S} s")
    if done.returncode != 0:
        pytest.fail(f"Octave/BSLTL failed (is octave-bsltl installed?): exit {done.returncode}\n{done.stderr[-2000:]}")
    shapes = {"thsp_row": (W, N), "thsp_column": (H, N), "coom": (256, 256), "inertiamoment": (), "avd": ()}
    return {path.stem: np.fromfile(path, np.float64).reshape(shapes.get(path.stem, (H, W)))
            for path in folder.glob("*.f64")}


def _relative_error(ours: np.ndarray, theirs: np.ndarray) -> float:
    ours, theirs = np.asarray(ours, np.float64), np.asarray(theirs, np.float64)
    scale = np.maximum(np.abs(theirs), np.finfo(np.float64).tiny)
    return float((np.abs(ours - theirs) / scale).max())


@pytest.mark.parametrize("case", ["8bit", "12bit", "blueberry"])
def test_edgedsm_matches_bsltl(case: str, tmp_path: Path) -> None:
    stack = {"8bit": lambda: _speckle(np.uint8, 255), "12bit": lambda: _speckle(np.uint16, 4095),
             "blueberry": _blueberry}[case]()
    assert stack.shape == (N, H, W) and stack.std() > 1  # a live speckle stack, not an empty crop
    bsltl = _octave(stack, tmp_path / "octave")
    exact = {"graphavd": s1(stack, 1), "gendiff": gd(stack), "graphim": im(stack, 1),
             "thsp_row": thsp(stack, row=ROW), "thsp_column": thsp(stack, column=COLUMN)}
    for name, ours in exact.items():
        np.testing.assert_array_equal(ours, bsltl[name], err_msg=name)
    close = {"fujii": fujii(stack), "graphmhi": mhi(stack, MOTION_THRESHOLD)}
    for name, ours in close.items():
        assert _relative_error(ours, bsltl[name]) <= RTOL, name
    # BSLTL's 0/0 pixels are NaN there and 0 here; everywhere else the values agree
    for name, ours, undefined in (("stdcont", contrast(stack), stack.mean(axis=0) == 0),
                                  ("graphskew", skewness(stack), stack.std(axis=0) == 0),
                                  ("graphkurt", kurtosis(stack), stack.std(axis=0) == 0)):
        theirs = bsltl[name]
        np.testing.assert_array_equal(np.isnan(theirs), undefined, err_msg=name)
        assert (ours[undefined] == 0).all(), name
        np.testing.assert_allclose(ours[~undefined], theirs[~undefined], rtol=RTOL, atol=RTOL, err_msg=name)
    # the streaming engine's descriptors (issue 24) over the same N frames, one sliding window
    engine = SlidingWindow((H, W), N, 1, q=0, estimators=("s1", "contrast", "fujii", "im", "gd"))
    for frame in stack:
        engine.push(np.ascontiguousarray(frame))
    streamed = engine.maps()
    for name, theirs in (("s1", "graphavd"), ("im", "graphim"), ("gd", "gendiff")):
        np.testing.assert_array_equal(streamed[name], bsltl[theirs], err_msg=f"streaming {name}")
    assert _relative_error(streamed["fujii"], bsltl["fujii"]) <= RTOL
    dark = stack.mean(axis=0) == 0
    assert (streamed["contrast"][dark] == 0).all()
    np.testing.assert_allclose(streamed["contrast"][~dark], bsltl["stdcont"][~dark], rtol=RTOL, atol=RTOL)
    if stack.dtype == np.uint8:  # coom.m's 256 x 256 matrix is for 8-bit values
        com = coom(thsp(stack, row=ROW))
        np.testing.assert_array_equal(com, bsltl["coom"])
        assert _relative_error(inertia_moment(com), bsltl["inertiamoment"]) <= RTOL
        assert _relative_error(avd(com), bsltl["avd"]) <= RTOL
