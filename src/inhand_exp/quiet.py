"""Silence what C extensions print straight to the process's file descriptors: PyBullet's build
banner at import (on stderr) and HiGHS's copyright banner whenever a solver is made (on stdout).
Every worker process would print them again; the run's own output is what the user should see."""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def c_output_silenced() -> Iterator[None]:
    """Send file descriptors 1 and 2 to /dev/null inside the block (Python's own streams are
    flushed first, and C's buffers before they are restored, so nothing of ours is lost)."""
    try:
        fds = [sys.stdout.fileno(), sys.stderr.fileno()]
    except (AttributeError, OSError, ValueError):  # no real file descriptors (captured)
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(fd) for fd in fds]
    try:
        with open(os.devnull, "wb") as null:
            for fd in fds:
                os.dup2(null.fileno(), fd)
        yield
    finally:
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None).fflush(None)  # what C stdio buffered goes to /dev/null too
        for fd, old in zip(fds, saved, strict=True):
            os.dup2(old, fd)
            os.close(old)
