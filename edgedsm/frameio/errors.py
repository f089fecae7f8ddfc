"""The errors every frame reader raises (re-exported by ``edgedsm.frameio.base``)."""

from __future__ import annotations

from edgedsm.errors import DataError


class ReaderError(DataError):
    """A frame source cannot be read as frames (exit code 65: the data, not the program)."""


class InputMissing(ReaderError):
    """The input named does not exist (exit code 66, EX_NOINPUT)."""

    exit_code = 66
    kind = "no input"
