"""The ``marionette`` command: one entry point, one sub-command per process or tool.

Each sub-command lives with the code it drives, in a module exposing
``register(subparsers)``, which adds its parser and sets ``func`` (args -> exit code).
Add a command by adding its module to ``COMMAND_MODULES``.

One error style for every sub-command (docs/errors.md): a mistake is answered by one line on
stderr, ``marionette <command>: <what is wrong and what to do>``, never a traceback unless
``--debug``; exit codes are 0 success, 1 failure or invalid input (a file that does not follow
its schema, an unknown name, an unreachable goal, a failed trial), 2 usage (argparse), 130
interrupted (Ctrl-C). The global options ``--lcm-url URL`` and ``--debug`` are accepted before
or after the sub-command.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
from typing import NoReturn

from marionette.processes import restore_stop_signals

COMMAND_MODULES: list[str] = [
    "marionette.planning.cli",
    "marionette.perception.cli",
    "marionette.footsteps.cli",
    "marionette.control.cli",
    "marionette.control.replay_cli",
    "marionette.execution.cli",
    "marionette.scenarios.cli",
    "marionette.viewer.cli",
    "marionette.models.cli",
]

EXIT_FAILURE, EXIT_USAGE, EXIT_INTERRUPTED = 1, 2, 130
# LCM's URL providers: udpm://ADDR:PORT?opts, file://PATH?mode=r|w, memq://, tcpq://HOST:PORT.
LCM_URL = re.compile(
    r"^(udpm://\d{1,3}(\.\d{1,3}){3}(:\d{1,5})?|memq://|file://[^?]+|tcpq://[^?]*)(\?.*)?$"
)
EXAMPLES = """examples:
  marionette demo                          # the plank flip (sets up nothing: run `make demo` once)
  marionette demo ur10-box --trials 5 --speed 0
  marionette plan ur10_box                 # a bundled problem, or any problem file
  marionette robot check models/panda      # a robot brought as data (docs/robots.md)
  marionette dg ls --lcm-url udpm://239.255.76.67:7667?ttl=0
"""


class Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one line (the problem, a "did you mean" for a mistyped
    choice, where the help is), exit code 2: every sub-parser is of this class (argparse makes
    sub-parsers of their parent's class)."""

    def error(self, message: str) -> NoReturn:
        m = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if m:
            import difflib

            choices = re.findall(r"'([^']*)'", m.group(2))
            close = difflib.get_close_matches(m.group(1), choices, n=1)
            if close:
                message += f"; did you mean {close[0]!r}?"
        self.exit(EXIT_USAGE, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _version(args: argparse.Namespace) -> int:
    import marionette

    print(marionette.__version__)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="marionette",
        description="Plan manipulation and walking with a constraint graph; execute it at 1 kHz.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--lcm-url",
        dest="global_lcm_url",
        default=None,
        metavar="URL",
        help="LCM URL of every process this command starts or talks to (default: "
        "$MARIONETTE_LCM_URL, else LCM's); accepted after the sub-command too",
    )
    parser.add_argument(
        "--debug", action="store_true", help="show the traceback of an error (after it too)"
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    sub.add_parser(
        "version",
        help="print the version",
        epilog="example:\n  marionette version",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    ).set_defaults(func=_version)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def split_global_options(argv: list[str]) -> tuple[list[str], str | None, bool]:
    """(argv without the global options, the ``--lcm-url`` value or None, ``--debug``): the
    global options may stand anywhere, before or after the sub-command."""
    rest: list[str] = []
    url, debug = None, False
    i = 0
    while i < len(argv):
        a = argv[i]
        if a == "--":
            rest += argv[i:]
            break
        if a == "--debug":
            debug = True
        elif a == "--lcm-url":
            if i + 1 >= len(argv):
                raise SystemExit(_usage_error("--lcm-url needs a URL"))
            url = argv[i + 1]
            i += 1
        elif a.startswith("--lcm-url="):
            url = a.split("=", 1)[1]
        else:
            rest.append(a)
        i += 1
    return rest, url, debug


def check_lcm_url(url: str) -> str | None:
    """None when ``url`` is a URL LCM accepts, else the one-line reason."""
    if LCM_URL.match(url):
        return None
    return (
        f"--lcm-url {url!r} is not an LCM URL; use udpm://239.255.76.67:7667?ttl=0 "
        "(ttl=0: this machine only; ttl=1 across a network), file://LOG?mode=r, memq:// or tcpq://"
    )


def _usage_error(message: str) -> int:
    print(f"marionette: {message}", file=sys.stderr)
    return EXIT_USAGE


def main(argv: list[str] | None = None) -> int:
    restore_stop_signals()
    argv = list(sys.argv[1:] if argv is None else argv)
    argv, url, debug = split_global_options(argv)
    if url is not None:
        problem = check_lcm_url(url)
        if problem is not None:
            return _usage_error(problem)
        os.environ["MARIONETTE_LCM_URL"] = url
    parser = build_parser()
    args = parser.parse_args(argv)
    if url is not None and getattr(args, "lcm_url", None) is None and hasattr(args, "lcm_url"):
        args.lcm_url = url
    command = " ".join(a for a in [args.command, *_subcommand(args)] if a)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"\nmarionette {command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SystemExit:
        raise
    except Exception as e:  # the one place every unexpected error is turned into one line
        if debug:
            raise
        print(f"marionette {command}: {describe_error(e)}", file=sys.stderr)
        return EXIT_FAILURE


def describe_error(e: BaseException) -> str:
    """One line for an exception: its message (first line), or its type when it has none; an
    error the program did not expect says how to see more."""
    text = str(e).strip()
    if isinstance(e, KeyError) and e.args and isinstance(e.args[0], str):
        text = e.args[0]
    first = text.splitlines()[0] if text else ""
    expected = _expected_errors()
    if isinstance(e, expected):
        return first or type(e).__name__
    detail = f"{type(e).__name__}: {first}" if first else type(e).__name__
    return f"{detail} (an internal error: rerun with --debug for the traceback and report it)"


def _expected_errors() -> tuple[type[BaseException], ...]:
    """Errors that report a user's input, environment or outcome (their message says what to
    do): a file, a name, a URL, a process that cannot start."""
    from marionette.footsteps.errors import FootstepError
    from marionette.robots import UnknownModel
    from marionette.schemas import DataFileError

    return (
        DataFileError,
        FootstepError,  # an impossible footstep problem, an unreachable goal
        UnknownModel,
        FileNotFoundError,
        PermissionError,
        ValueError,
        TimeoutError,
        RuntimeError,
    )


def _subcommand(args: argparse.Namespace) -> list[str]:
    return [
        str(v)
        for k, v in vars(args).items()
        if k.endswith("_command") and k != "command" and isinstance(v, str)
    ]


if __name__ == "__main__":
    sys.exit(main())
