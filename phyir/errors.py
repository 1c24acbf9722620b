"""Exceptions users can meet; the CLI turns them into one-line messages."""

from __future__ import annotations

import os


class PhyIRError(Exception):
    """Base of every error caused by the user's input or environment (not an internal bug)."""


class InputError(PhyIRError, ValueError):
    """An input file that can't be used; the message names the file and the problem."""

    def __init__(self, path: str | os.PathLike | None, problem: str):
        self.path = None if path is None else os.fspath(path)
        self.problem = problem
        super().__init__(problem if path is None else f"{self.path}: {problem}")
