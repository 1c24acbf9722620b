"""Exceptions users can meet; the CLI turns them into one-line messages."""

from __future__ import annotations

import os
import re

# C0 and C1 control characters, DEL, the lone surrogates os.fsdecode makes of undecodable bytes, and
# the invisible format characters that change what a terminal shows: line / paragraph separators,
# bidirectional overrides ("evil\u202egpj.hdr" displays as "evilrdh.jpg"), zero-width characters
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\ud800-\udfff\u061c\u200b-\u200f\u2028-\u202e"
                          "\u2060-\u2069\ufeff]")


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
        name = shown(self.path) or "''"  # an empty name is shown as '' (not ": no such file")
        super().__init__(problem if path is None else f"{name}: {problem}")


def os_error(path: str | os.PathLike | None, e: OSError) -> InputError:
    """An OSError as the one-line ``<path>: <strerror>`` (the path the error names, else ``path``)."""
    where = e.filename if e.filename is not None else path
    return InputError(where, e.strerror or type(e).__name__)
