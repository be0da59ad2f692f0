"""The one error type for bad user input: it names the file and the problem; and how a message
names an argument, as a command-line flag or as a keyword of the Python API."""
from __future__ import annotations

import contextlib
import contextvars
import os

# The flags not spelled "--" + the keyword with "-" for "_".
_FLAGS = {"scenes": "--scene", "estimators": "--estimator", "resolution": "--res"}
_KEYWORDS = contextvars.ContextVar("iblbench_keywords", default=False)


class InputError(Exception):
    """Bad input (file, flag or scene description). The CLI prints it on one line and exits 2."""

    def __init__(self, source: str | os.PathLike | None, problem: str):
        self.source = None if source is None else os.fspath(source)
        self.problem = problem
        message = f"{self.source}: {problem}" if self.source else problem
        # One line, whatever a corrupt file or a library's message puts in the text.
        super().__init__(" ".join(message.splitlines()))


def argument(name: str, value=None) -> str:
    """How a message names the argument ``name`` (the Python API's keyword, e.g. ``first_seed``)
    and, if given, its ``value``: ``--first-seed 5`` (``--force`` for True, ``--pixel 3,4`` for
    a tuple), or inside :func:`keywords_named` ``first_seed=5``, so that an error raised from the
    Python API names no flag it does not have (issue 23)."""
    if keywords_named():
        return name if value is None else f"{name}={value!r}"
    flag = _FLAGS.get(name, "--" + name.replace("_", "-"))
    if value is None or value is True:
        return flag
    return f"{flag} {','.join(map(str, value)) if isinstance(value, tuple) else value}"


def keywords_named() -> bool:
    """Whether messages name arguments as the Python API's keywords (:func:`python_keywords`)."""
    return _KEYWORDS.get()


@contextlib.contextmanager
def python_keywords():
    """Inside, :func:`argument` names the Python API's keywords (the API's functions run in it)."""
    token = _KEYWORDS.set(True)
    try:
        yield
    finally:
        _KEYWORDS.reset(token)
