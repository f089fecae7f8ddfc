"""The command line's manners in a shell: a reader that closed the pipe early (``edgedsm
check-config FILE | head -2``) ends the command quietly, and ``edgedsm completion bash`` prints
the bash completion of every command and option (docs/integration.md, "Scripts")."""

from __future__ import annotations

import argparse
import os
import select
import shlex
import sys

from edgedsm import __version__

#: Exit status after the reader closed stdout: 128 + SIGPIPE, what a shell reports for a command
#: the signal ended (``yes | head`` under ``set -o pipefail``).
EXIT_PIPE_CLOSED = 141
SHELLS = ("bash",)


def stdout_closed() -> bool:
    """Whether nobody reads our stdout any more (the read end of its pipe is closed): poll()
    says POLLERR on such a pipe. False for a terminal, a file, or a reader still there."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))
    except (OSError, ValueError, AttributeError):
        return False


def end_quietly() -> int:
    """After a BrokenPipeError on stdout: point stdout at /dev/null (the interpreter's flush at
    exit would fail on the closed pipe again and print a traceback) and return
    :data:`EXIT_PIPE_CLOSED`."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    finally:
        os.close(devnull)
    return EXIT_PIPE_CLOSED


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse keeps its sub-parsers here and nowhere public
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _words(values: object) -> str:
    return " ".join(shlex.quote(str(value)) for value in values)  # type: ignore[attr-defined]


def bash_completion(parser: argparse.ArgumentParser) -> str:
    """A bash completion script for ``parser`` (edgedsm's whole command line): the commands, each
    command's options, the values of options and arguments with choices; anything else completes
    as a file name (configs, recordings, output folders)."""
    commands = _subcommands(parser)
    top = [option for action in parser._actions for option in action.option_strings]
    options, values = [], []
    for name, sub in sorted(commands.items()):
        flags = sorted(option for action in sub._actions for option in action.option_strings)
        positional = [choice for action in sub._actions if not action.option_strings and action.choices
                      for choice in action.choices]
        options.append(f"        {shlex.quote(name)}) options={shlex.quote(' '.join(flags))}; "
                       f"words={shlex.quote(_words(positional))} ;;")
        for action in sub._actions:
            if action.option_strings and action.choices:
                patterns = "|".join(shlex.quote(f"{name} {option}") for option in action.option_strings)
                values.append(f"        {patterns}) COMPREPLY=($(compgen -W {shlex.quote(_words(action.choices))}"
                              f' -- "$cur")); return ;;')
    body = "\n".join(options)
    chosen = "\n".join(values) or "        '') ;;"
    return f"""# bash completion for edgedsm {__version__} (printed by `edgedsm completion bash`)
_edgedsm() {{
    local cur="${{COMP_WORDS[COMP_CWORD]}}" prev="${{COMP_WORDS[COMP_CWORD-1]}}" command="" word i
    for ((i = 1; i < COMP_CWORD; i++)); do
        word="${{COMP_WORDS[i]}}"
        case "$word" in -*) ;; *) command="$word"; break ;; esac
    done
    if [[ -z "$command" ]]; then
        COMPREPLY=($(compgen -W {shlex.quote(' '.join([*sorted(commands), 'completion', *top]))} -- "$cur"))
        return
    fi
    local options="" words=""
    case "$command" in
{body}
        completion) words={shlex.quote(' '.join(SHELLS))} ;;
    esac
    case "$command $prev" in
{chosen}
    esac
    if [[ "$cur" == -* ]]; then
        COMPREPLY=($(compgen -W "$options" -- "$cur"))
    elif [[ -n "$words" ]]; then
        COMPREPLY=($(compgen -W "$words" -- "$cur"))
    fi
}}
complete -o default -o bashdefault -F _edgedsm edgedsm
"""


def completion(argv: list[str], parser: argparse.ArgumentParser) -> int:
    """``edgedsm completion SHELL``: print the completion script; 2 (usage) for another shell."""
    if argv in (["-h"], ["--help"]):
        print("usage: edgedsm completion bash\n\nPrint the bash completion of edgedsm's commands and options. "
              "Install it once:\n  edgedsm completion bash | sudo tee /etc/bash_completion.d/edgedsm\n"
              "or for yourself, in ~/.bashrc:\n  source <(edgedsm completion bash)")
        return 0
    if argv != ["bash"]:
        print(f"usage: edgedsm completion {{{','.join(SHELLS)}}}", file=sys.stderr)
        return 2
    sys.stdout.write(bash_completion(parser))
    return 0
