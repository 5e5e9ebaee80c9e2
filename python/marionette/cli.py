"""The ``marionette`` command: one entry point, one sub-command per process or tool.

Each sub-command lives with the code it drives, in a module exposing
``register(subparsers)``, which adds its parser and sets ``func`` (args -> exit code).
Add a command by adding its module to ``COMMAND_MODULES``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

COMMAND_MODULES: list[str] = [
    "marionette.planning.cli",
    "marionette.perception.cli",
    "marionette.footsteps.cli",
    "marionette.control.cli",
    "marionette.control.replay_cli",
    "marionette.execution.cli",
    "marionette.execution.demo_cli",
    "marionette.viewer.cli",
]


def _version(args: argparse.Namespace) -> int:
    import marionette

    print(marionette.__version__)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="marionette",
        description="Plan manipulation and walking with a constraint graph; execute it at 1 kHz.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    sub.add_parser("version", help="print the version").set_defaults(func=_version)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from marionette.lcm_signing import KeyFileError

    try:
        return int(args.func(args) or 0)
    except KeyFileError as e:  # MARIONETTE_KEY names a file that cannot be the shared key
        print(f"marionette {args.command}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
