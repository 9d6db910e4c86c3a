"""The one CLI convention of ``tof-mpd``: inputs are positional, every written output is
``-o/--output OUT``.

Every subcommand adds its output with :func:`add_output`. Before issue 14, ``sim dataset``,
``sim predict``, ``correct`` and ``recording import-npz / export-npz`` took the output as a
positional argument; their parsers (``was_positional=True``) recognise that old form and fail
with one line giving the command to type instead, not argparse's usage dump.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

OUTPUT_FLAGS = ("-o", "--output")


class OldOutputForm(Exception):
    """A command line in the old form, its output positional; ``main`` prints :meth:`hint`."""

    def __init__(self, prog: str, args: Sequence[str], output: str) -> None:
        super().__init__(f"{prog}: positional output {output!r}")
        self.prog, self.args, self.output = prog, list(args), output

    def hint(self, root: str, argv: Sequence[str]) -> str:
        """``PROG: the output is now -o/--output: ROOT ARGV`` with ``-o`` before the output.

        ``argv`` is the whole command line; the subcommand's arguments are its tail.
        """
        head = list(argv)[:len(argv) - len(self.args)]
        tail = list(self.args)
        # the last occurrence: the old form put the output after the inputs
        index = len(tail) - 1 - tail[::-1].index(self.output)
        tail[index:index + 1] = ["-o", self.output]
        return f"{self.prog}: the output is now -o/--output: {root} {shlex.join(head + tail)}"


class _Held(Exception):
    """argparse's error message, held back while the parser looks for the old form."""


class CliParser(argparse.ArgumentParser):
    """An ArgumentParser that turns its subcommand's old positional output into
    :class:`OldOutputForm`. Subparsers take their parent's class, so ``tof-mpd``'s top-level
    parser being one makes every subcommand's parser one."""

    old_output: argparse.Action | None = None
    _holding = False

    def error(self, message: str) -> NoReturn:
        if self._holding:
            raise _Held(message)
        super().error(message)

    def parse_known_args(self, args: Sequence[str] | None = None,
                         namespace: argparse.Namespace | None = None,
                         ) -> tuple[argparse.Namespace, list[str]]:
        if self.old_output is None:
            return super().parse_known_args(args, namespace)
        args = list(sys.argv[1:] if args is None else args)
        try:
            return self._parse_holding_errors(args, namespace)
        except _Held as held:
            output = self._old_positional_output(args)
            if output is None:
                self.error(str(held))
            raise OldOutputForm(self.prog, args, output) from None

    def _parse_holding_errors(self, args: list[str], namespace: argparse.Namespace | None,
                              ) -> tuple[argparse.Namespace, list[str]]:
        self._holding = True
        try:
            return super().parse_known_args(args, namespace)
        finally:
            self._holding = False

    def _old_positional_output(self, args: list[str]) -> str | None:
        """The one positional left over when ``-o`` is absent: the old form's output."""
        assert self.old_output is not None
        # -o optional for this second parse only, so that the leftover positional shows
        self.old_output.required = False
        try:
            namespace, extras = self._parse_holding_errors(args, None)
        except _Held:
            return None  # wrong for another reason too: argparse's message says which
        finally:
            self.old_output.required = True
        stray = [arg for arg in extras if not arg.startswith("-")]
        absent = getattr(namespace, self.old_output.dest, None) is None
        return stray[0] if absent and len(stray) == 1 else None


def add_output(parser: argparse.ArgumentParser, help: str, *, default: Path | None = None,
               required: bool = True, was_positional: bool = False) -> argparse.Action:
    """Add ``-o/--output OUT`` (a path; required unless it has a default or ``required`` is
    False). ``was_positional``: the command took its output positionally before; a command
    line in that form raises :class:`OldOutputForm` while parsing."""
    action = parser.add_argument(*OUTPUT_FLAGS, dest="output", type=Path, metavar="OUT",
                                 default=default, required=required and default is None,
                                 help=help)
    if was_positional:
        if not (isinstance(parser, CliParser) and action.required):
            raise TypeError("the old positional form needs a CliParser and a required output")
        parser.old_output = action
    return action
