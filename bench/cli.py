"""The `bench` command line: discovers subcommands in :mod:`bench.commands`.

Only the command being run is imported (a module per command, named as the command):
importing them all would cost every start the live path's python-can, rich tables and
more (a sixth of a whole `bench replay`); ``bench --help``, completion and anything
unexpected still build the whole tree."""

from __future__ import annotations

import argparse
import gc
import importlib
import pkgutil
import sys
from collections.abc import Sequence
from typing import NoReturn

from bench import __version__, commands
from bench.errors import BenchError


class OneLineParser(argparse.ArgumentParser):
    """argparse with its errors on one line (``bench run: error: ...``), not after a usage
    block that buries them; ``--help`` still shows the usage. Subcommands inherit it."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def command_names() -> list[str]:
    """The modules of :mod:`bench.commands` (found without importing them)."""
    return sorted(m.name for m in pkgutil.iter_modules(commands.__path__))


TOP_FLAGS = ("--print-config",)
"""The top-level options that may come before a command and leave its parser enough."""


def named_command(argv: Sequence[str]) -> str | None:
    """The command ``argv`` runs, when its parser alone can parse it; None when the whole
    tree is needed (no command, ``--help``, ``--completion``, an abbreviated option, an
    unknown name: argparse's messages must list every choice)."""
    for arg in argv:
        if arg in TOP_FLAGS:
            continue
        if arg.startswith("-"):
            return None
        return arg if arg in command_names() else None
    return None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or of ``command`` alone (when its module registers it;
    else of every command)."""
    parser = OneLineParser(
        prog="bench", description="Hardware-in-the-loop bench for the ACB-3 gradient board."
    )
    parser.add_argument("--version", action="version", version=f"bench {__version__}")
    parser.add_argument(
        "--print-config",
        action="store_true",
        help="show the interface, channel, bitrate, calibration sheet and log folder a command "
        "would use and where each came from (bench.toml, BENCH_*, ...), then exit",
    )
    parser.add_argument(
        "--completion",
        choices=("bash", "zsh"),
        metavar="SHELL",
        help="print a completion script for bash or zsh and exit "
        '(e.g. eval "$(bench --completion bash)" in ~/.bashrc)',
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    if command is not None:
        _register(sub, command)
        if command in sub.choices:
            return parser
        return build_parser()  # a helper module, not a command: the whole tree's message
    for name in command_names():
        _register(sub, name)
    return parser


def _register(sub: argparse._SubParsersAction, name: str) -> None:
    module = importlib.import_module(f"{commands.__name__}.{name}")
    register = getattr(module, "register", None)
    if register is not None:
        register(sub)


def main(argv: Sequence[str] | None = None) -> int:
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        parser = build_parser(named_command(argv))
        args = parser.parse_args(argv)
        if args.completion:
            import shtab

            print(shtab.complete(parser, shell=args.completion), end="")
            return 0
        from bench import defaults

        defaults.layers()  # a bad defaults file or BENCH_* value: one line, whatever the command
        if args.print_config:
            defaults.print_config(args)
            return 0
        defaults.apply_bus_defaults(args)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        return int(args.func(args) or 0)
    except BenchError as exc:
        print(f"bench: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


def program() -> int:
    """The `bench` program (its console script and ``python -m bench``): :func:`main`, then
    every object frozen out of the collection the interpreter makes on its way out, which
    would walk them all (the modules, numba's kernels: over 100 000) only to free nothing
    the exit does not free anyway (0.1 s of a replay's CPU)."""
    code = main()
    gc.freeze()
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(program())
