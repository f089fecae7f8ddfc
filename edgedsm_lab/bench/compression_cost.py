"""What a codec costs on speckle frames: ratio, MB/s per core, and what a lossy one takes from the maps.

The measurement behind `edgedsm bench compression` (its tables and command: edgedsm_lab.bench.compression).
Frames come from the simulator's logo scene (the paper's two-level object, edgedsm_lab.bench.accuracy's
``logo_scene``), digitised at 8, 12 and 16 bits by changing only ``[detector] bits``.

- Lossless codecs: ratio = raw bytes / compressed bytes (raw: 1 byte per pixel at 8 bits, 2 at 12 and
  16: the uint16 a camera delivers), encode and decode MB/s of raw data on one core (median of a few
  repetitions over the same frames), and whether decoding gives back every pixel.
- Lossy codecs (8-bit logo scene): ratio, RMS error of the decoded frames (grey levels), and the
  activity maps S1, S2, S3 (paper Eq. 1-3) and τc computed from the decoded frames against the same
  maps from the originals: relative RMS error, contrast β (paper §2C) and AUC of the logos against
  the background, and the regions' τc.

Every codec runs through imagecodecs, one call per frame on the calling thread; the codecs that
have a thread option (OpenJPEG, libjxl, libwebp) are given ``numthreads=1``. Speed is MB of raw
frames per CPU second of the calling thread (a shared machine's wall clock would count the time
other work held the core); the process's CPU time against the thread's shows that no other thread
helped, the thread's CPU time against the wall time how much of the run it got a core.
imagecodecs is imported when a codec list is built, not when this module is (the CLI builds every
bench parser at start-up).
"""

from __future__ import annotations

import io
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edgedsm.analysis import contrast
from edgedsm.estimators import tau_c
from edgedsm.sim import Scene, region_masks, scene_from_dict
from edgedsm_lab.bench.accuracy import ESTIMATORS, activity_maps, frames_of, logo_scene
from edgedsm_lab.report.measures import auc

DEPTHS = (8, 12, 16)
REGIONS = ("IOMT", "ETRI", "background")  # the logo scene's regions whose τc is reported


@dataclass(frozen=True)
class Plan:
    """Sizes of one run."""

    size: int = 256  # pixels per side of the simulated frames
    frames: int = 200  # frames per lossy trial (the maps' window N)
    speed_frames: int = 16  # frames per timed pass and per lossless ratio
    repeats: int = 7  # timed passes; the median counts
    lag: int = 5  # m of S1-S3 (the paper's Fig. 10-11 processing)
    max_lag: int = 20  # K of τc

    def __post_init__(self) -> None:
        if self.size < 16 or self.speed_frames < 1 or self.repeats < 1 or self.lag < 1:
            raise ValueError("size >= 16, speed_frames >= 1, repeats >= 1 and lag >= 1 are needed")
        if not self.lag < self.frames or not 1 <= self.max_lag < self.frames - 1:
            raise ValueError(f"frames ({self.frames}) must exceed the lag ({self.lag}) and max_lag + 1 "
                             f"({self.max_lag + 1})")


@dataclass(frozen=True)
class Codec:
    """One codec at one setting: ``encode(frame, bits) -> bytes``, ``decode(bytes, like) -> frame``."""

    name: str  # table label: library and mode
    setting: str  # level or quality, "" when there is none
    lossless: bool
    depths: tuple[int, ...]  # bit depths it takes
    encode: Callable[[np.ndarray, int], bytes]
    decode: Callable[[bytes, np.ndarray], np.ndarray]
    tiff: tuple[str, dict[str, Any]] | None = None  # tifffile compression= and its arguments, if TIFF has it

    @property
    def label(self) -> str:
        return f"{self.name} {self.setting}".strip()


@dataclass(frozen=True)
class Timing:
    """One operation over the frames: median CPU seconds of the calling thread per pass, and over
    all passes the share of wall time that thread was on a CPU and the process's CPU time per
    thread CPU time (1.0: the codec used no other thread)."""

    thread_s: float
    on_cpu: float
    threads: float


@dataclass(frozen=True)
class Speed:
    """Encode and decode of ``raw_mb`` megabytes (10^6 bytes) of raw frames on one core."""

    raw_mb: float
    encode: Timing
    decode: Timing

    @property
    def encode_mb_s(self) -> float:
        """MB of raw frames per CPU second of the encoding thread."""
        return self.raw_mb / self.encode.thread_s if self.encode.thread_s > 0 else float("inf")

    @property
    def decode_mb_s(self) -> float:
        return self.raw_mb / self.decode.thread_s if self.decode.thread_s > 0 else float("inf")


@dataclass(frozen=True)
class DepthStats:
    """What the frames at one bit depth hold: distinct grey levels, order-0 entropy (bits/pixel)."""

    bits: int
    itemsize: int  # bytes per pixel as delivered
    levels: int
    entropy: float

    @property
    def entropy_ratio(self) -> float:
        """The ratio a coder of independent pixels (order-0 entropy) would reach."""
        return 8 * self.itemsize / self.entropy if self.entropy > 0 else float("inf")


@dataclass(frozen=True)
class LosslessRow:
    codec: Codec
    bits: int
    ratio: float
    speed: Speed
    identical: bool  # every decoded pixel equals the original
    tiff: TiffCheck | None  # None: TIFF has no such compression


@dataclass(frozen=True)
class TiffCheck:
    """A multi-page TIFF written by tifffile with the codec, read back by three readers: "yes" if
    tifffile gives back every pixel ("no: <why>" otherwise); OpenCV and Pillow: True if they
    do too, False if not, None if not installed."""

    tifffile: str
    opencv: bool | None
    pillow: bool | None


@dataclass(frozen=True)
class MapQuality:
    """The maps of one set of frames: per estimator (S1, S2, S3, tau_c) relative RMS error against
    the uncompressed maps, β and AUC (1/τc for tau_c: higher = more active), and regions' τc (frames)."""

    error: dict[str, float]
    beta: dict[str, float]
    auc: dict[str, float]
    region_tau: dict[str, float]


@dataclass(frozen=True)
class LossyRow:
    codec: Codec
    ratio: float
    frame_rms: float  # RMS error of the decoded frames, grey levels
    speed: Speed
    quality: MapQuality


@dataclass
class Results:
    plan: Plan
    depths: list[DepthStats] = field(default_factory=list)
    lossless: list[LosslessRow] = field(default_factory=list)
    reference: MapQuality | None = None  # the uncompressed frames' maps (errors 0)
    lossy: list[LossyRow] = field(default_factory=list)
    absent: list[str] = field(default_factory=list)  # codecs this imagecodecs build lacks


# ----------------------------------------------------------------------------- codecs
def _byte_codec(ic: Any, encode: Callable[[Any], bytes], decode: Callable[[bytes], bytes],
                predictor: bool) -> tuple[Callable, Callable]:
    """A byte-stream compressor on the frame's buffer; ``predictor``: TIFF's horizontal
    differencing (predictor 2, modulo the integer type) before it, as tifffile writes it."""

    def enc(frame: np.ndarray, _bits: int) -> bytes:
        return encode(ic.delta_encode(frame, axis=-1) if predictor else frame)

    def dec(data: bytes, like: np.ndarray) -> np.ndarray:
        out = np.frombuffer(decode(data), like.dtype).reshape(like.shape)
        return ic.delta_decode(out, axis=-1) if predictor else out

    return enc, dec


def _grey_as_rgb(encode: Callable[[np.ndarray], bytes]) -> Callable[[np.ndarray, int], bytes]:
    """WebP takes RGB only: the grey frame in all three channels (the luma carries it)."""
    return lambda frame, _bits: encode(np.repeat(frame[..., None], 3, axis=-1))


def _first_channel(decode: Callable[[bytes], np.ndarray]) -> Callable[[bytes, np.ndarray], np.ndarray]:
    def dec(data: bytes, _like: np.ndarray) -> np.ndarray:
        out = decode(data)
        return out[..., 0] if out.ndim == 3 else out
    return dec


def _image(decode: Callable[[bytes], np.ndarray]) -> Callable[[bytes, np.ndarray], np.ndarray]:
    return lambda data, _like: decode(data)


def _available(ic: Any, names: Sequence[str], absent: list[str]) -> bool:
    """Whether every imagecodecs codec in ``names`` is in this build (those missing go to ``absent``)."""
    missing = [n for n in names if not getattr(getattr(ic, n.upper(), None), "available", False)]
    absent.extend(m for m in missing if m not in absent)
    return not missing


def lossless_codecs(absent: list[str]) -> list[Codec]:
    """The lossless codecs measured, in table order (those this build lacks are named in ``absent``)."""
    import imagecodecs as ic

    all_depths = DEPTHS
    codecs: list[Codec] = []

    def add(needs: Sequence[str], *args: Any, **kwargs: Any) -> None:
        if _available(ic, needs, absent):
            codecs.append(Codec(*args, **kwargs))

    for predictor in (False, True):
        suffix = " + predictor" if predictor else ""
        tiff_args: dict[str, Any] = {"predictor": True} if predictor else {}
        add(["zlib"], "deflate (zlib)" + suffix, "level 6", True, all_depths,
            *_byte_codec(ic, lambda d: ic.zlib_encode(d, 6), ic.zlib_decode, predictor),
            tiff=("zlib", {"compressionargs": {"level": 6}, **tiff_args}))
        for level in (1, 3, 9) if not predictor else (3,):
            add(["zstd"], "zstd" + suffix, f"level {level}", True, all_depths,
                *_byte_codec(ic, lambda d, lv=level: ic.zstd_encode(d, lv), ic.zstd_decode, predictor),
                tiff=("zstd", {"compressionargs": {"level": level}, **tiff_args}))
        add(["lzw"], "LZW" + suffix, "", True, all_depths,
            *_byte_codec(ic, ic.lzw_encode, ic.lzw_decode, predictor), tiff=("lzw", tiff_args))
    add(["png"], "PNG (libpng)", "", True, all_depths, lambda f, _b: ic.png_encode(f), _image(ic.png_decode),
        tiff=("png", {}))
    add(["jpegls"], "JPEG-LS (CharLS)", "", True, all_depths, lambda f, _b: ic.jpegls_encode(f, 0),
        _image(ic.jpegls_decode))
    add(["jpeg8"], "lossless JPEG (libjpeg-turbo)", "", True, all_depths,
        lambda f, b: ic.jpeg8_encode(f, lossless=True, bitspersample=b), _image(ic.jpeg8_decode),
        tiff=("jpeg", {"compressionargs": {"lossless": True}}))
    add(["jpeg2k"], "JPEG 2000 reversible (OpenJPEG)", "", True, all_depths,
        lambda f, b: ic.jpeg2k_encode(f, reversible=True, bitspersample=b, numthreads=1),
        _image(ic.jpeg2k_decode), tiff=("jpeg2000", {"compressionargs": {"reversible": True}}))
    add(["htj2k"], "HTJ2K reversible (OpenJPH)", "", True, all_depths,
        lambda f, _b: ic.htj2k_encode(f, reversible=True), _image(ic.htj2k_decode))
    for effort in (1, 7):
        add(["jpegxl"], "JPEG-XL lossless (libjxl)", f"effort {effort}", True, all_depths,
            lambda f, b, e=effort: ic.jpegxl_encode(f, lossless=True, effort=e, bitspersample=b, numthreads=1),
            _image(lambda d: ic.jpegxl_decode(d, numthreads=1)),
            tiff=("jpegxl", {"compressionargs": {"lossless": True, "effort": effort}}))
    add(["webp"], "WebP lossless (libwebp, grey as RGB)", "", True, (8,),
        _grey_as_rgb(lambda rgb: ic.webp_encode(rgb, lossless=True, numthreads=1)), _first_channel(ic.webp_decode))
    return codecs


JPEG_QUALITIES = (95, 90, 75, 50)
J2K_PSNR_DB = (50, 40, 35, 30)  # OpenJPEG's quality layer: the PSNR it aims at, in dB
WEBP_QUALITIES = (95, 90, 75, 50)
JXL_QUALITIES = (95, 90, 75, 50)


def lossy_codecs(absent: list[str]) -> list[Codec]:
    """The lossy codecs measured on 8-bit frames, each from its best setting to its worst, after a
    lossless control."""
    import imagecodecs as ic

    codecs: list[Codec] = []
    if _available(ic, ["zstd"], absent):  # a control: the maps of bit-identical frames must not move
        codecs.append(Codec("zstd (lossless control)", "level 3", True, (8,),
                            *_byte_codec(ic, lambda d: ic.zstd_encode(d, 3), ic.zstd_decode, False)))
    if _available(ic, ["jpeg8"], absent):
        codecs += [Codec("JPEG (libjpeg-turbo)", f"quality {q}", False, (8,),
                         lambda f, _b, q=q: ic.jpeg8_encode(f, q), _image(ic.jpeg8_decode),
                         tiff=("jpeg", {"compressionargs": {"level": q}})) for q in JPEG_QUALITIES]
    if _available(ic, ["jpeg2k"], absent):
        codecs += [Codec("JPEG 2000 (OpenJPEG)", f"PSNR {db} dB", False, (8,),
                         lambda f, _b, db=db: ic.jpeg2k_encode(f, db, numthreads=1), _image(ic.jpeg2k_decode),
                         tiff=("jpeg2000", {"compressionargs": {"level": db}})) for db in J2K_PSNR_DB]
    if _available(ic, ["webp"], absent):
        codecs += [Codec("WebP (libwebp, grey as RGB)", f"quality {q}", False, (8,),
                         _grey_as_rgb(lambda rgb, q=q: ic.webp_encode(rgb, q, lossless=False, numthreads=1)),
                         _first_channel(ic.webp_decode)) for q in WEBP_QUALITIES]
    if _available(ic, ["jpegxl"], absent):
        codecs += [Codec("JPEG-XL (libjxl)", f"quality {q}", False, (8,),
                         lambda f, _b, q=q: ic.jpegxl_encode(f, q, numthreads=1),
                         _image(lambda d: ic.jpegxl_decode(d, numthreads=1)),
                         tiff=("jpegxl", {"compressionargs": {"level": q}})) for q in JXL_QUALITIES]
    return codecs


# ----------------------------------------------------------------------------- frames
def scene_at(bits: int, size: int) -> Scene:
    """The logo scene with its detector digitising at ``bits`` (nothing else changed)."""
    data = logo_scene(size, noisy=False).model_dump()
    data["detector"]["bits"] = bits
    return scene_from_dict(data, f"<logo scene at {bits} bits>")


def depth_stats(frames: np.ndarray, bits: int) -> DepthStats:
    _, counts = np.unique(frames, return_counts=True)
    p = counts / frames.size
    return DepthStats(bits, frames.itemsize, counts.size, float(-(p * np.log2(p)).sum()))


# ----------------------------------------------------------------------------- measures
def _timed(work: Callable[[], object], repeats: int) -> Timing:
    """``work`` run ``repeats`` times, timed by the calling thread's CPU clock: on a shared machine
    the wall clock also counts the time other work held the core."""
    thread_times = []
    wall_start, process_start = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        start = time.thread_time()
        work()
        thread_times.append(time.thread_time() - start)
    wall, process = time.perf_counter() - wall_start, time.process_time() - process_start
    thread_total = sum(thread_times)
    return Timing(statistics.median(thread_times), thread_total / wall if wall > 0 else float("nan"),
                  process / thread_total if thread_total > 0 else float("nan"))


def encode_all(codec: Codec, frames: np.ndarray, bits: int) -> list[bytes]:
    return [bytes(codec.encode(frame, bits)) for frame in frames]


def decode_all(codec: Codec, encoded: list[bytes], like: np.ndarray) -> np.ndarray:
    return np.stack([codec.decode(data, like[0]) for data in encoded])


def speed(codec: Codec, frames: np.ndarray, bits: int, repeats: int) -> tuple[Speed, list[bytes]]:
    """Encoding and decoding ``frames`` timed after one untimed warm-up frame; with the encoded frames."""
    codec.decode(codec.encode(frames[0], bits), frames[0])
    encoded = encode_all(codec, frames, bits)
    encode = _timed(lambda: encode_all(codec, frames, bits), repeats)
    decode = _timed(lambda: decode_all(codec, encoded, frames), repeats)
    return Speed(frames.nbytes / 1e6, encode, decode), encoded


def ratio(frames: np.ndarray, encoded: list[bytes]) -> float:
    return frames.nbytes / sum(len(data) for data in encoded)


def tiff_round_trip(codec: Codec, frames: np.ndarray) -> TiffCheck | None:
    """Write ``frames`` as a multi-page TIFF in memory with the codec's tifffile compression, then
    read every page back with tifffile, OpenCV and Pillow (None if TIFF has no such compression)."""
    if codec.tiff is None:
        return None
    import tifffile

    compression, kwargs = codec.tiff
    buffer = io.BytesIO()
    try:
        tifffile.imwrite(buffer, frames, compression=compression, photometric="minisblack", **kwargs)
        back = tifffile.imread(io.BytesIO(buffer.getvalue()))
    except Exception as exc:  # any refusal by tifffile or the codec is the finding
        return TiffCheck(f"no: {type(exc).__name__}", None, None)
    data = buffer.getvalue()
    return TiffCheck("yes" if np.array_equal(back.reshape(frames.shape), frames) else "no: differs",
                     _opencv_reads(data, frames), _pillow_reads(data, frames))


def _same_pages(pages: Sequence[np.ndarray], frames: np.ndarray) -> bool:
    return len(pages) == len(frames) and all(np.array_equal(p, f) for p, f in zip(pages, frames, strict=True))


def _opencv_reads(data: bytes, frames: np.ndarray) -> bool | None:
    """Whether OpenCV (its own libtiff) decodes every page bit-identically; None if not installed."""
    try:
        import cv2
    except ImportError:
        return None
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # a refusal is the finding
    try:
        ok, pages = cv2.imdecodemulti(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        return False
    finally:
        cv2.utils.logging.setLogLevel(level)
    return bool(ok) and _same_pages(pages, frames)


def _pillow_reads(data: bytes, frames: np.ndarray) -> bool | None:
    """Whether Pillow decodes every page bit-identically; None if not installed."""
    try:
        from PIL import Image
    except ImportError:
        return None
    try:
        with Image.open(io.BytesIO(data)) as image:
            pages = []
            for index in range(getattr(image, "n_frames", 1)):
                image.seek(index)
                pages.append(np.array(image))
    except Exception:  # Pillow raises many types for a compression it lacks
        return False
    return _same_pages(pages, frames)


def map_quality(frames: np.ndarray, scene: Scene, plan: Plan,
                reference: dict[str, np.ndarray] | None) -> tuple[MapQuality, dict[str, np.ndarray]]:
    """The maps of ``frames`` and how they compare with ``reference`` (None: these are the reference)."""
    masks = region_masks(scene)
    active, background = masks["regions"], masks["background"]
    maps = activity_maps(frames, plan.lag, plan.max_lag)  # tau_c is the rate 1/τc
    maps["tau_c_frames"] = 1.0 / maps["tau_c"]
    error = {}
    for name in ESTIMATORS:
        key = "tau_c_frames" if name == "tau_c" else name
        if reference is None:
            error[name] = 0.0
        else:
            truth = reference[key]
            error[name] = float(np.sqrt(np.mean((maps[key] - truth) ** 2) / np.mean(truth ** 2)))
    quality = MapQuality(
        error=error,
        beta={name: contrast(maps[name], active, background) for name in ESTIMATORS},
        auc={name: auc(maps[name], active, background) for name in ESTIMATORS},
        region_tau={name: float(tau_c(frames, plan.max_lag, mask=masks[name])) for name in REGIONS},
    )
    return quality, maps


def measure_lossless(plan: Plan, results: Results, codecs: list[Codec],
                     progress: Callable[[str], None]) -> None:
    for bits in DEPTHS:
        frames = frames_of(scene_at(bits, plan.size), plan.speed_frames)
        results.depths.append(depth_stats(frames, bits))
        for codec in codecs:
            if bits not in codec.depths:
                continue
            progress(f"lossless {bits} bits: {codec.label}")
            timing, encoded = speed(codec, frames, bits, plan.repeats)
            identical = np.array_equal(decode_all(codec, encoded, frames), frames)
            results.lossless.append(LosslessRow(codec, bits, ratio(frames, encoded), timing, identical,
                                                tiff_round_trip(codec, frames)))


def measure_lossy(plan: Plan, results: Results, codecs: list[Codec], progress: Callable[[str], None]) -> None:
    scene = scene_at(8, plan.size)
    frames = frames_of(scene, plan.frames)
    progress("lossy: maps of the uncompressed frames")
    results.reference, reference = map_quality(frames, scene, plan, None)
    for codec in codecs:
        progress(f"lossy: {codec.label}")
        timing, _ = speed(codec, frames[: plan.speed_frames], 8, plan.repeats)
        encoded = encode_all(codec, frames, 8)
        decoded = decode_all(codec, encoded, frames)
        rms = float(np.sqrt(np.mean((decoded.astype(np.float64) - frames) ** 2)))
        quality, _ = map_quality(decoded, scene, plan, reference)
        results.lossy.append(LossyRow(codec, ratio(frames, encoded), rms, timing, quality))


def measure(plan: Plan, lossless: list[Codec] | None = None, lossy: list[Codec] | None = None,
            progress: Callable[[str], None] = lambda _text: None) -> Results:
    """Everything in one run (codec lists default to :func:`lossless_codecs` / :func:`lossy_codecs`)."""
    results = Results(plan)
    lossless = lossless_codecs(results.absent) if lossless is None else lossless
    lossy = lossy_codecs(results.absent) if lossy is None else lossy
    measure_lossless(plan, results, lossless, progress)
    measure_lossy(plan, results, lossy, progress)
    return results
