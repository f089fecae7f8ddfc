"""τc settings of the daemon config: estimator.activity = 'tau_c', estimator.tau_c, max_lag and
regions' wet_below_s / dry_above_s (bounded, exclusive, checked against K·Δt when Δt is known)."""

from __future__ import annotations

import pytest

from edgedsm.cli import main
from edgedsm.config import DaemonConfig, load_config
from edgedsm.daemon.reload import restart_reasons
from edgedsm.errors import ConfigError
from edgedsm.validation import validate

CAMERA = "[camera]\nuri = 'sim:default'\n"
TAU_REGION = "[[regions]]\nname = 'plate'\nwet_below_s = 0.2\ndry_above_s = 0.5\n"


def test_tau_c_is_off_unless_asked_for_or_needed():
    plain = validate(DaemonConfig, {"camera": {"uri": "sim:default"}}, "<plain>")
    assert not plain.tau_c_on and plain.estimator.lags == 100  # N/2 with N = 200
    asked = validate(DaemonConfig, {"camera": {"uri": "sim:default"}, "estimator": {"tau_c": True}}, "<asked>")
    assert asked.tau_c_on and asked.regions[0].thresholds().on_tau is False
    needed = validate(DaemonConfig, {"camera": {"uri": "sim:default"}, "regions": [
        {"name": "a", "wet_above": 0.3, "dry_below": 0.1},
        {"name": "b", "wet_below_s": 0.2, "dry_above_s": 0.5}]}, "<needed>")
    assert needed.tau_c_on and [r.on_tau for r in needed.regions] == [False, True]
    th = needed.regions[1].thresholds()
    assert th.on_tau and th.wet_above == pytest.approx(5.0) and th.dry_below == pytest.approx(2.0)
    judged = validate(DaemonConfig, {"camera": {"uri": "sim:default"}, "estimator": {"activity": "tau_c", "window": 50,
                                                                                     "lag": 2}, "regions": [
        {"name": "b", "wet_below_s": 0.2, "dry_above_s": 0.5}]}, "<judged>")
    assert judged.tau_c_on and judged.estimator.lags == 25  # N/2, N = 50


@pytest.mark.parametrize(("text", "message"), [
    (CAMERA + "[estimator]\nactivity = 'tau_c'\n[[regions]]\nname = 'a'\nwet_above = 2\ndry_below = 1\n",
     "regions.0.wet_above: estimator.activity = 'tau_c' judges every region on its τc in seconds"),
    (CAMERA + "[[regions]]\nname = 'a'\nwet_above = 2\ndry_below = 1\nwet_below_s = 0.2\ndry_above_s = 0.5\n",
     "regions.0: Value error, give either wet_above/dry_below (activity) or wet_below_s/dry_above_s"),
    (CAMERA + "[[regions]]\nname = 'a'\nwet_below_s = 0.5\ndry_above_s = 0.2\n",
     "regions.0: Value error, need 0 < wet_below_s (0.5) < dry_above_s (0.2)"),
    (CAMERA + "[[regions]]\nname = 'a'\nwet_below_s = 0.48\ndry_above_s = 0.5\n",
     "the hysteresis bands of wet_below_s and dry_above_s overlap"),
    (CAMERA + "[[regions]]\nname = 'a'\nwet_below_s = 0.2\n", "regions.0: Value error, give both wet_below_s and "
                                                             "dry_above_s"),
    (CAMERA + "[[regions]]\nname = 'a'\n", "drying thresholds missing"),
    (CAMERA + "[[regions]]\nname = 'a'\nwet_below_s = 0\ndry_above_s = 0.5\n",
     "regions.0.wet_below_s: Input should be greater than 0"),
    (CAMERA + "[estimator]\nwindow = 20\nlag = 2\nmax_lag = 19\n",
     "estimator: Value error, max_lag K=19 does not fit a window of N=20 frames (need 1 <= K <= N-2)"),
    (CAMERA + "[estimator]\nmax_lag = 0\n", "estimator.max_lag: Input should be greater than or equal to 1"),
    (CAMERA + "[estimator]\ntau_c = true\nmode = 'exponential'\n",
     "estimator: Value error, tau_c: τc needs mode 'sliding' or 'tumbling', not 'exponential'"),
    (CAMERA + "[estimator]\nactivity = 'tau_c'\nmode = 'exponential'\n" + TAU_REGION,
     "estimator: Value error, activity: τc needs mode 'sliding' or 'tumbling'"),
    (CAMERA + "[estimator]\nmode = 'exponential'\n" + TAU_REGION,
     "regions.0.wet_below_s: τc thresholds in seconds: estimator.mode: τc needs mode 'sliding' or 'tumbling'"),
    (CAMERA + "frame_interval_s = 0.05\n[estimator]\nwindow = 20\nlag = 5\n" + TAU_REGION,
     "regions.0: dry_above_s (0.5 s; 0.5263 s with the hysteresis) is beyond the longest τc measured, "
     "estimator.max_lag x Δt = 10 x 0.05 s = 0.5 s"),
    (CAMERA + "frame_interval_s = 0.7\n[estimator]\nwindow = 100\nlag = 5\n" + TAU_REGION,
     "wet_below_s (0.2 s; 0.1905 s with the hysteresis) is below the shortest τc measured, Δt/3 = 0.2333 s"),
    (CAMERA + "[estimator]\nactivity = 'tau'\n",
     "estimator.activity: Input should be 's1', 's2', 's3', 'tau_c', 'contrast', 'fujii', 'im', 'gd', 'band_ratio' "
     "or 'kinetics'"),
])
def test_bad_tau_settings_name_their_key_and_exit_78(tmp_path, capsys, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"bad\.toml"):
        load_config(path)
    assert main(["check-config", str(path)]) == 78
    assert message in capsys.readouterr().err


def test_tau_thresholds_that_fit_k_dt_are_accepted(tmp_path):
    path = tmp_path / "good.toml"
    path.write_text(CAMERA + "frame_interval_s = 0.05\n[estimator]\nwindow = 100\nlag = 5\nmax_lag = 20\n"
                    + TAU_REGION)
    config = load_config(path)
    assert config.tau_c_on and config.estimator.lags == 20


def test_switching_a_region_to_tau_thresholds_restarts_the_measurement():
    base = {"camera": {"uri": "sim:default"}}
    on_activity = validate(DaemonConfig, {**base, "regions": [{"name": "a", "wet_above": 0.3, "dry_below": 0.1}]}, "x")
    on_tau = validate(DaemonConfig, {**base, "regions": [{"name": "a", "wet_below_s": 0.2, "dry_above_s": 0.5}]}, "x")
    retuned = validate(DaemonConfig, {**base, "regions": [{"name": "a", "wet_below_s": 0.3, "dry_above_s": 0.6}]}, "x")
    assert restart_reasons(on_tau, on_activity) == ["τc on/off"]  # the engine must keep τc's sums
    assert restart_reasons(retuned, on_tau) == []  # new seconds: applied in place
