"""The study on a real Ray cluster: two nodes on this machine, one worker process killed while it
trains; the study still completes and its outputs equal the local executor's, bit for bit. A
job whose worker dies more often than retried, and a wrong --ray-address, are one-line errors."""

from __future__ import annotations

import os
import signal
import socket
import threading
import time
from pathlib import Path

import pytest

from latent_sindy.cli import main
from latent_sindy.errors import UserError
from latent_sindy.executors import EXECUTORS, ExecutorOptions, RayExecutor, make_executor
from push_study import run_push
from study_outputs import assert_same_study

ray = pytest.importorskip("ray")


def _parent(pid: int) -> int:
    # /proc/PID/stat: "pid (comm) state ppid ..."; comm may hold spaces, so split after ")"
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def _descends_from(pid: int, root: int) -> bool:
    try:
        while pid > 1:
            if pid == root:
                return True
            pid = _parent(pid)
    except (OSError, ValueError, IndexError):
        return False
    return False


def _task_processes(task: str) -> list[int]:
    """Ray workers started by this test that are running ``task`` now (Ray titles them so)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            title = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if title.startswith(f"ray::{task}".encode()) and _descends_from(int(entry.name),
                                                                        os.getpid()):
            found.append(int(entry.name))
    return found


def _kill_one_training_worker(stop: threading.Event, killed: list[int]) -> None:
    while not stop.is_set():
        for pid in _task_processes("train_job"):
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
            return
        stop.wait(0.05)


@pytest.fixture(scope="module")
def studies(tmp_path_factory) -> dict:
    """The tiny study with the local executor, and on a two-node Ray cluster with a kill."""
    from ray.cluster_utils import Cluster

    local = tmp_path_factory.mktemp("local")
    run_push(local, scale="tiny", workers=1)

    t0 = time.perf_counter()
    cluster = Cluster(initialize_head=True,
                      head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        started = time.perf_counter() - t0
        out = tmp_path_factory.mktemp("ray")
        stop, killed = threading.Event(), []
        killer = threading.Thread(target=_kill_one_training_worker, args=(stop, killed))
        killer.start()
        lines: list[str] = []
        t1 = time.perf_counter()
        try:
            run_push(out, lines.append, scale="tiny", executor="ray",
                     ray_address=cluster.address)
        finally:
            stop.set()
            killer.join()
        study_s = time.perf_counter() - t1
        print(f"\ntwo-node Ray: started in {started:.1f} s, tiny study in {study_s:.1f} s")
        return {"local": local, "ray": out, "killed": killed, "lines": lines}
    finally:
        cluster.shutdown()


@pytest.mark.slow  # two tiny studies and a two-node cluster: about 90 s on 2 cores
def test_a_killed_worker_is_retried_and_the_study_equals_the_local_one(studies):
    assert len(studies["killed"]) == 1, "no training worker was seen to kill"
    with pytest.raises(ProcessLookupError):
        os.kill(studies["killed"][0], 0)
    assert any(line.startswith("report: ") for line in studies["lines"])
    assert "ray executor, 2 at once" in " ".join(studies["lines"])  # both nodes' CPUs
    assert_same_study(studies["local"], studies["ray"])


def test_executor_registry_names_the_choices():
    assert set(EXECUTORS) == {"local", "ray"}
    with pytest.raises(UserError, match="--executor 'dask': use one of local, ray"):
        make_executor("dask", ExecutorOptions())
    assert not ray.is_initialized()  # the study shut down the Ray connection it opened


def test_a_job_whose_worker_keeps_dying_is_a_one_line_error_naming_it(tmp_path):
    attempts = tmp_path / "attempts"

    def die(path: str) -> None:  # a local function: Ray ships it by value
        with open(path, "a") as f:
            f.write("x")
        os._exit(1)

    with RayExecutor(ExecutorOptions(workers=1, threads=1, retries=1)) as pool:
        fut = pool.submit(die, str(attempts), name="training sindy2 (seed 3)")
        assert pool.wait_one({fut: None}) == {fut}
        with pytest.raises(UserError, match=r"^training sindy2 \(seed 3\) was lost on Ray "
                                            r"after 2 attempt\(s\) \(\w+Error") as e:
            fut.result()
    assert attempts.read_text() == "xx"  # run, then retried once
    assert "\n" not in str(e.value) and "run the same command again" in str(e.value)
    assert not ray.is_initialized()


def test_a_wrong_ray_address_fails_at_once_in_one_line(tmp_path, capsys):
    with socket.socket() as s:  # a local port nothing listens on once closed
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    t0 = time.perf_counter()
    code = main(["reproduce", "--scale", "tiny", "--out", str(tmp_path / "study"),
                 "--executor", "ray", "--ray-address", address])
    assert code == 2 and time.perf_counter() - t0 < 10
    err = capsys.readouterr().err
    assert err.startswith(f"latent-sindy: error: --ray-address {address}: nothing answers at "
                          f"{address} (") and err.count("\n") == 1, err
    assert not ray.is_initialized()
    assert not (tmp_path / "study").exists()  # a refused study leaves no folder behind
