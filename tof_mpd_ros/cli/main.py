"""Entry point of ``tof-mpd``.

Every subcommand lives in its own module of this package and exposes
``register(subparsers) -> None``; the parser it adds sets ``func(args) -> int``. Inputs are
positional and every written output is ``-o/--output`` (:mod:`.output`). Library errors
(:class:`~tof_mpd_ros.errors.TofMpdError`) and a command line in the old positional-output form
become one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from ..errors import TofMpdError
from ..machine import set_openmp_wait_policy
from .output import CliParser, OldOutputForm

# Subcommand modules, in the order ``--help`` lists them. A module that fails to import (for
# example because an optional dependency is missing) is reported when its command is used.
SUBCOMMAND_MODULES = (
    "recording", "sim", "calibrate", "train", "correct", "evaluate", "benchmark",
    "mismatch", "demo",
)


def build_parser() -> argparse.ArgumentParser:
    parser = CliParser(
        prog="tof-mpd",
        description="Remove multipath distortion from ToF range images: simulate, record, "
                    "train, correct, evaluate and diagnose sim-vs-real mismatch.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(f"{__package__}.{name}")
        except ModuleNotFoundError as err:
            if err.name and err.name.startswith(f"{__package__}.{name}"):
                continue  # not built yet
            raise
        module.register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    set_openmp_wait_policy()  # before a command loads numba or torch
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(argv)
    except OldOutputForm as old:
        print(old.hint(parser.prog, argv), file=sys.stderr)
        return 2
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except TofMpdError as err:
        print(f"tof-mpd {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"tof-mpd {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
