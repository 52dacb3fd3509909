"""The `palpate` command. Each sub-command lives in `palpate.commands.<name>` and registers itself."""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import os
import sys
import warnings
from typing import TextIO

from palpate.errors import MeshWarning, PalpateError

#: Sub-command modules, each with `register(subparsers)` that sets `func` on its parser.
COMMAND_MODULES = [
    "palpate.commands.launch",
    "palpate.commands.docs",
    "palpate.commands.keys",
    "palpate.commands.introspect",
    "palpate.commands.bag",
    "palpate.commands.bench",
    "palpate.commands.evaluate",
    "palpate.commands.view",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="palpate", description="Learn the shape of unknown objects by touch.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # a command not built yet
                continue
            raise
        module.register(sub)
    return parser


def parse(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse the command line; `NAME:=VALUE` arguments may also come after options
    (``palpate launch FILE --bus DIR seed:=3``), for the commands that take them (an ``args`` list)."""
    args, extra = parser.parse_known_args(argv)
    takes_assignments = isinstance(getattr(args, "args", None), list)
    late = [a for a in extra if takes_assignments and ":=" in a and not a.startswith("-")]
    unknown = [a for a in extra if a not in late]
    almost = [a for a in unknown if takes_assignments and "=" in a and not a.startswith("-")]
    if almost:  # name=value: the launch file's arguments take name:=value
        parser.error(f"launch argument {almost[0]!r} must look like name:=value")
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    if late:
        args.args = [*args.args, *late]
    return args


#: An error message longer than this is printed as its start and its end: one that echoes a bad value
#: in full (a 200,000-character argument name) would fill the terminal.
MAX_ERROR_CHARS = 4000


def shortened(message: str, limit: int = MAX_ERROR_CHARS) -> str:
    """`message`, or its first and last limit / 2 characters with how many were left out between."""
    if len(message) <= limit:
        return message
    half = limit // 2
    return f"{message[:half]} ... [{len(message) - 2 * half:,} characters left out] ... {message[-half:]}"


def _show_mesh_warnings(command: str) -> None:
    """Print palpate's mesh warnings as one line named by the command (Python's form shows our source);
    installed once per process, the command's name updated on each call."""
    _warning_command[0] = command
    if getattr(warnings.showwarning, "_palpate", False):
        return
    default = warnings.showwarning

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: TextIO | None = None,
        line: str | None = None,
    ) -> None:
        if issubclass(category, MeshWarning):
            print(f"palpate {_warning_command[0]}: warning: {message}", file=sys.stderr)
        else:
            default(message, category, filename, lineno, file, line)

    show._palpate = True  # type: ignore[attr-defined]
    warnings.showwarning = show


_warning_command = ["palpate"]  # the running command, for `_show_mesh_warnings`


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parse(parser, argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(message)s")
    _show_mesh_warnings(args.command)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # here, where a closed pipe is caught below, not at exit
        return code
    except PalpateError as exc:
        print(f"palpate {args.command}: {shortened(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # the reader stopped early (`palpate bag info LOG --json | head`): no error
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - Python flushes stdout again at exit
        return 0
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        # a full disk (or quota) is the machine's state, not a fault: say it in a line (an evaluation's
        # runs.jsonl keeps every run written before; --resume or --from-runs goes on from it)
        where = f" writing {exc.filename}" if exc.filename else ""
        print(
            f"palpate {args.command}: the disk is full ({exc.strerror}{where}); make room and run again "
            "(an evaluation: with --resume, or --from-runs for its tables)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
