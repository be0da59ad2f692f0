"""What native code prints, collected instead of shown: a C library (the OpenEXR core, a
compiler inside an OpenCL driver) writes to file descriptors 1 and 2 itself, past Python's
``sys.stdout`` and ``sys.stderr``."""
from __future__ import annotations

import contextlib
import ctypes
import io
import os
import sys
import tempfile

_LIBC = ctypes.CDLL(None)  # the C library, to flush its stdio buffers
_FILE_DESCRIPTORS = {"stdout": 1, "stderr": 2}


@contextlib.contextmanager
def output_collected(printed: list[str], streams: tuple[str, ...] = ("stdout", "stderr")):
    """Append to ``printed`` what is printed meanwhile on ``streams`` (names of ``sys``'s
    streams): first what native code writes to their file descriptors, then what Python code
    writes to them."""
    python = io.StringIO()
    for name in streams:
        if getattr(sys, name) is not None:   # None: Python started with the descriptor closed
            getattr(sys, name).flush()
    # A descriptor closed from the start (``2>&-``) prints nothing: it is left alone.
    copies = {fd: _duplicate(fd) for fd in (_FILE_DESCRIPTORS[name] for name in streams)}
    saved = {fd: copy for fd, copy in copies.items() if copy is not None}
    with tempfile.TemporaryFile() as native:
        try:
            for fd in saved:
                os.dup2(native.fileno(), fd)
            with contextlib.ExitStack() as redirections:
                for name in streams:
                    redirect = {"stdout": contextlib.redirect_stdout,
                                "stderr": contextlib.redirect_stderr}[name]
                    redirections.enter_context(redirect(python))
                yield
        finally:
            _LIBC.fflush(None)   # C stdio holds what it prints in buffers
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)
            native.seek(0)
            printed += [native.read().decode(errors="replace"), python.getvalue()]


def _duplicate(fd: int) -> int | None:
    """A copy of file descriptor ``fd``, or None where it is closed."""
    try:
        return os.dup(fd)
    except OSError:
        return None
