"""The ``edgedsm`` command line: one sub-command per module in ``edgedsm.commands``.

Each command module exposes ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Errors edgedsm raises on purpose are printed as one clear message and end the process with the
error's ``exit_code`` and named by its ``kind`` (edgedsm.errors).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from edgedsm import __version__, terminal
from edgedsm.errors import ConfigError, EdgedsmError
from edgedsm.estimators.jit import configure_threading

COMMANDS = ("demo", "simulate", "analyze", "thsp", "tune", "record", "reproduce", "bench", "run", "check-config",
            "laser", "watch", "cmd", "probe", "init", "dashboard")

EXIT_ERROR = 1
EXIT_USAGE = 2
def command_named(argv: list[str]) -> str | None:
    """The command ``argv`` names (its first word that is not an option; the program's own options
    take no values), if it is one of ``COMMANDS``."""
    word = next((arg for arg in argv if not arg.startswith("-")), None)
    return word if word in COMMANDS else None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; with ``command``, only that command's module is imported (the others
    get an empty parser, enough to choose them): ``edgedsm cmd`` in a SCADA script then starts
    without importing the simulator, numba, the configuration models and the reports it does not
    use (several times faster: docs/bench-design.md)."""
    parser = argparse.ArgumentParser(
        prog="edgedsm",
        description="Dynamic speckle activity maps (S1, S2, S3 of Levchenko et al. 2022): "
                    "simulate speckle, compute maps, run the factory daemon.",
        epilog="Run 'edgedsm COMMAND --help' for the options of one command; 'edgedsm completion bash' prints "
               "the shell completion.",
    )
    parser.add_argument("--version", action="version", version=f"edgedsm {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        if command is not None and name != command:
            sub.add_parser(name)
            continue
        module_name = f"edgedsm.commands.{name.replace('-', '_')}"
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:
                continue  # command not part of this build
            raise
        chosen = sub.add_parser(module.NAME, help=module.HELP, description=module.__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(chosen)
        chosen.set_defaults(handler=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    configure_threading()  # before any kernel starts numba's threads
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == ["completion"]:  # `edgedsm completion bash`: the whole command line, as a script
        return terminal.completion(argv[1:], build_parser())
    parser = build_parser(command_named(argv))
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        code = int(args.handler(args) or 0)
        if sys.stdout is not None:  # None: started with stdout closed
            sys.stdout.flush()  # a reader gone (`| head`) is met here, not in a traceback at exit
        return code
    except BrokenPipeError:
        if not terminal.stdout_closed():
            raise
        return terminal.end_quietly()
    except ConfigError as exc:
        # one line per problem (each with its key path), so a file with three mistakes is fixed at once
        print(f"edgedsm: configuration error:\n{exc}", file=sys.stderr)
        return exc.exit_code
    except EdgedsmError as exc:
        print(f"edgedsm: {exc.kind}: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("edgedsm: interrupted", file=sys.stderr)
        return 130
