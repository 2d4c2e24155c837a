"""Where the study's jobs run: one interface (submit, wait for one, shut down) and a registry.

An executor takes picklable module-level functions with their arguments and gives back
:class:`concurrent.futures.Future` objects; :meth:`Executor.wait_one` blocks until at least
one of the given futures is done. The study never asks which executor it holds.

- ``local``: this machine's processes, as before: one worker runs jobs in this process
  (:class:`Inline`); more run them in freshly spawned processes (:class:`Pool`), which die
  with the process that made them, even when it is killed -9 (:func:`die_with_parent`).
- ``ray``: Ray tasks (:class:`RayExecutor`), on a one-node Ray started here or on the cluster at
  ``--ray-address``. Each task declares its CPUs (and GPUs); a task whose worker process or
  node dies is run again (``max_retries``), and once those are spent its job fails with a
  one-line error naming it. Ray is an optional extra, imported only here.

    latent-sindy reproduce --scale tiny --executor ray                       # a local Ray
    ray start --head && latent-sindy reproduce --executor ray --ray-address auto
"""

from __future__ import annotations

import os
import socket
import threading
from collections.abc import Callable, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, Protocol

from latent_sindy.errors import UserError
from latent_sindy.reaper import start_reaper

__all__ = ["EXECUTORS", "Executor", "ExecutorOptions", "Inline", "Pool", "RayExecutor",
           "Resources", "die_with_parent", "make_executor"]

#: Environment every worker needs before torch loads (see cli.py: OpenMP threads sleep
#: instead of spinning while they wait).
WORKER_ENV = {"OMP_WAIT_POLICY": "PASSIVE"}

#: Seconds to wait for a --ray-address to accept a connection (Ray itself retries for minutes).
CONNECT_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class Resources:
    """What one job declares it uses (Ray schedules by it; local processes ignore it)."""

    cpus: float = 1.0
    gpus: float = 0.0


@dataclass(frozen=True)
class ExecutorOptions:
    """Settings every executor is built from."""

    workers: int = 2
    """Local: processes (1: this process). Ray without an address: CPUs of the Ray it starts
    (times ``threads``)."""
    threads: int = 1
    """CPUs one job uses (its torch threads)."""
    address: str | None = None
    """Ray: the cluster to join ("auto", "HOST:6379", "ray://HOST:10001"); None starts one."""
    retries: int = 3
    """Ray: how often a task whose worker died is run again."""


class Executor(Protocol):
    """What the study needs of an executor."""

    slots: int
    """About how many jobs run at once (to cut work into enough pieces)."""

    def submit(self, fn: Callable, *args: Any, resources: Resources = ...,
               name: str | None = None) -> Future:
        """Run ``fn(*args)``; ``name`` says what the job is in errors (default: fn's name)."""
        ...

    def wait_one(self, pending: Mapping[Future, Any]) -> set[Future]: ...

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None: ...

    def __enter__(self) -> Executor: ...

    def __exit__(self, *exc: object) -> None: ...


class Inline:
    """One worker: jobs run in this process one at a time, newest first (so an evaluation
    follows its training at once), when :meth:`wait_one` is called."""

    slots = 1

    def __init__(self) -> None:
        self._queue: list[tuple[Future, Callable, tuple]] = []

    def submit(self, fn: Callable, *args: Any, resources: Resources = Resources(),
               name: str | None = None) -> Future:
        fut: Future = Future()
        self._queue.append((fut, fn, args))
        return fut

    def wait_one(self, pending: Mapping[Future, Any]) -> set[Future]:
        fut, fn, args = self._queue.pop()
        try:
            fut.set_result(fn(*args))
        except Exception as e:  # re-raised by fut.result(), as a process pool would
            fut.set_exception(e)
        return {fut}

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        self._queue.clear()

    def __enter__(self) -> Inline:
        return self

    def __exit__(self, *exc: object) -> None: ...


def die_with_parent() -> None:
    """In a worker process started by multiprocessing: end it as soon as its parent ends.

    A worker initializer. A killed (-9) parent runs no clean-up, and a worker waiting for work
    or busy with a job would live on, idle or writing into its parent's outputs. A daemon
    thread waits on multiprocessing's sentinel of the parent (a pipe whose other end only the
    parent holds, so it reads end-of-file when the parent is gone, on every platform) and then
    exits the process at once. In a process without a multiprocessing parent it does nothing.
    """
    import multiprocessing as mp
    from multiprocessing.connection import wait as wait_ready

    parent = mp.parent_process()
    if parent is None or parent.sentinel is None:
        return

    def watch() -> None:
        wait_ready([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="latent-sindy-parent-watch", daemon=True).start()


class Pool:
    """Worker processes started fresh (spawn: no inherited PyBullet or torch state), which
    end with this process (:func:`die_with_parent`)."""

    def __init__(self, workers: int) -> None:
        import multiprocessing as mp

        self.slots = workers
        self._pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"),
                                         initializer=die_with_parent)

    def submit(self, fn: Callable, *args: Any, resources: Resources = Resources(),
               name: str | None = None) -> Future:
        return self._pool.submit(fn, *args)

    def wait_one(self, pending: Mapping[Future, Any]) -> set[Future]:
        return wait(pending, return_when=FIRST_COMPLETED).done

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        self._pool.shutdown(wait=wait, cancel_futures=cancel_futures)

    def __enter__(self) -> Pool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


class RayExecutor:
    """Jobs as Ray tasks with declared resources, retried when their worker dies.

    Without an address it starts a one-node Ray on this machine with ``workers * threads``
    CPUs and stops it at shutdown; with one it joins that cluster (``ray start --head`` on
    one machine, ``ray start --address HEAD:6379`` on the others) and leaves it running.
    Every node needs this package installed, and the study's folders on a filesystem they
    all share.
    """

    def __init__(self, options: ExecutorOptions) -> None:
        try:
            import ray
        except ImportError:
            raise UserError("--executor ray needs Ray, which is not installed: "
                            "pip install 'latent-sindy[ray]'") from None
        import logging

        self._ray = ray
        self._retries = options.retries
        self._reaper = None
        self._remote: dict[Callable, Any] = {}
        self._refs: dict[Future, Any] = {}
        self._names: dict[Future, str] = {}
        # The workers' environment: ours, as cli.py set it before torch loaded.
        env = {k: os.environ.get(k, v) for k, v in WORKER_ENV.items()}
        self._owner = not ray.is_initialized()
        if self._owner and options.address:
            _probe(options.address)
        if self._owner:
            kwargs: dict[str, Any] = {"address": options.address} if options.address else {
                "num_cpus": options.workers * options.threads, "include_dashboard": False}
            try:
                ray.init(runtime_env={"env_vars": env}, logging_level=logging.WARNING,
                         **kwargs)
            except ConnectionError as e:
                raise UserError(f"--ray-address {options.address}: no Ray cluster there ({e}); "
                                "start one with `ray start --head` or fix the address") from None
            except (ValueError, RuntimeError) as e:
                where = f"--ray-address {options.address}" if options.address else "a local Ray"
                raise UserError(f"{where}: Ray did not start ({e}); check the address or run "
                                "`ray start --head`") from None
        # A kill -9 of this process leaves a local Ray's processes behind (its dashboard agent
        # ignores SIGTERM): a reaper kills them when we are gone.
        self._reaper = start_reaper() if self._owner and not options.address else None
        cpus = ray.cluster_resources().get("CPU", 1.0)
        self.slots = max(1, int(cpus // options.threads))

    def submit(self, fn: Callable, *args: Any, resources: Resources = Resources(),
               name: str | None = None) -> Future:
        remote = self._remote.get(fn)
        if remote is None:
            remote = self._remote[fn] = self._ray.remote(fn)
        ref = remote.options(num_cpus=resources.cpus, num_gpus=resources.gpus,
                             max_retries=self._retries, retry_exceptions=False).remote(*args)
        fut: Future = Future()
        self._refs[fut] = ref
        self._names[fut] = name or getattr(fn, "__name__", "a job")
        return fut

    def wait_one(self, pending: Mapping[Future, Any]) -> set[Future]:
        ray = self._ray
        by_ref = {self._refs[f]: f for f in pending if f in self._refs}
        ready, _ = ray.wait(list(by_ref), num_returns=1)
        done = set()
        for ref in ready:
            fut = by_ref[ref]
            del self._refs[fut]
            name = self._names.pop(fut)
            try:
                fut.set_result(ray.get(ref))
            except ray.exceptions.RayTaskError as e:  # the job raised: its own exception
                cause = getattr(e, "cause", None)
                fut.set_exception(cause if isinstance(cause, BaseException) else e)
            except ray.exceptions.RayError as e:  # e.g. its worker died more often than retried
                reason = (str(e).strip().splitlines() or [""])[0]
                fut.set_exception(UserError(
                    f"{name} was lost on Ray after {self._retries + 1} attempt(s) "
                    f"({type(e).__name__}: {reason}); check the nodes' memory and logs "
                    "(`ray status`), then run the same command again: finished jobs are "
                    "reused"))
            done.add(fut)
        return done

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        if cancel_futures:
            for ref in self._refs.values():
                self._ray.cancel(ref, force=True)
        self._refs.clear()
        self._names.clear()
        if self._owner and self._ray.is_initialized():
            self._ray.shutdown()
            self._owner = False
        if self._reaper is not None:
            self._reaper.stop()
            self._reaper = None

    def __enter__(self) -> RayExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


def _probe(address: str) -> None:
    """UserError unless something accepts connections at a HOST:PORT address (also
    ray://HOST:PORT) within :data:`CONNECT_TIMEOUT_S`: Ray would retry a dead address for
    minutes. Other forms ("auto") are Ray's to resolve."""
    host, sep, port = address.split("://", 1)[-1].rpartition(":")  # ray://HOST:PORT too
    if not (sep and host and port.isdigit()):
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), CONNECT_TIMEOUT_S).close()
    except OSError as e:
        reason = e.strerror or type(e).__name__
        raise UserError(f"--ray-address {address}: nothing answers at {host}:{port} ({reason}); "
                        "start the cluster there with `ray start --head` or fix the "
                        "address") from None


def _local(options: ExecutorOptions) -> Inline | Pool:
    return Inline() if options.workers == 1 else Pool(options.workers)


#: Executor name -> how to build it (the values of ``--executor``).
EXECUTORS: dict[str, Callable[[ExecutorOptions], Executor]] = {
    "local": _local,
    "ray": RayExecutor,
}


def make_executor(name: str, options: ExecutorOptions) -> Executor:
    """The executor registered as ``name``; UserError naming the choices for another name."""
    try:
        build = EXECUTORS[name]
    except KeyError:
        raise UserError(f"--executor {name!r}: use one of {', '.join(EXECUTORS)}") from None
    return build(options)
