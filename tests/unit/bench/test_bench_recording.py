"""`edgedsm bench recording`'s parts: the daemon config it shares with bench e2e validates, and a
recording trial is sustained only when neither the measurement nor the recorder dropped a frame."""

from __future__ import annotations

from pathlib import Path

from edgedsm_lab.bench.e2e_trial import Trial, daemon_config
from edgedsm_lab.bench.recording import Recorded


def test_the_bench_daemon_config_validates(tmp_path: Path) -> None:
    config = daemon_config(tmp_path / "frames.npy", 1883, tmp_path / "state", 30.0, 8, (256, 256))
    assert config.cadence.stats_interval_s == 1.0 and config.cadence.maps_interval_s == 10.0
    assert config.recording is None


def _trial(drops: int) -> Trial:
    return Trial("recording", 30.0, 30, 1.0, 10.0, delivered=300, processed=300, drops=drops, cpu_s=1.0, rss=0.0)


def test_a_recording_trial_is_sustained_only_without_any_drop() -> None:
    assert Recorded(_trial(0), 0, written=300, dropped=0, queued=0, mb=30.0).sustained
    assert not Recorded(_trial(0), 0, written=290, dropped=10, queued=0, mb=29.0).sustained
    assert not Recorded(_trial(3), 3, written=300, dropped=0, queued=0, mb=30.0).sustained
    timed = Recorded(_trial(0), 0, written=300, dropped=0, queued=0, mb=30.0, disk_s=12.0, mb_by_stop=24.0)
    assert timed.mb_s == 2.0 and timed.mb_per_frame == 0.1
