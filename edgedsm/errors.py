"""Exception hierarchy shared by every part of edgedsm.

Each error the CLI may end on carries its process exit code (sysexits.h), so that systemd can
act on it (``RestartPreventExitStatus=78 65``): 78 configuration, 65 bad data, 66 missing input, 69 device
unavailable, 73 output exists, 74 write failed.
"""


class EdgedsmError(Exception):
    """Base class of every error edgedsm raises on purpose."""

    exit_code = 1
    #: What the CLI's one line calls it (``edgedsm: <kind>: <message>``).
    kind = "error"


class ConfigError(EdgedsmError):
    """A configuration or scene file is invalid; the message names the key path.

    The CLI maps it to exit code 78 (EX_CONFIG), which systemd is told not to restart on.
    """

    exit_code = 78


class DataError(EdgedsmError):
    """Input data is unusable (a corrupt recording, frames that change size); the message names
    the file. Exit code 65 (EX_DATAERR): restarting would not help."""

    exit_code = 65
    kind = "bad data"


class EstimatorError(EdgedsmError, ValueError):
    """Bad arguments to an estimator (lag that does not fit the window, bad stack shape...)."""


class FrameError(EdgedsmError, ValueError):
    """A frame was refused at the boundary (shape, dtype, bit depth, layout)."""


class DeviceError(EdgedsmError):
    """A camera or relay misbehaved. Exit code 69 (EX_UNAVAILABLE): it may work after a restart."""

    exit_code = 69
    kind = "device unavailable"


class DeviceUnavailable(DeviceError):
    """A device could not be opened at all (missing, busy, no permission)."""


class DeviceTimeout(DeviceError):
    """A device did not answer in time."""


class DeviceLost(DeviceError):
    """A device disappeared (cable pulled, process killed, control lost)."""
