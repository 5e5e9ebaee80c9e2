"""The ``marionette`` command: one entry point, one sub-command per process or tool."""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="marionette", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("version", help="print the version")
    args = parser.parse_args(argv)
    if args.command == "version":
        import marionette

        print(marionette.__version__)
        return 0
    return 2


if __name__ == "__main__":
    sys.exit(main())
