"""The command line in a shell (edgedsm.terminal): a closed pipe ends a command quietly, and the
bash completion script completes commands, options and choices in a real bash."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from edgedsm.cli import build_parser, main
from edgedsm.terminal import EXIT_PIPE_CLOSED, bash_completion

REPO = Path(__file__).resolve().parents[2]


def _closed_pipe_run(*args: str) -> subprocess.CompletedProcess[str]:
    """``python -m edgedsm ARGS`` with a stdout whose reader has gone (``| head`` after its lines)."""
    read, write = os.pipe()
    os.close(read)
    try:
        return subprocess.run([sys.executable, "-m", "edgedsm", *args], stdout=write, stderr=subprocess.PIPE,
                              text=True, cwd=REPO, timeout=120)
    finally:
        os.close(write)


def test_check_config_into_a_closed_pipe_ends_quietly() -> None:
    done = _closed_pipe_run("check-config", "config/daemon/demo.toml")
    assert done.returncode == EXIT_PIPE_CLOSED == 141
    assert "Traceback" not in done.stderr and "BrokenPipe" not in done.stderr, done.stderr
    assert done.stderr == ""


def test_a_broken_pipe_that_is_not_stdout_still_raises(monkeypatch: pytest.MonkeyPatch) -> None:
    # stdout is read (pytest's capture): an EPIPE from elsewhere (a socket, a relay) is a real error
    import edgedsm.commands.check_config as check_config

    def broken(args: object) -> int:
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(check_config, "run", broken)
    with pytest.raises(BrokenPipeError):
        main(["check-config", "whatever.toml"])


def _complete(script: Path, *words: str) -> list[str]:
    """COMPREPLY of the edgedsm completion for the command line ``words`` (the last: the word typed)."""
    bash = shutil.which("bash")
    assert bash is not None, "bash is needed for the completion test"
    line = " ".join(f"'{word}'" for word in words)
    program = (f"source {script}; COMP_WORDS=(edgedsm {line}); COMP_CWORD={len(words)}; _edgedsm; "
               'printf "%s\\n" "${COMPREPLY[@]}"')
    done = subprocess.run([bash, "--norc", "--noprofile", "-c", program], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    return [line for line in done.stdout.splitlines() if line]


def test_bash_completes_commands_options_and_choices(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["completion", "bash"]) == 0
    script = tmp_path / "edgedsm.bash"
    script.write_text(capsys.readouterr().out)
    assert script.read_text() == bash_completion(build_parser())
    assert _complete(script, "r") == ["record", "reproduce", "run"]
    assert _complete(script, "")[:3] == ["analyze", "bench", "check-config"]
    assert "completion" in _complete(script, "")
    assert _complete(script, "run", "--") == ["--config", "--help"]
    assert _complete(script, "check-config", "--j") == ["--json"]
    assert _complete(script, "cmd", "--dev") == ["--device"]
    assert _complete(script, "laser", "o") == ["on", "off"]  # a positional argument's choices
    assert _complete(script, "completion", "") == ["bash"]
    estimators = _complete(script, "analyze", "--estimator", "s")  # an option's choices
    assert {"s1", "s2", "s3"} <= set(estimators) and all(name.startswith("s") for name in estimators)
    assert _complete(script, "-v", "watch", "--ti") == ["--timeout"]  # the program's own options before


def test_completion_of_another_shell_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["completion", "fish"]) == 2
    assert "usage: edgedsm completion {bash}" in capsys.readouterr().err
    assert main(["completion", "--help"]) == 0
    assert "/etc/bash_completion.d/edgedsm" in capsys.readouterr().out
