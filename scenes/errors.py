"""The one error type for bad user input: it names the file and the problem."""
from __future__ import annotations

import os


class InputError(Exception):
    """Bad input (file, flag or scene description). The CLI prints it on one line and exits 2."""

    def __init__(self, source: str | os.PathLike | None, problem: str):
        self.source = None if source is None else os.fspath(source)
        self.problem = problem
        message = f"{self.source}: {problem}" if self.source else problem
        # One line, whatever a corrupt file or a library's message puts in the text.
        super().__init__(" ".join(message.splitlines()))
