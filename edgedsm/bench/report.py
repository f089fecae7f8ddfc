"""Pieces every benchmark report shares: the machine it ran on, and writing the markdown."""

from __future__ import annotations

import platform
import sys
from pathlib import Path

import numpy as np


def cpu_model() -> str:
    """The processor's model name (from /proc/cpuinfo on Linux)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def versions(*modules: str) -> str:
    """'Python x, numpy y, <module> z, ...'; numba also says its thread count."""
    parts = [f"Python {platform.python_version()}", f"numpy {np.__version__}"]
    for module in modules:
        try:
            imported = __import__(module)
        except ImportError:
            parts.append(f"{module} (not installed)")
            continue
        text = f"{module} {imported.__version__}"
        if module == "numba":
            text += f" ({imported.config.NUMBA_NUM_THREADS} threads)"
        parts.append(text)
    return ", ".join(parts)


def write_markdown(path: str | Path, lines: list[str]) -> Path:
    """Write the report's lines (parent directories created) and say so on stderr."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines).rstrip() + "\n", encoding="utf-8")
    print(f"wrote {path}", file=sys.stderr)
    return path
