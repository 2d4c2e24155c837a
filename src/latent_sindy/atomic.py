"""Writing files so that a reader (or a crash) never sees half of one.

Everything is written to a temporary file beside its destination and renamed into place
(``os.replace`` is atomic on one file system); on any error the temporary file is removed and
the destination is left as it was.

    with atomic_path("data/push.h5") as tmp:
        write_something(tmp)
    write_atomic(Path("run/config.json"), lambda f: f.write("{}"), binary=False)
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any


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
