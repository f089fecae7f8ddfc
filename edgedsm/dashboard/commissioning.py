"""The last commissioning report of each device, as ``edgedsm tune -c CONFIG`` keeps it in the
config's ``device.commissioning_dir`` (docs/commissioning.md): found from the daemon configs the
dashboard is given, read at each request (a new run shows at the next look), checked, and cut
down to what the page shows. A report that is absent or unreadable is a message, never an error
page: the file is written by another program, maybe another version, and may be anything."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError

from edgedsm.config import DeviceSection
from edgedsm.errors import ConfigError
from edgedsm.tuning.output import LAST_PLOTS, LAST_SUMMARY
from edgedsm.validation import read_toml, validate

log = logging.getLogger(__name__)

MAX_SUMMARY_BYTES = 16 * 1024 * 1024  # every candidate with its transitions: a few hundred kB on the default grid
MAX_PLOT_BYTES = 8 * 1024 * 1024
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class _Loose(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)


class RegionView(_Loose):
    thresholds: dict[str, float]
    delay_s: float | None = None
    auc: float | None = None


class ChoiceView(_Loose):
    estimator: str
    label: str
    noise_floor: bool
    window: int
    lag: int
    mode: str
    auc: float
    d_prime: float | None = None  # None: infinite (no spread)
    delay_s: float | None = None
    cost_ms_per_frame: float
    robust: bool | None = None  # absent in reports of versions before the robustness rule
    regions: dict[str, RegionView]


class ReportView(_Loose):
    """What the page shows of summary.json (edgedsm.tuning.output.keep_last)."""

    run: str
    frames: int
    dt_s: float
    wet_until_s: float
    dry_from_s: float
    seconds: float
    reason: str
    recommended: ChoiceView | None
    pareto: list[str]
    candidates: int
    written_at: str
    command: str
    config: str
    plots: list[str]


def report_dirs(configs: list[Path]) -> dict[str, Path]:
    """Each device's report folder, from its daemon config's [device] table (a config whose
    [device] table is invalid is skipped with a warning: its report cannot be placed)."""
    found: dict[str, Path] = {}
    for path in configs:
        try:
            data = read_toml(path)
            table = data.get("device", {})
            device = validate(DeviceSection, table if isinstance(table, dict) else {}, str(path))
        except ConfigError as exc:
            log.warning("dashboard: no commissioning report for %s: %s", path, exc)
            continue
        found[device.name] = device.commissioning_directory(path.resolve().parent)
    return found


def load(device: str, folder: Path | None) -> dict[str, Any]:
    """``{"device", "folder", "report": ReportView as a dict or None, "message": why not or None}``."""
    answer: dict[str, Any] = {"device": device, "folder": None if folder is None else str(folder),
                              "report": None, "message": None}
    if folder is None:
        answer["message"] = (f"no daemon config names the device {device}: give the dashboard its config (-c or "
                             "--config-dir) to see its commissioning report")
        return answer
    path = folder / LAST_SUMMARY
    try:
        with path.open("rb") as file:
            raw = file.read(MAX_SUMMARY_BYTES + 1)
    except FileNotFoundError:
        answer["message"] = (f"no commissioning report yet: `edgedsm tune RUN -c CONFIG ...` with this device's "
                             f"config keeps its last one in {folder}")
        return answer
    except OSError as exc:
        answer["message"] = f"the commissioning report {path} cannot be read: {exc.strerror or exc}"
        return answer
    try:
        if len(raw) > MAX_SUMMARY_BYTES:
            raise ValueError(f"larger than {MAX_SUMMARY_BYTES >> 20} MiB")
        data = json.loads(raw)
        if not isinstance(data, dict):
            raise ValueError("not a JSON object")
        if isinstance(data.get("candidates"), list):
            data["candidates"] = len(data["candidates"])
        view = ReportView.model_validate(data)
    except ValidationError as exc:
        error = exc.errors()[0]
        where = ".".join(map(str, error["loc"]))
        answer["message"] = f"the commissioning report {path} cannot be read: {where}: {error['msg']}"
        return answer
    except ValueError as exc:  # json.JSONDecodeError and UnicodeDecodeError are ValueErrors
        answer["message"] = f"the commissioning report {path} cannot be read: {exc}"
        return answer
    report = view.model_dump()
    report["plots"] = [name for name in view.plots if name in LAST_PLOTS]
    answer["report"] = report
    return answer


def plot(folder: Path | None, name: str) -> bytes | None:
    """One of the report's PNG plots (LAST_PLOTS), None when absent, too large or not a PNG."""
    if folder is None or name not in LAST_PLOTS:
        return None
    try:
        with (folder / name).open("rb") as file:
            data = file.read(MAX_PLOT_BYTES + 1)
    except OSError:
        return None
    return data if data.startswith(PNG_MAGIC) and len(data) <= MAX_PLOT_BYTES else None
