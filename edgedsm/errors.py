"""Exception hierarchy shared by every part of edgedsm."""


class EdgedsmError(Exception):
    """Base class of every error edgedsm raises on purpose."""


class ConfigError(EdgedsmError):
    """A configuration or scene file is invalid; the message names the key path.

    The CLI maps it to exit code 78 (EX_CONFIG), which systemd is told not to restart on.
    """

    exit_code = 78


class EstimatorError(EdgedsmError, ValueError):
    """Bad arguments to an estimator (lag that does not fit the window, bad stack shape...)."""


class FrameError(EdgedsmError, ValueError):
    """A frame was refused at the boundary (shape, dtype, bit depth, layout)."""


class DeviceError(EdgedsmError):
    """A camera or relay misbehaved."""


class DeviceTimeout(DeviceError):
    """A device did not answer in time."""


class DeviceLost(DeviceError):
    """A device disappeared (cable pulled, process killed, control lost)."""
