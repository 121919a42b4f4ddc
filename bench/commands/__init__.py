"""One module per `bench` subcommand, found at start-up (cantools' subparsers style).

A command module defines ``register(subparsers) -> None``, which adds its parser and
sets ``func=`` to a callable taking the parsed args and returning an exit code.
"""
