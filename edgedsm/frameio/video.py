"""Video files (AVI, MP4, MKV, MOV ...) decoded frame by frame with PyAV (FFmpeg's libraries).

Each decoded frame is turned into pixels by its own pixel format, never guessed:

- grey (``gray``, ``gray10le`` .. ``gray16le``, either byte order): the stored values exactly,
  uint8 or uint16, with the format's significant bits (FFV1 gray16le stays bit-exact);
- palettized (``pal8``: the 8-, 4- and 1-bit DIBs of older capture software): each index looked
  up in the frame's palette; a grey palette gives its grey levels, a colour one R, G, B
  (a channel to choose), never the indices as intensities;
- anything else (RGB555, BGR24, YUV of MJPG or H.264 ...): R, G, B of 8 bits (16 above 8 bits
  per component) by FFmpeg's converter; a grey video stored as colour has equal channels and is
  read as grey, a colour one needs a channel.

FFmpeg puts row 0 of a bottom-up DIB on top. Lossless codecs (raw, FFV1, HuffYUV, Ut Video,
PNG ...) give the frames as recorded; any other codec (MJPG, H.264, MPEG-4 ...) is accepted for
analysis with a note naming its FOURCC (AVI) or codec, because its artefacts change the speckle
statistics.

The frame count is the container's (AVI and MP4 store it; MKV and WebM only a duration, so
their count is unknown); a count the file is too small to hold is refused at open, and so is an
uncompressed AVI shorter than its frames (a cut file: check-config sees it as run would). A file that
ends before the count it announces is truncated: ``ReaderError`` naming the file, once the last
frame has been decoded. The frame size the stream announces is checked against the memory
budget (``edgedsm.frameio.budget``) before any frame is decoded.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import av
import numpy as np

from edgedsm.frameio.base import FrameReader, InputMissing, ReaderError
from edgedsm.frameio.budget import check_frame
from edgedsm.frames import sample_dtype

VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov", ".webm", ".m4v", ".mj2")
#: FFmpeg decoders of codecs that keep every pixel.
LOSSLESS_CODECS = {"rawvideo", "ffv1", "huffyuv", "ffvhuff", "png", "apng", "utvideo", "magicyuv", "lagarith",
                   "v210", "v210x", "r210", "r10k", "v308", "v408", "v410", "y41p", "yuv4", "ayuv", "zlib",
                   "mszh", "qtrle", "msrle", "bmp", "tiff", "ljpeg", "jpegls", "fits", "qoi"}
#: Containers whose frame count is an estimate from the duration, not a stored number.
_ESTIMATED_COUNT = (".mkv", ".webm")
#: AVI compression tags of Windows DIBs, whose rows are padded to 4 bytes (BI_RGB, BI_BITFIELDS and
#: the 'DIB '/'RGB ' spellings); other raw tags (Y800, YUY2 ...) store rows unpadded.
_DIB_TAGS = ("\0\0\0\0", "\x03\0\0\0", "DIB ", "RGB ")
#: The smallest a frame takes in an AVI file (its chunk header): a count needing more is a lie.
_MIN_FRAME_BYTES = 8


def shown_codec(tag: str, codec: str, container: str) -> str:
    """How messages name a stream's codec: the FOURCC in an AVI (what its tools show), else
    FFmpeg's codec name ('h264', 'mjpeg' ...)."""
    if "avi" in container and tag and tag.isprintable() and tag.strip("\0 "):
        return repr(tag.strip("\0 ") if tag.strip("\0 ") else tag)
    return repr(codec)


def _dib_frame_bytes(container: av.container.InputContainer, stream: av.VideoStream) -> int | None:
    """Bytes of one uncompressed DIB frame in an AVI (rows padded to 4 bytes), None for others."""
    context = stream.codec_context
    bits = int(getattr(context, "bits_per_coded_sample", 0) or 0)
    if (context.name != "rawvideo" or "avi" not in container.format.name or bits not in (1, 2, 4, 8, 16, 24, 32)
            or (context.codec_tag or "") not in _DIB_TAGS):
        return None
    return (int(context.width) * bits + 31) // 32 * 4 * int(context.height)


def _grey_bits(fmt: av.VideoFormat) -> int | None:
    """Significant bits of a one-component grey format (gray, gray12le ...), else None; formats
    of fewer than 8 bits (monob) are widened to 8 by FFmpeg's converter."""
    parts = fmt.components
    if (len(parts) == 1 and not fmt.is_rgb and not fmt.has_palette and not getattr(fmt, "is_bayer", False)
            and parts[0].bits <= 16):
        return max(8, int(parts[0].bits))
    return None


def _samples(fmt: av.VideoFormat | None) -> tuple[int, int]:
    """(samples per pixel, bytes per sample) of the pixels a frame of ``fmt`` becomes; R, G, B of
    16 bits where the stream does not say."""
    if fmt is None:
        return 3, 2
    bits = _grey_bits(fmt)
    if bits is not None:
        return 1, sample_dtype(bits).itemsize  # grey: the frames' own array type
    return 3, 1 if fmt.has_palette or max(int(part.bits) for part in fmt.components) <= 8 else 2


def _plane_rows(frame: av.VideoFrame, plane: int, row_bytes: int) -> np.ndarray:
    """A plane's bytes as (height, row_bytes), row 0 on top: PyAV gives the plane's memory from
    its lowest address, which for a bottom-up frame (a negative stride) is the last row."""
    data = frame.planes[plane]
    step = abs(data.line_size)
    rows = np.frombuffer(data, np.uint8)[: step * frame.height].reshape(frame.height, step)
    return (rows[::-1] if data.line_size < 0 else rows)[:, :row_bytes]


def _grey_pixels(frame: av.VideoFrame, bits: int) -> np.ndarray:
    """The stored grey values of a grey frame, exactly (uint8 up to 8 bits, uint16 above)."""
    if frame.format.name != "gray" and bits <= 8:
        return frame.to_ndarray(format="gray")
    if bits <= 8:
        return np.ascontiguousarray(_plane_rows(frame, 0, frame.width))
    order = ">" if frame.format.is_big_endian else "<"
    return _plane_rows(frame, 0, 2 * frame.width).view(f"{order}u2").astype(np.uint16)


def _palette_pixels(frame: av.VideoFrame) -> np.ndarray:
    """A pal8 frame through its palette: (H, W) grey when every entry is grey, else (H, W, 3) R, G, B."""
    index = _plane_rows(frame, 0, frame.width)
    entries = np.frombuffer(frame.planes[1], "=u4")[:256]  # FFmpeg's palette: native-endian 0xAARRGGBB
    rgb = np.stack([(entries >> shift) & 0xFF for shift in (16, 8, 0)], axis=1).astype(np.uint8)
    if len(rgb) < 256:  # indices beyond a short palette are black, as FFmpeg fills it
        rgb = np.concatenate([rgb, np.zeros((256 - len(rgb), 3), np.uint8)])
    if np.array_equal(rgb[:, 0], rgb[:, 1]) and np.array_equal(rgb[:, 0], rgb[:, 2]):
        return rgb[:, 0][index]
    return rgb[index]


class VideoReader(FrameReader):
    kind = "video"

    def __init__(self, path: Path, channel: str | None = None) -> None:
        super().__init__(path, channel)
        self._container: av.container.InputContainer | None = None
        self._decoded: Iterator[av.VideoFrame] | None = None
        try:
            self._open()
            self._inspect()
        except av.FFmpegError as exc:
            self.close()
            raise ReaderError(f"{path}: cannot be opened as a video (damaged or truncated file, or a codec "
                              f"FFmpeg lacks: {_reason(exc)})") from None
        except BaseException:
            self.close()
            raise

    def _open(self) -> None:
        try:
            container = av.open(str(self.path), mode="r", metadata_errors="ignore")
        except FileNotFoundError:
            raise InputMissing(f"{self.path}: no such file or directory") from None
        except PermissionError:
            raise InputMissing(f"{self.path}: cannot be read (permission denied)") from None
        except av.FFmpegError as exc:
            raise ReaderError(f"{self.path}: cannot be opened as a video (not a video, or a damaged or "
                              f"truncated one: {_reason(exc)})") from None
        self._container = container
        if not container.streams.video:
            raise ReaderError(f"{self.path}: holds no video stream")
        self._stream = container.streams.video[0]
        self._stream.thread_type = "AUTO"  # frame and slice threads, as OpenCV's reader used
        self._raw_bytes = _dib_frame_bytes(container, self._stream)
        self._damage: str | None = None
        self._decoded = self._decode()
        self._position = 0

    def _decode(self) -> Iterator[av.VideoFrame]:
        """The stream's frames; a raw DIB frame whose chunk is shorter than the header's frame
        size ends it (FFmpeg would pad it with black: not what was recorded), saying why."""
        assert self._container is not None
        for number, packet in enumerate(self._container.demux(self._stream)):
            if self._raw_bytes and packet.size and packet.size < self._raw_bytes:
                self._damage = (f"frame {number} holds {packet.size:,} bytes where the header's frames of "
                                f"{self._stream.codec_context.width}x{self._stream.codec_context.height} "
                                f"pixels need {self._raw_bytes:,}")
                return
            yield from packet.decode()

    def _inspect(self) -> None:
        path, stream = self.path, self._stream
        context = stream.codec_context
        width, height = int(context.width or 0), int(context.height or 0)
        if width and height:  # before a frame is decoded: what one frame's pixels will take
            samples, itemsize = _samples(context.format)
            check_frame(path, (height, width, samples), itemsize, "video stream's header")
        codec = context.name
        self.fourcc = context.codec_tag or ""
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        self.dt = 1.0 / float(rate) if rate and float(rate) > 0 else None
        announced = int(stream.frames or 0)
        if path.suffix.lower() in _ESTIMATED_COUNT or announced <= 0:
            announced = 0
        size = path.stat().st_size
        if announced * _MIN_FRAME_BYTES > size:
            raise ReaderError(f"{path}: its header announces {announced:,} frames, more than a file of "
                              f"{size:,} bytes can hold (damaged or forged header)")
        if self._raw_bytes and announced and announced * (self._raw_bytes + _MIN_FRAME_BYTES) > size:
            raise ReaderError(f"{path}: holds {size:,} bytes, too few for the {announced} frames of "
                              f"{context.width}x{context.height} pixels its header announces "
                              f"({announced * self._raw_bytes:,} bytes of pixels): truncated or damaged video")
        self._announced = announced or None
        self.count = self._announced
        first = self._next()
        if first is None:
            why = self._damage or "empty, damaged or truncated video"
            raise ReaderError(f"{path}: no frame can be decoded ({why})")
        self._first: np.ndarray | None = first
        self._settle(first, 1 if first.ndim == 2 else first.shape[2], order="rgb")
        if codec not in LOSSLESS_CODECS:
            shown = shown_codec(self.fourcc, codec, self._container.format.name)
            self.lossy = shown.strip("'")
            self.note(f"{path}: codec {shown} is lossy: compression artefacts change the speckle statistics "
                      f"(analysed all the same; record with a lossless codec such as FFV1)")

    def _pixels(self, frame: av.VideoFrame) -> np.ndarray:
        """One decoded frame as pixels, by its pixel format (see the module docstring)."""
        fmt = frame.format
        if (frame.height, frame.width) != self.shape and self.shape != (0, 0):
            samples, itemsize = _samples(fmt)
            check_frame(self.path, (frame.height, frame.width, samples), itemsize, "video stream")
        bits = _grey_bits(fmt)
        if bits is not None:
            if self.bits is None:
                self.bits = bits
            return _grey_pixels(frame, bits)
        if fmt.has_palette:
            return _palette_pixels(frame)
        deep = max(int(part.bits) for part in fmt.components) > 8
        return frame.to_ndarray(format="rgb48le" if deep else "rgb24")

    def _next(self) -> np.ndarray | None:
        """The next frame's pixels; None at the end, or where the stream cannot be decoded further
        (the truncation check then names it)."""
        if self._decoded is None:
            return None
        try:
            frame = next(self._decoded)
        except StopIteration:
            self._decoded = None
            return None
        except av.FFmpegError:
            self._decoded = None  # a damaged packet ends the stream here
            return None
        try:
            return self._pixels(frame)
        except (av.FFmpegError, ValueError, TypeError) as exc:  # PyAV: a format it cannot convert
            raise ReaderError(f"{self.path}: frame {self._position} of pixel format {frame.format.name} cannot "
                              f"be converted to grey levels ({_reason(exc)})") from None

    def _read(self) -> np.ndarray | None:
        if self._first is not None and self._position == 0:
            image, self._first = self._first, None
        else:
            image = self._next()
            if image is None:
                return None
        self._position += 1
        return image

    def _rewind(self) -> None:
        """Back to frame 0 (seeking in a compressed stream is not exact: decode forward again)."""
        self.close()
        try:
            self._open()
        except av.FFmpegError as exc:
            raise ReaderError(f"{self.path}: cannot be opened again ({_reason(exc)})") from None
        self._first = None

    def _skip_to(self, start: int) -> None:
        """Decode forward to frame ``start``."""
        if start < self._position:
            self._rewind()
        while self._position < start:
            if self._first is not None and self._position == 0:
                self._first = None
            elif not self._skip_one():
                self._truncated(self._position)
                raise ReaderError(f"{self.path}: has {self._position} frames; frame {start} does not exist")
            self._position += 1

    def _skip_one(self) -> bool:
        """Decode one frame without converting it; False at the end of the stream."""
        if self._decoded is None:
            return False
        try:
            next(self._decoded)
        except (StopIteration, av.FFmpegError):
            self._decoded = None
            return False
        return True

    def _truncated(self, decoded: int) -> None:
        if self._announced is not None and decoded < self._announced:
            raise ReaderError(f"{self.path}: ends after {decoded} of the {self._announced} frames its header "
                              f"announces ({self._damage or 'truncated or damaged video'})")
        if self._damage is not None:
            raise ReaderError(f"{self.path}: ends after {decoded} frames: {self._damage} (truncated or damaged video)")

    def _raw(self, start: int) -> Iterator[tuple[int, np.ndarray]]:
        self._skip_to(start)
        while True:
            index = self._position
            image = self._read()
            if image is None:
                self._truncated(index)
                if self.count is None:
                    self.count = index
                return
            yield index, image

    def close(self) -> None:
        self._decoded = None
        container = getattr(self, "_container", None)
        if container is not None:
            self._container = None
            with contextlib.suppress(av.FFmpegError):
                container.close()


def _reason(exc: Exception) -> str:
    """FFmpeg's reason in a few words ('Invalid data found when processing input')."""
    text = getattr(exc, "strerror", None) or str(exc)
    return str(text).split(":")[0].strip() or type(exc).__name__
