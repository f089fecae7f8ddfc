"""``[recording]``: what the daemon keeps of the frames it measures (docs/recording.md, "In the
daemon"). The files are edgedsm recordings (:mod:`edgedsm.frameio.recording`); the recorder is
:mod:`edgedsm.daemon.recording`."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

from edgedsm.frameio.recording import CODECS, DEFAULT_CODEC
from edgedsm.validation import StrictModel

#: Where recordings go when ``dir`` is not given: this folder of the state directory.
DEFAULT_SUBDIR = "recordings"
#: Compression ratios measured on simulated speckle (docs/recording.md, "The codec"), by codec
#: and significant bits (8; 12 in 16-bit words; 16): what ``check-config`` expects on disk.
SPECKLE_RATIO: dict[str, tuple[float, float, float]] = {
    "zstd": (1.37, 1.36, 1.07), "deflate": (1.37, 1.37, 1.07), "lzw": (1.07, 1.14, 0.77), "none": (1.0, 1.0, 1.0)}


def speckle_ratio(codec: str, bits: int) -> float:
    """The measured ratio of ``codec`` on speckle of ``bits`` significant bits."""
    ratios = SPECKLE_RATIO[codec]
    return ratios[0] if bits <= 8 else ratios[1] if bits <= 12 else ratios[2]


class RecordingSection(StrictModel):
    """``[recording]``: continuous, alert clips or a time-lapse, with retention by size and age."""

    dir: Path | None = Field(None, description="folder of the recordings (relative: to the config file's folder; "
                                               "default: <device.state_dir>/recordings)")
    mode: Literal["continuous", "alerts", "timelapse"] = Field(
        "alerts", description="continuous: every frame; alerts: a clip of pre_s + post_s seconds around each "
                              "transition or fault alert (from an in-memory ring); timelapse: one frame every every_s")
    pre_s: float = Field(10.0, ge=0, le=600, description="alerts mode: seconds kept before an alert (the ring)")
    post_s: float = Field(20.0, gt=0, le=3600, description="alerts mode: seconds recorded after an alert; also "
                                                           "the length of a cmd/record clip without 'seconds'")
    every_s: float = Field(60.0, gt=0, le=86_400, description="timelapse mode: seconds between two frames kept")
    segment_s: float = Field(600.0, ge=1, le=86_400,
                             description="a continuous or time-lapse file is closed after this many seconds "
                                         "(retention deletes whole files)")
    max_bytes: int = Field(10 * 2**30, ge=4 * 2**20, le=2**50,
                           description="the recordings' total size: the oldest files are deleted beyond it")
    keep_days: float = Field(30.0, gt=0, le=3650, description="files older than this are deleted")
    codec: str = Field(DEFAULT_CODEC, description=f"lossless codec: {', '.join(CODECS)} (docs/recording.md)")
    ring_max_mib: int = Field(256, ge=1, le=65_536,
                              description="alerts mode: memory bound of the ring (it holds less than pre_s "
                                          "when pre_s of frames would take more)")
    queue_max_mib: int = Field(256, ge=1, le=65_536,
                               description="memory bound of the frames waiting for the disk (beyond: dropped "
                                           "and counted, the measurement never waits)")

    @field_validator("codec")
    @classmethod
    def _known_codec(cls, value: str) -> str:
        if value not in CODECS:
            raise ValueError(f"unknown codec {value!r}: choose one of {', '.join(CODECS)}")
        return value

    def directory(self, base_dir: Path, state_dir: Path) -> Path:
        """The recordings' folder: ``dir`` resolved against ``base_dir`` (the config file's
        folder), else ``state_dir/recordings``."""
        if self.dir is None:
            return state_dir / DEFAULT_SUBDIR
        return self.dir if self.dir.is_absolute() else base_dir / self.dir
