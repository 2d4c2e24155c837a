"""PyBullet, imported and connected without its C-level chatter.

PyBullet writes its build time to stderr on import and "argv[0]=" to stdout on connect,
straight from C; this module hides both so the CLI's output stays ours (and a CLI error
stays one line).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys


@contextlib.contextmanager
def quiet_c_output():
    """Send file descriptors 1 and 2 to /dev/null for the duration (C code included)."""
    streams = []
    for stream in (sys.stdout, sys.stderr):
        try:
            streams.append((stream, stream.fileno()))
        except (AttributeError, ValueError, OSError):  # replaced stream (captured output)
            pass
    saved = []
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        for stream, fd in streams:
            stream.flush()
            saved.append((fd, os.dup(fd)))
            os.dup2(null, fd)
        yield
    finally:
        with contextlib.suppress(Exception):
            ctypes.CDLL(None).fflush(None)
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        os.close(null)


with quiet_c_output():
    import pybullet
    import pybullet_data
    from pybullet_utils.bullet_client import BulletClient

__all__ = ["BulletClient", "pybullet", "pybullet_data", "quiet_c_output"]
