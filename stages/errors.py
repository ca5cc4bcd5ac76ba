"""Errors for bad input that a user can fix (a corrupt file, a degenerate mesh, an unknown name)."""
from __future__ import annotations


class InputError(ValueError):
    """Bad input, with the file / item it came from and what is wrong with it.

    The CLI prints `str(err)` as one line and exits 2; no traceback reaches the user.
    """

    def __init__(self, source, problem: str):
        super().__init__(f"{source}: {problem}")
        self.source = source
        self.problem = problem
