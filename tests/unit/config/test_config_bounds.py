"""Bad configuration input is refused with one clear ConfigError (exit 78), never a traceback or a hang."""

from __future__ import annotations

import os
import re

import pytest

from edgedsm.cli import main
from edgedsm.config import load_config
from edgedsm.errors import ConfigError
from edgedsm.sim import load_scene
from edgedsm.validation import MAX_FILE_BYTES, MAX_NESTING

CAMERA = "[camera]\nuri = 'sim:default'\n"


def _write(tmp_path, content: bytes | str, name: str = "c.toml"):
    path = tmp_path / name
    if isinstance(content, str):
        path.write_text(content)
    else:
        path.write_bytes(content)
    return path


def _refused(path, capsys, message: str) -> str:
    with pytest.raises(ConfigError, match=message):
        load_config(path)
    assert main(["check-config", str(path)]) == 78
    err = capsys.readouterr().err
    assert "Traceback" not in err and re.search(message, err)
    return err


def test_non_utf8_bytes_are_a_config_error(tmp_path, capsys):
    path = _write(tmp_path, CAMERA.encode() + b"# caf\xe9\n")
    _refused(path, capsys, "not UTF-8 text")


def test_random_binary_is_a_config_error(tmp_path, capsys):
    path = _write(tmp_path, bytes(range(256)) * 4)
    _refused(path, capsys, "not UTF-8 text")


def test_oversized_file_is_refused_without_reading_it_all(tmp_path, capsys):
    path = _write(tmp_path, CAMERA + "#" * MAX_FILE_BYTES + "\n")
    _refused(path, capsys, "larger than")


@pytest.mark.timeout(20)
def test_config_symlinked_to_dev_zero_does_not_hang(tmp_path, capsys):
    path = tmp_path / "zero.toml"
    os.symlink("/dev/zero", path)
    _refused(path, capsys, "not a regular file")


def test_deeply_nested_toml_is_a_config_error(tmp_path, capsys):
    depth = 5000
    path = _write(tmp_path, CAMERA + "x = " + "[" * depth + "]" * depth + "\n")
    _refused(path, capsys, "nested")


def test_moderate_nesting_beyond_the_limit_is_refused(tmp_path, capsys):
    depth = MAX_NESTING + 1
    path = _write(tmp_path, CAMERA + "x = " + "[" * depth + "]" * depth + "\n")
    _refused(path, capsys, "nested more than")


@pytest.mark.parametrize(("text", "message"), [
    ("[estimator]\nwindow = '100'", r"estimator\.window: Input should be a valid integer"),
    ("[estimator]\nq = '1.0'", r"estimator\.q: Input should be a valid number"),
    ("[estimator]\nambient_correction = 'true'", r"estimator\.ambient_correction: Input should be a valid boolean"),
    ("[estimator]\nambient_correction = 1", r"estimator\.ambient_correction: Input should be a valid boolean"),
    ("[estimator]\nwindow = 100.5", r"estimator\.window: Input should be a valid integer"),
    ("[acquisition]\ndark_frames = true", r"acquisition\.dark_frames: Input should be a valid integer"),
    ("[mqtt]\nport = '1883'", r"mqtt\.port: Input should be a valid integer"),
    ("[estimator]\nq = nan", r"estimator\.q: Input should be a finite number"),
    ("[camera]\nuri = 'sim:default'\nexposure_us = inf", r"camera\.exposure_us: Input should be a finite number"),
    ("[device]\nname = 1979-05-27", r"device\.name: Input should be a valid string"),
])
def test_strings_are_not_numbers(tmp_path, capsys, text, message):
    if "[camera]" not in text:
        text = CAMERA + text
    _refused(_write(tmp_path, text), capsys, message)


def test_a_number_where_a_float_is_expected_is_fine(tmp_path):
    config = load_config(_write(tmp_path, CAMERA + "[estimator]\nq = 2\n"))
    assert config.estimator.q == 2.0


def test_scene_files_are_bounded_too(tmp_path):
    with pytest.raises(ConfigError, match="not UTF-8 text"):
        load_scene(_write(tmp_path, b"[activity]\ntau_c = 5 # \xff\n", "s.toml"))
    with pytest.raises(ConfigError, match=r"activity\.tau_c: Input should be a valid number"):
        load_scene(_write(tmp_path, "[activity]\ntau_c = '5'\n", "s.toml"))


def test_empty_file_does_not_silently_pick_the_simulated_camera(tmp_path, capsys):
    _refused(_write(tmp_path, ""), capsys, r"camera: Field required")


def test_camera_table_without_uri_is_refused(tmp_path, capsys):
    _refused(_write(tmp_path, "[camera]\nexposure_us = 100\n"), capsys, r"camera\.uri: Field required")


@pytest.mark.parametrize(("text", "message"), [
    ('[camera]\nuri = "replay:a\\u0000b"', r"camera\.uri: contains a NUL character"),
    ('[camera]\nuri = "sim:a\\u0000b"', r"camera\.uri: contains a NUL character"),
    (CAMERA + '[device]\nstate_dir = "a\\u0000b"', r"device\.state_dir: contains a NUL character"),
    (CAMERA + '[[regions]]\nname = "m"\nshape = "mask"\npath = "\\u0000"\nwet_above = 2\ndry_below = 1',
     r"regions\.0\.path: contains a NUL character"),
    ('[camera]\nuri = "replay:/dev/zero"', r"camera\.uri: .*/dev/zero: not a recording"),
    ('[camera]\nuri = "sim:/dev/zero"', r"camera\.uri: .*/dev/zero: not a regular file"),
])
def test_paths_the_system_cannot_use_are_refused_at_load(tmp_path, capsys, text, message):
    _refused(_write(tmp_path, text), capsys, message)
