"""``[kinetics]`` in the daemon config: off by default, every field bounded, the activity
'kinetics' accepted only with it on and every region in seconds below the longest age; the
schema and check-config follow (issue 37)."""

from __future__ import annotations

import json

import pytest

from edgedsm.cli import main
from edgedsm.config import DaemonConfig, load_config
from edgedsm.config.kinetics import KineticsSection
from edgedsm.daemon.reload import restart_reasons
from edgedsm.errors import ConfigError
from edgedsm.estimators import registry
from edgedsm.estimators.kinetics import slot_schedule
from edgedsm.validation import validate

CAMERA = "[camera]\nuri = 'sim:default'\n"
SECONDS = "[[regions]]\nname = 'plate'\nwet_below_s = 0.5\ndry_above_s = 60\n"
ON = "[kinetics]\nenabled = true\nlongest_age_s = 600\n"


def test_off_by_default_and_its_frames_follow_the_interval():
    config = validate(DaemonConfig, {"camera": {"uri": "sim:default"}}, "<plain>")
    assert config.kinetics.enabled is False and config.kinetics.step is None  # the step each region's size asks
    section = KineticsSection(enabled=True, longest_age_s=3600.0, per_octave=4)
    assert section.longest_age(0.1) == 36_000 and section.longest_age(7200.0) == 2  # at least one reference
    assert section.slots(0.1) == 75  # docs/kinetics.md's table: 36,000 frames at 4 per octave
    with pytest.raises(ValueError, match="frame interval"):
        section.longest_age(0.0)


def test_the_activity_is_the_registry_s_and_judges_seconds(tmp_path):
    assert "kinetics" in registry.activities()
    record = registry.get("kinetics")
    assert record.unit == "s" and record.region_level and not record.streams and record.cost == "O(R)"
    assert record.mode_problem("exponential") is None  # its own reference frames: any window mode
    path = tmp_path / "k.toml"
    path.write_text(CAMERA + "[estimator]\nactivity = 'kinetics'\nmode = 'exponential'\n" + ON + SECONDS)
    config = load_config(path)
    assert not config.tau_c_on  # seconds thresholds judge the kinetics, not τc
    assert config.estimator.maps == ("s1", "s2", "s3")  # no engine map of it
    assert config.regions[0].thresholds().on_tau


@pytest.mark.parametrize(("text", "message"), [
    (CAMERA + "[estimator]\nactivity = 'kinetics'\n" + SECONDS,
     "estimator.activity: 'kinetics' judges each region on its decorrelation time: it needs [kinetics] enabled"),
    (CAMERA + "[estimator]\nactivity = 'kinetics'\n" + ON + "[[regions]]\nname = 'a'\nwet_above = 2\ndry_below = 1\n",
     "regions.0.wet_above: estimator.activity = 'kinetics' judges every region"),
    (CAMERA + "[estimator]\nactivity = 'kinetics'\n" + ON + "[[regions]]\nname = 'a'\nwet_below_s = 1\n"
     "dry_above_s = 590\n", "regions.0.dry_above_s: 590 s (with its hysteresis 0.05) is not below"),
    (CAMERA + "[kinetics]\nenabled = true\nper_octave = 17\n", "kinetics.per_octave: Input should be less than or"),
    (CAMERA + "[kinetics]\nlongest_age_s = 0\n", "kinetics.longest_age_s: Input should be greater than 0"),
    (CAMERA + "[kinetics]\nstep = 17\n", "kinetics.step: Input should be less than or equal to 16"),
    (CAMERA + "[kinetics]\nrefs = 4\n", "kinetics.refs: unknown key"),
])
def test_bad_kinetics_exits_78_with_the_key_path(tmp_path, capsys, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")
                       .replace("]", r"\]")):
        load_config(path)
    assert main(["check-config", str(path)]) == 78
    assert message in capsys.readouterr().err


def test_schema_describes_every_field_and_a_change_restarts(capsys, tmp_path):
    assert main(["check-config", "--schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    section = schema["$defs"]["KineticsSection"]
    assert section["additionalProperties"] is False
    assert all(field.get("description") for field in section["properties"].values())
    step = next(choice for choice in section["properties"]["step"]["anyOf"] if choice.get("type") == "integer")
    assert step["maximum"] == 16 and section["properties"]["per_octave"]["minimum"] == 1
    running = validate(DaemonConfig, {"camera": {"uri": "sim:default"}}, "<a>")
    new = validate(DaemonConfig, {"camera": {"uri": "sim:default"}, "kinetics": {"enabled": True}}, "<b>")
    assert restart_reasons(new, running) == ["kinetics"]


def test_check_config_says_what_the_kinetics_keep(tmp_path, capsys):
    path = tmp_path / "k.toml"
    path.write_text(CAMERA + "frame_interval_s = 0.1\n[estimator]\nactivity = 'kinetics'\n" + ON + "step = 4\n"
                    "[[kinetics.stages]]\nname = 'tack_free'\nrate_below_hz = 0.05\n" + SECONDS)
    assert main(["check-config", str(path)]) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    slots = slot_schedule(6000, 4)[0].size  # 600 s at 0.1 s: 6,000 frames; slots + 1 buffers of 4 bytes
    assert slots > 50
    assert line == (f"kinetics: on, τ up to 600 s, 4 per octave, every 4th pixel each way; {slots} reference "
                    f"frames ({(slots + 1) * 4} bytes per kept pixel) at Δt = 0.1 s; stages: tack_free at 0.05 Hz")
    assert main(["check-config", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["kinetics"]["step"] == 4


def test_the_default_step_keeps_a_region_within_the_cost_budget():
    section = KineticsSection(enabled=True)
    assert section.step_for(128 * 128) == 1 and section.step_for(128 * 128 + 1) == 2  # small regions: every pixel
    assert section.step_for(2048 * 1024) == 12  # half a 2048² frame: 14,564 pixels kept, ~0.06x the default push
    assert 2048 * 1024 / section.step_for(2048 * 1024) ** 2 <= 16_384
    assert section.step_for(10 ** 9) == 16  # at most MAX_STEP
    assert KineticsSection(enabled=True, step=3).step_for(10 ** 6) == 3  # a step given is kept
