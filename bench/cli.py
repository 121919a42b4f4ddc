"""The `bench` command line: discovers subcommands in :mod:`bench.commands`."""

from __future__ import annotations

import argparse
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


def build_parser() -> argparse.ArgumentParser:
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
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        parser = build_parser()
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
