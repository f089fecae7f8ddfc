"""Contract checks for your own camera and relay drivers (see docs/drivers.md).

From your own test file (pytest or any other runner; this package does not import pytest)::

    from edgedsm.testing import RelayRig, check_camera_contract, check_relay_contract

    def test_my_camera():
        check_camera_contract(lambda: MyCamera("my device"))     # a new, unopened camera

    def test_my_relay():
        board = MyBoardEmulator()
        check_relay_contract(RelayRig(open=lambda: MyRelay(board.port), is_on=lambda: board.is_on,
                                      readback=True, force=board.set))

Each check is also available alone in ``CAMERA_CHECKS`` / ``RELAY_CHECKS`` (name -> function),
to parametrize one test per check. A failed check raises ``AssertionError`` saying what was
expected and what the driver did.
"""

from edgedsm.testing.camera import (
    CAMERA_CHECKS,
    CameraFactory,
    check_bad_settings_refused,
    check_camera_contract,
    check_frames,
    check_frames_after_reopen,
    check_lifecycle,
)
from edgedsm.testing.relay import (
    RELAY_CHECKS,
    RelayRig,
    check_relay_close_leaves_it_off,
    check_relay_closed_refuses,
    check_relay_contract,
    check_relay_exit_on_exception_leaves_it_off,
    check_relay_readback_is_reported_honestly,
    check_relay_safety_off_at_start_and_on_error,
    check_relay_sigterm_leaves_it_off,
)

__all__ = [
    "CAMERA_CHECKS",
    "RELAY_CHECKS",
    "CameraFactory",
    "RelayRig",
    "check_bad_settings_refused",
    "check_camera_contract",
    "check_frames",
    "check_frames_after_reopen",
    "check_lifecycle",
    "check_relay_close_leaves_it_off",
    "check_relay_closed_refuses",
    "check_relay_contract",
    "check_relay_exit_on_exception_leaves_it_off",
    "check_relay_readback_is_reported_honestly",
    "check_relay_safety_off_at_start_and_on_error",
    "check_relay_sigterm_leaves_it_off",
]
