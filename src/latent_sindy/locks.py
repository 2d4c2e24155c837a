"""One owner per output: an advisory lock a command holds on its folder or file while it runs.

A run folder (``train --out``), a study folder (``reproduce --out``) and a trajectory file
(``collect --out``) are written by one process at a time. :func:`exclusive` takes an
exclusive ``flock`` on a lock file beside the path (``.NAME.lock``, hidden like the project's
temporary files), so nothing inside the folder changes. A second process asking for the same
path is refused at once with one line naming it. The kernel drops the lock when its process
dies, so a ``kill -9`` leaves no stale lock: the leftover empty file is taken over by the next
owner, and an owner that ends normally removes it.

Worker processes of a study (see :mod:`latent_sindy.executors`) do not take the study's lock:
they run inside its owner's lifetime and die with it. Each training job takes the lock of its
own run folder.

    with exclusive("runs/sindy2", "run folder"):
        ...  # write into runs/sindy2
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
from collections.abc import Iterator
from pathlib import Path

from latent_sindy.errors import UserError

try:
    import fcntl
except ImportError:  # no flock (Windows): outputs are not locked there
    fcntl = None  # type: ignore[assignment]

__all__ = ["exclusive", "holder", "lock_path"]

#: flock errors of file systems that have no locks (some network ones): go on unlocked there.
_NO_LOCKS = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS}


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of ``path``: ``.NAME.lock`` in the same folder."""
    path = Path(path)
    return path.with_name(f".{path.name}.lock")


@contextlib.contextmanager
def exclusive(path: str | os.PathLike, what: str, option: str = "--out", wait: bool = False
              ) -> Iterator[None]:
    """Hold ``path`` (a ``what``, given as ``option``) for this process while the block runs.

    UserError, before anything else is touched, if another process holds it; with ``wait``,
    the block waits for that process to let it go instead (a shared result that one process
    makes and the others then read). Folders above ``path`` that had to be made for the lock
    file are removed again if they are left empty.
    """
    path = Path(path)
    if fcntl is None:
        yield
        return
    made: list[Path] = []  # folders made for the lock file, outermost first
    try:
        try:
            _make_parents(path.parent, made)
            fd = _acquire(lock_path(path), path, what, option, wait)
        except OSError as e:  # a file where a folder should be, no permission, ...
            raise UserError(f"{option} {path}: cannot write there ({e.strerror or e}); check "
                            "the path and its permissions") from None
        try:
            yield
        finally:
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.unlink(lock_path(path))  # while still holding it (see _acquire)
                os.close(fd)
    finally:
        for folder in reversed(made):
            with contextlib.suppress(OSError):  # not empty: something else lives there now
                folder.rmdir()


def holder(path: str | os.PathLike) -> str | None:
    """Who holds ``path`` now ("another process (pid N)", as a refusal names it), or None
    where nobody does. A reader's check: it takes a shared lock for an instant where the
    lock file exists, and creates nothing."""
    lock = lock_path(path)
    if fcntl is None:
        return None
    try:
        fd = os.open(lock, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None  # no lock file: nobody holds it
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _holder(fd)
    except OSError:
        return None  # a file system without locks
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _make_parents(folder: Path, made: list[Path]) -> None:
    """Make ``folder`` and its missing parents, adding each one made to ``made``; a folder
    another process makes at the same moment (a study's workers) is taken as it is."""
    if folder.exists() or folder == folder.parent:
        return
    _make_parents(folder.parent, made)
    try:
        folder.mkdir()
    except FileExistsError:
        if not folder.is_dir():
            raise
        return
    made.append(folder)


def _acquire(lock: Path, path: Path, what: str, option: str, wait: bool = False
             ) -> int | None:
    """An open descriptor of ``lock`` holding its flock (None where the file system has no
    locks); UserError if another process holds it, unless ``wait``: then it waits."""
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise UserError(f"{option} {path}: {holder} is using this {what}; "
                            f"wait for it to end, or choose another {option}") from None
        except OSError as e:
            os.close(fd)
            if e.errno in _NO_LOCKS:
                with contextlib.suppress(OSError):
                    os.unlink(lock)
                return None
            raise
        try:
            # An owner that ended removed the file after we opened it: ours would lock nothing.
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            same = False
        except BaseException:
            os.close(fd)
            raise
        if same:
            with contextlib.suppress(OSError):  # who holds it, for the message of a refusal
                os.ftruncate(fd, 0)
                os.write(fd, f"{os.getpid()} {socket.gethostname()}\n".encode())
            return fd
        os.close(fd)


def _holder(fd: int) -> str:
    """Who holds the lock, as its file says: "another process (pid N)" (on HOST if not here)."""
    try:
        pid, host = os.pread(fd, 256, 0).decode().split()
        pid = str(int(pid))
    except (OSError, ValueError):
        return "another process"
    if host != socket.gethostname():
        return f"another process (pid {pid} on {host})"
    return "this process" if int(pid) == os.getpid() else f"another process (pid {pid})"
