"""A watchdog that kills a process's descendants when that process is killed.

A local Ray started by a study is a tree of processes (GCS server, raylet, the dashboard
agent, workers) under the study's process. A clean exit stops them (``ray.shutdown``); a kill
-9 of the study runs no clean-up, and some of them (the dashboard agent ignores SIGTERM) live
on. :func:`start_reaper` starts a small separate process that notes the descendants of the
watched process every ``every`` seconds while it lives, and SIGKILLs the ones it noted as soon
as it is gone (each checked by its start time, so a recycled process id is never touched).
Stop it with :meth:`Reaper.stop` after a clean shutdown. Linux only (it reads ``/proc``);
elsewhere it does nothing.

    reaper = start_reaper()          # after starting the processes to guard
    ...
    reaper.stop()                    # after stopping them cleanly
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

__all__ = ["Reaper", "start_reaper"]


def _stat(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time) of a live process, or None."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()  # after "pid (comm) "
    return int(fields[1]), int(fields[19])


def descendants(root: int) -> dict[int, int]:
    """{pid: start time} of every live descendant of ``root`` (Linux /proc)."""
    children: dict[int, list[int]] = {}
    starts: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            st = _stat(int(entry))
            if st is not None:
                children.setdefault(st[0], []).append(int(entry))
                starts[int(entry)] = st[1]
    found = {}
    todo = [root]
    while todo:
        for pid in children.get(todo.pop(), ()):
            if pid not in found:
                found[pid] = starts[pid]
                todo.append(pid)
    return found


def _watch(parent: int, every: float) -> None:
    """The reaper process: note ``parent``'s descendants until it is gone, then kill them."""
    import signal
    import time

    me = os.getpid()
    noted: dict[int, int] = {}
    while os.getppid() == parent:
        noted.update(descendants(parent))
        noted.pop(me, None)
        time.sleep(every)
    for pid, start in noted.items():
        st = _stat(pid)
        if st is not None and st[1] == start:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


class Reaper:
    """Handle of a running reaper process."""

    def __init__(self, proc: subprocess.Popen | None) -> None:
        self._proc = proc

    def stop(self) -> None:
        """End the reaper without killing anything (the guarded processes ended cleanly)."""
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self._proc = None


def start_reaper(every: float = 0.5) -> Reaper:
    """Start a reaper for this process's descendants (a no-op Reaper off Linux)."""
    if not Path("/proc/self/stat").exists():
        return Reaper(None)
    code = f"from latent_sindy.reaper import _watch; _watch({os.getpid()}, {float(every)})"
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)  # not in our process group's signals
    return Reaper(proc)
