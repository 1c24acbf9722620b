"""Exceptions users can meet; the CLI turns them into one-line messages."""

from __future__ import annotations

import os
import re

# C0 and C1 control characters, DEL, and the lone surrogates os.fsdecode makes of undecodable bytes
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\ud800-\udfff]")


def _escape(m: re.Match) -> str:
    c = m.group()
    if "\udc80" <= c <= "\udcff":  # an undecodable byte of a file name: show the byte
        return f"\\x{ord(c) - 0xDC00:02x}"
    return repr(c)[1:-1]  # \n, \t, \x1b, \x85, \ud800 ...


def shown(text: str | os.PathLike | None) -> str:
    """``text`` (a file name, a message) safe to print on one line of a terminal: control
    characters (newline, ESC, ...) and undecodable bytes escaped as ``repr`` writes them."""
    s = "" if text is None else os.fspath(text)
    if isinstance(s, bytes):
        s = os.fsdecode(s)
    return _UNPRINTABLE.sub(_escape, s)


class PhyIRError(Exception):
    """Base of every error caused by the user's input or environment (not an internal bug)."""


class InputError(PhyIRError, ValueError):
    """An input file that can't be used; the message names the file and the problem."""

    def __init__(self, path: str | os.PathLike | None, problem: str):
        self.path = None if path is None else os.fspath(path)
        self.problem = problem
        super().__init__(problem if path is None else f"{shown(self.path)}: {problem}")


def os_error(path: str | os.PathLike | None, e: OSError) -> InputError:
    """An OSError as the one-line ``<path>: <strerror>`` (the path the error names, else ``path``)."""
    where = e.filename if e.filename is not None else path
    return InputError(where, e.strerror or type(e).__name__)
