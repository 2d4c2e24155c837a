"""Writing files so that a reader (or a crash) never sees half of one.

Everything is written to a temporary file beside its destination and renamed into place
(``os.replace`` is atomic on one file system); on any error the temporary file is removed and
the destination is left as it was.

    with atomic_path("data/push.h5") as tmp:
        write_something(tmp)
    write_atomic(Path("run/config.json"), lambda f: f.write("{}"), binary=False)

and the checks every command makes on its output paths before it touches anything:
:func:`check_output_file` (never a folder, never one of the command's inputs, the right
suffix) and :func:`check_output_dir` (never a file), and :func:`check_memory` (a size that
cannot fit is refused up front).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

from latent_sindy.errors import UserError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside `path` (same suffix), renamed onto `path` if the block succeeds.

    The temporary name starts with a dot, so globs for the final names never match it.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp",
                               dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_atomic(path: str | os.PathLike, write: Callable[[IO[Any]], object],
                 binary: bool = True) -> None:
    """Call ``write(fileobj)`` on a temporary file beside `path`, then rename it into place."""
    with atomic_path(path) as tmp:
        mode = {"mode": "wb"} if binary else {"mode": "w", "newline": "", "encoding": "utf-8"}
        with open(tmp, **mode) as f:
            write(f)


def check_output_file(path: str | os.PathLike, option: str, suffixes: tuple[str, ...],
                      inputs: tuple[str | os.PathLike, ...] = ()) -> Path:
    """UserError unless ``path`` may be written as an output file: not a folder, not one of
    ``inputs``, and ending in one of ``suffixes``. Nothing is touched."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"{option} {path} is a folder: give a file name ending in "
                        f"{' or '.join(suffixes)}")
    for given in inputs:
        if path.exists() and Path(given).exists() and path.resolve() == Path(given).resolve():
            raise UserError(f"{option} {path} is the input file: choose another {option}")
    if path.suffix.lower() not in suffixes:
        raise UserError(f"{option} {path}: the file name must end in {' or '.join(suffixes)}")
    return path


def check_output_dir(path: str | os.PathLike, option: str) -> Path:
    """UserError if ``path`` exists and is not a folder. Nothing is touched."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UserError(f"{option} {path} is a file, not a folder: give a folder name")
    return path


def available_memory() -> int:
    """Bytes of memory available to a new allocation (MemAvailable; total RAM if unknown)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(n_bytes: int, what: str, fix: str) -> None:
    """UserError if ``n_bytes`` will not fit in half the available memory."""
    free = available_memory()
    if n_bytes > free // 2:
        raise UserError(f"{what} needs about {n_bytes / 2**30:.1f} GiB of memory, more than "
                        f"half of the {free / 2**30:.1f} GiB available: {fix}")
