"""One process per output, and no process outliving its parent.

A run folder, a study folder and a trajectory file being written by one command are refused
to a second command at once (one line), and a kill -9 of the first leaves no stale lock.
Worker processes of a pool die with the process that made them, even when it is killed -9.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from latent_sindy.cli import main
from latent_sindy.data import write_sequences
from latent_sindy.errors import UserError
from latent_sindy.worlds.push.collect import CollectionPlan, collect
from synthetic import make_trajectories

pytestmark = pytest.mark.usefixtures("one_torch_thread")
CLI = [sys.executable, "-m", "latent_sindy.cli"]
TINY = ["--latent-dim", "3", "--encoder-hidden", "8", "--decoder-hidden", "16"]
linux_only = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")


def start(argv: list[str], ready: Path, timeout: float = 180) -> subprocess.Popen:
    """Start a command and return once ``ready`` exists (it is then writing its output)."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + timeout
    while not ready.exists():
        if proc.poll() is not None:
            pytest.fail(f"{argv} ended early: {proc.stderr.read().decode()[-2000:]}")
        if time.monotonic() > deadline:
            kill(proc)
            pytest.fail(f"{ready} did not appear within {timeout} s")
        time.sleep(0.05)
    return proc


def kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stderr.close()


def refused_in_use(capsys, argv: list[str], path: Path) -> None:
    """The command exits 2 with one line naming ``path`` and the other process."""
    rc = main(argv)
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2, err
    assert len(err) == 1 and str(path) in err[0] and "another process" in err[0], err


@pytest.fixture(scope="module")
def data_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("data") / "d.h5"
    write_sequences(path, make_trajectories())
    return path


# ----------------------------------------------------------------------------- D1: one owner
def test_d1_a_run_folder_in_use_is_refused_and_freed_by_kill(data_file, tmp_path, capsys):
    out = tmp_path / "tc"
    train = ["train", "sindy", "--data", str(data_file), "--out", str(out), "--no-progress",
             *TINY]
    first = start([*CLI, *train, "--epochs", "100000"], out / "config.json")
    try:
        # --overwrite would otherwise replace the running run under its feet
        refused_in_use(capsys, [*train, "--epochs", "1", "--overwrite"], out)
    finally:
        kill(first)
    assert main([*train, "--epochs", "1", "--overwrite"]) == 0  # kill -9 left no stale lock
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tc"]  # and no lock file behind


def test_d1_a_trajectory_file_being_collected_is_refused(tmp_path):
    out = tmp_path / "c.h5"
    plan = CollectionPlan(trajectories=200, steps=5)
    first = start([*CLI, "collect", "--out", str(out), "--trajectories", "200", "--steps", "5",
                   "--workers", "1", "--no-progress"], tmp_path / "c.h5.partial" / "plan.json")
    try:
        with pytest.raises(UserError, match="another process") as e:
            collect(out, plan, workers=1)
        assert str(out) in str(e.value)
    finally:
        kill(first)


def test_d1_a_study_folder_in_use_is_refused(data_file, tmp_path, capsys):
    out = tmp_path / "study"
    study = ["reproduce", "--scale", "tiny", "--out", str(out), "--data", str(data_file),
             "--models", "linear", "--workers", "1"]
    first = start([*CLI, *study], out)
    try:
        refused_in_use(capsys, study, out)
    finally:
        kill(first)


def test_a_lock_leaves_nothing_behind_even_when_its_block_fails(tmp_path):
    from latent_sindy.locks import exclusive

    with pytest.raises(RuntimeError), exclusive(tmp_path / "a" / "b" / "run", "run folder"):
        assert (tmp_path / "a" / "b" / ".run.lock").is_file()
        raise RuntimeError
    assert not any(tmp_path.iterdir())  # neither the lock file nor the folders made for it


def test_a_second_holder_in_the_same_process_is_refused_too(tmp_path):
    from latent_sindy.locks import exclusive

    with exclusive(tmp_path / "run", "run folder"), pytest.raises(
            UserError, match=r"--out .*run: this process is using this run folder"):
        with exclusive(tmp_path / "run", "run folder"):
            pass
    with exclusive(tmp_path / "run", "run folder"):  # free again
        pass


def test_a_waiting_holder_goes_on_once_the_other_process_lets_go(tmp_path):
    from latent_sindy.locks import exclusive

    code = textwrap.dedent(f"""
        import time
        from pathlib import Path
        from latent_sindy.locks import exclusive
        with exclusive(Path({str(tmp_path / "fit")!r}), "fit"):
            Path({str(tmp_path / "held")!r}).touch()
            time.sleep(1.0)
            Path({str(tmp_path / "done")!r}).touch()
    """)
    proc = start([sys.executable, "-c", code], tmp_path / "held")
    try:
        with pytest.raises(UserError, match="another process"):
            with exclusive(tmp_path / "fit", "fit"):
                pass
        with exclusive(tmp_path / "fit", "fit", wait=True):
            assert (tmp_path / "done").exists()  # entered only after the other let go
    finally:
        kill(proc)


def test_a_parent_folder_another_process_makes_at_the_same_moment_is_taken(tmp_path,
                                                                          monkeypatch):
    """Two study workers locking runs/seed0/a and runs/seed0/b both find seed0 missing, and
    one of them makes it first: the other takes it (it is not a failure, and not its own to
    remove afterwards)."""
    from latent_sindy import locks

    shared = tmp_path / "runs" / "seed0"
    real_mkdir = Path.mkdir

    def racing_mkdir(self, *args, **kwargs):
        if self == shared and not shared.exists():  # the other worker gets there first
            real_mkdir(self)
        return real_mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", racing_mkdir)
    with locks.exclusive(shared / "a", "run folder"):
        assert (shared / ".a.lock").is_file()
    monkeypatch.undo()
    assert shared.is_dir()  # made by the other: left for it
    assert not any(shared.iterdir())


def test_an_unusable_place_for_the_lock_is_one_line_naming_the_output(tmp_path):
    from latent_sindy.locks import exclusive

    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(UserError, match=f"--out {blocker}/run: cannot write there"):
        with exclusive(blocker / "run", "run folder"):
            pass


# ----------------------------------------------------------------------------- D20: orphans
def children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` and that multiprocessing spawned as workers."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            cmdline = (entry / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and b"spawn_main" in cmdline:
            found.append(int(entry.name))
    return found


def alive(pid: int) -> bool:
    """Running (a zombie no init has reaped yet is dead)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def assert_workers_die_with(proc: subprocess.Popen, n: int, busy: float = 0.0) -> None:
    """Wait for ``n`` workers of ``proc`` (and ``busy`` seconds more), kill -9 ``proc``, and see
    the workers gone within 30 s (a worker still importing when its parent dies notices once
    its imports are done: seconds on a loaded machine; an orphan would live on for good)."""
    deadline = time.monotonic() + 180
    while len(workers := children(proc.pid)) < n:
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        assert time.monotonic() < deadline, f"{n} workers did not start"
        time.sleep(0.05)
    time.sleep(busy)
    kill(proc)
    deadline = time.monotonic() + 30
    while (left := [p for p in workers if alive(p)]) and time.monotonic() < deadline:
        time.sleep(0.05)
    for p in left:  # leave nothing behind on this machine either way
        os.kill(p, signal.SIGKILL)
    assert not left, f"workers {left} outlived their killed parent"


HELPER = textwrap.dedent("""
    import time
    from latent_sindy.executors import ExecutorOptions, make_executor

    if __name__ == "__main__":
        pool = make_executor("local", ExecutorOptions(workers=2))
        for f in [pool.submit(time.sleep, 0.2), pool.submit(time.sleep, 0.2)]:
            f.result()
        time.sleep(600)
""")


@linux_only
def test_d20_the_study_executors_workers_die_with_it(tmp_path):
    script = tmp_path / "pool.py"
    script.write_text(HELPER)
    proc = subprocess.Popen([sys.executable, str(script)], stderr=subprocess.PIPE)
    try:
        assert_workers_die_with(proc, 2)
    finally:
        kill(proc)


@linux_only
def test_d20_collect_workers_die_with_it(tmp_path):
    # trajectories of 300 pushes: the workers are in the middle of one when it is killed
    proc = subprocess.Popen([*CLI, "collect", "--out", str(tmp_path / "c.h5"), "--trajectories",
                             "4", "--steps", "300", "--workers", "2", "--no-progress"],
                            stderr=subprocess.PIPE)
    try:
        assert_workers_die_with(proc, 2, busy=3.0)
    finally:
        kill(proc)


REAPED = textwrap.dedent("""
    import subprocess, sys, time
    from latent_sindy.reaper import start_reaper
    # a child that ignores SIGTERM and has a child of its own, like Ray's dashboard agent
    code = ("import signal, subprocess, sys, time; "
            "signal.signal(signal.SIGTERM, signal.SIG_IGN); "
            "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)']); "
            "time.sleep(600)")
    subprocess.Popen([sys.executable, "-c", code])
    start_reaper(every=0.1)
    print("ready", flush=True)
    time.sleep(600)
""")


@linux_only
def test_d20_a_reaper_kills_the_descendants_of_a_killed_process(tmp_path):
    from latent_sindy.reaper import descendants

    script = tmp_path / "guarded.py"
    script.write_text(REAPED)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        assert proc.stdout.readline().strip() == b"ready"
        deadline = time.monotonic() + 30
        while len(descendants(proc.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # the reaper has noted them
        guarded = descendants(proc.pid)
        assert len(guarded) >= 2, guarded  # the child and the grandchild (not the reaper)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 10
        alive = set(guarded)
        while alive and time.monotonic() < deadline:
            alive = {p for p in alive if Path(f"/proc/{p}").exists()
                     and "Z" not in Path(f"/proc/{p}/stat").read_text().split(")")[1][:3]}
            time.sleep(0.1)
        assert not alive, f"still alive after the parent's kill -9: {alive}"
    finally:
        kill(proc)
        proc.stdout.close()


def test_a_stopped_reaper_kills_nothing(tmp_path):
    from latent_sindy.reaper import start_reaper

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        reaper = start_reaper(every=0.05)
        time.sleep(0.5)
        reaper.stop()
        time.sleep(0.3)
        assert child.poll() is None
    finally:
        child.kill()
        child.wait()
