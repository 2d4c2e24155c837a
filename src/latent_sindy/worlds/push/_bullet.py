"""PyBullet, imported and connected without its C-level chatter.

PyBullet writes its build time to stderr on import and "argv[0]=" to stdout on connect,
straight from C; this module hides both so the CLI's output stays ours (and a CLI error
stays one line). PyBullet is the ``push`` extra (``pip install 'latent-sindy[push]'``): where
it is missing, importing this module (what simulating, rendering or reaching in this world
does) raises a UserError saying so.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys

from latent_sindy.errors import UserError

#: What a user without PyBullet is told (one line).
MISSING = ("the push world simulates with PyBullet, which is not installed: "
           "pip install 'latent-sindy[push]' (or pip install pybullet)")


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


try:
    with quiet_c_output():
        import pybullet
        import pybullet_data
        from pybullet_utils.bullet_client import BulletClient
except ModuleNotFoundError as e:
    if (e.name or "").partition(".")[0] not in ("pybullet", "pybullet_data", "pybullet_utils"):
        raise
    raise UserError(MISSING) from None

__all__ = ["MISSING", "BulletClient", "pybullet", "pybullet_data", "quiet_c_output"]
