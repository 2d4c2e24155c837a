"""Collect random-push trajectories in parallel, resumably, into a trajectory file.

Trajectory i depends only on (seed, i): its start pose and its actions come from
``numpy.random.default_rng([seed, i, attempt])``, so the data set is the same whatever the
number of workers and however often the collection was interrupted. A trajectory whose
block leaves the workspace is discarded and drawn again (attempt + 1).

While it runs, finished trajectories are kept one file each in ``OUT.partial/`` (each
written to a temporary name and renamed, so none is ever half-written). When all are in,
they are assembled into ``OUT`` (again through a temporary file) and the folder is removed.
Killed at any moment, the command can be re-run as it was and completes what is missing.

    latent-sindy collect --out data/push.h5 --trajectories 200 --workers 2 --seed 0
    latent-sindy collect --out data/textured.h5 --table-look textured --lighting varied \
        --distractor                            # the textured world (ENV_PRESETS)
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tyro

from latent_sindy.atomic import atomic_path, check_memory, write_atomic
from latent_sindy.configs import from_json, to_json
from latent_sindy.data import SPLITS, read_sequences, write_sequences
from latent_sindy.errors import UserError, check_seed
from latent_sindy.executors import Executor, die_with_parent
from latent_sindy.locks import exclusive
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.data import push_data

MAX_ATTEMPTS = 50


@dataclass(frozen=True)
class CollectionPlan:
    """What to collect; two runs with equal plans produce identical files."""

    trajectories: int = 200
    """Number of trajectories in all splits (the paper: 200 = 100 train / 50 val / 50 test)."""
    steps: int = 10
    """Pushes per trajectory (each trajectory holds steps + 1 images)."""
    seed: int = 0
    """Seed of every random choice; the same seed gives the same file."""
    val_fraction: float = 0.25
    """Fraction of trajectories for the validation split."""
    test_fraction: float = 0.25
    """Fraction of trajectories for the test split."""
    env: tyro.conf.OmitArgPrefixes[PushEnvConfig] = field(default_factory=PushEnvConfig)
    """The pushing world and its camera."""

    def __post_init__(self) -> None:
        if self.trajectories < 1:
            raise UserError(f"--trajectories {self.trajectories}: collect at least 1")
        if self.steps < 1:
            raise UserError(f"--steps {self.steps}: each trajectory needs at least 1 push")
        check_seed(self.seed, "--seed")
        for name, v in (("val", self.val_fraction), ("test", self.test_fraction)):
            if not 0.0 <= v < 1.0:
                raise UserError(f"--{name}-fraction {v}: use a fraction in [0, 1)")
        if self.split_counts()["train"] < 1:
            raise UserError(
                f"--val-fraction {self.val_fraction} and --test-fraction {self.test_fraction} "
                f"leave no training trajectory out of {self.trajectories}: lower them")

    def split_counts(self) -> dict[str, int]:
        n_val = round(self.trajectories * self.val_fraction)
        n_test = round(self.trajectories * self.test_fraction)
        return {"train": self.trajectories - n_val - n_test, "val": n_val, "test": n_test}

    def split_ids(self) -> np.ndarray:
        """Contiguous blocks: train, then validation, then test (trajectories are i.i.d.)."""
        c = self.split_counts()
        return np.repeat(np.arange(len(SPLITS), dtype=np.uint8), [c[s] for s in SPLITS])


# --------------------------------------------------------------------------- one trajectory
def collect_one(env, index: int, plan: CollectionPlan) -> dict[str, np.ndarray]:
    """Roll out trajectory `index` of `plan` in `env` (a PandaPushEnv built from `plan.env`).

    Actions are uniform in the world's own action box (`plan.env.action_low` ..
    `action_high`, `action_dim` components).
    """
    low, high = np.array(plan.env.action_low), np.array(plan.env.action_high)
    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng([plan.seed, index, attempt])
        obs, info = env.reset(seed=int(rng.integers(2**31)))
        actions = rng.uniform(low, high, size=(plan.steps, plan.env.action_dim)).astype(np.float32)
        images = [obs]
        poses = [info["pose"]]
        executed = []
        for a in actions:
            obs, _, terminated, _, info = env.step(a)
            images.append(obs)
            poses.append(info["pose"])
            executed.append(bool(info["push_executed"]))
            if terminated:
                break
        else:
            return {"images": np.stack(images), "actions": actions,
                    "poses": np.stack(poses).astype(np.float32),
                    "executed": np.array(executed), "attempts": np.array(attempt + 1)}
    raise RuntimeError(f"trajectory {index}: the block left the workspace in all "
                       f"{MAX_ATTEMPTS} attempts")


_worker_env = None


def _worker_init(env_config: dict) -> None:
    global _worker_env
    die_with_parent()
    from latent_sindy.worlds.push.panda_push import PandaPushEnv

    _worker_env = PandaPushEnv(from_json(PushEnvConfig, env_config, "environment"))


def _worker_run(job: tuple[int, CollectionPlan]) -> tuple[int, dict]:
    index, plan = job
    return index, collect_one(_worker_env, index, plan)


def collect_shard(plan: CollectionPlan, indices: tuple[int, ...]) -> list[tuple[int, dict]]:
    """SequenceData ``indices`` of ``plan`` in one environment: one job of an executor."""
    from latent_sindy.worlds.push.panda_push import PandaPushEnv

    env = PandaPushEnv(plan.env)
    try:
        return [(i, collect_one(env, i, plan)) for i in indices]
    finally:
        env.close()


# --------------------------------------------------------------------------- the journal
def same_plan(recorded, plan: CollectionPlan) -> bool:
    """Whether ``recorded`` (a file's or journal's plan, JSON) is ``plan``. Settings the
    record lacks predate it and take their defaults (then: the old behaviour), except a
    world without ``push``, which is the paper's."""
    if recorded == json.loads(json.dumps(to_json(plan))):
        return True
    if not isinstance(recorded, dict) or not isinstance(recorded.get("env", {}), dict):
        return False
    try:
        env = {"push": "paper", **recorded.get("env", {})}
        return from_json(CollectionPlan, {**recorded, "env": env}, "plan") == plan
    except UserError:
        return False


def _partial_dir(out: Path) -> Path:
    return out.with_name(out.name + ".partial")


def _save_atomic_npz(path: Path, arrays: dict) -> None:
    with atomic_path(path) as tmp:
        np.savez(tmp, **arrays)


def _load_done(partial: Path, plan: CollectionPlan) -> dict[int, dict]:
    """Finished trajectories of an interrupted run; anything unreadable is dropped."""
    done = {}
    for f in sorted(partial.glob("traj_*.npz")):
        try:
            i = int(f.stem.split("_")[1])
            with np.load(f, allow_pickle=False) as z:
                item = {k: z[k] for k in z.files}
            ok = (0 <= i < plan.trajectories
                  and item["actions"].shape == (plan.steps, plan.env.action_dim)
                  and item["executed"].shape == (plan.steps,)
                  and item["images"].shape[0] == plan.steps + 1)
        except (ValueError, OSError, KeyError, IndexError, zipfile.BadZipFile):
            ok = False
        if ok:
            done[i] = item
        else:
            f.unlink(missing_ok=True)
    return done


def _open_journal(out: Path, plan: CollectionPlan) -> Path:
    partial = _partial_dir(out)
    manifest = partial / "plan.json"
    if partial.exists():
        try:
            previous = json.loads(manifest.read_text())
        except (OSError, ValueError):
            previous = None
        if previous is not None and not same_plan(previous, plan):
            raise UserError(
                f"{partial} holds an interrupted collection with other settings; re-run it "
                f"with the same settings to finish it, or delete {partial} to start over")
    partial.mkdir(parents=True, exist_ok=True)
    write_atomic(manifest, lambda f: f.write(json.dumps(to_json(plan), indent=1)), False)
    return partial


# --------------------------------------------------------------------------- the command
def collect(out: str | os.PathLike, plan: CollectionPlan, workers: int = 2,
            progress: Callable[[Iterable, int, int], Iterable] | None = None,
            executor: Executor | None = None) -> Path:
    """Collect `plan` into the trajectory file `out`, resuming an interrupted run.

    `progress(iterable, total, initial)` wraps the stream of finished trajectories (a
    progress bar); None shows nothing. With an `executor` (the study's), the trajectories
    are cut into shards, one job each, and `workers` is not used. Returns the path of the
    finished file.
    """
    out = Path(out)
    if workers < 1:
        raise UserError(f"--workers {workers}: use 1 or more worker processes")
    with exclusive(out, "trajectory file"):  # one collection into `out` at a time
        return _collect(out, plan, workers, progress, executor)


def _collect(out: Path, plan: CollectionPlan, workers: int,
             progress: Callable[[Iterable, int, int], Iterable] | None,
             executor: Executor | None) -> Path:
    if out.exists():
        try:
            existing = read_sequences(out)
        except UserError as e:
            raise UserError(f"--out {out} exists and is not a usable trajectory file ({e}); "
                            "delete it or choose another --out") from e
        recorded = existing.record.get("collection", {}).get("plan")
        if same_plan(recorded, plan):
            return out  # already complete
        raise UserError(f"{out} already exists with other collection settings; choose another "
                        "--out or delete the file")
    if out.suffix not in (".h5", ".hdf5"):
        raise UserError(f"--out {out}: trajectory files end in .h5")
    env = plan.env
    check_memory(plan.trajectories * (plan.steps + 1) * env.channels * env.image_size**2
                 + 16 * env.render_size**2, f"{plan.trajectories} trajectories of "
                 f"{env.image_size}x{env.image_size} images", "collect fewer or smaller images")
    partial = _open_journal(out, plan)
    done = _load_done(partial, plan)
    todo = [i for i in range(plan.trajectories) if i not in done]

    results = _run(todo, plan, workers) if executor is None else _run_on(executor, todo, plan)
    if progress is not None:
        results = progress(results, plan.trajectories, len(done))
    for i, item in results:
        _save_atomic_npz(partial / f"traj_{i:06d}.npz", item)
        done[i] = item

    order = range(plan.trajectories)
    data = push_data(
        images=np.stack([done[i]["images"] for i in order]),
        actions=np.stack([done[i]["actions"] for i in order]),
        poses=np.stack([done[i]["poses"] for i in order]),
        executed=np.stack([done[i]["executed"] for i in order]),
        split_ids=plan.split_ids(),
        env_config=plan.env,
        seed=plan.seed,
        collection={"plan": to_json(plan),
                    "attempts": [int(done[i]["attempts"]) for i in order]},
        source=str(out),
    )
    write_sequences(out, data)
    shutil.rmtree(partial, ignore_errors=True)
    return out


def _run(todo: list[int], plan: CollectionPlan, workers: int):
    """Yield (index, trajectory) as they finish, in-process or from worker processes."""
    if not todo:
        return
    if workers == 1:
        from latent_sindy.worlds.push.panda_push import PandaPushEnv

        env = PandaPushEnv(plan.env)
        try:
            for i in todo:
                yield i, collect_one(env, i, plan)
        finally:
            env.close()
        return
    ctx = mp.get_context("spawn")  # fresh interpreters: no inherited PyBullet or torch state
    with ctx.Pool(min(workers, len(todo)), initializer=_worker_init,
                  initargs=(to_json(plan.env),)) as pool:
        yield from pool.imap_unordered(_worker_run, [(i, plan) for i in todo])


#: Shards per slot of an executor: small enough that the slots finish together, large
#: enough that building an environment (a fraction of one trajectory) stays negligible.
SHARDS_PER_SLOT = 4


def _indices(shard: tuple[int, ...]) -> str:
    """A shard's trajectory indices for messages: "0, 4, 8" or "0, 4, ... (25 of them)"."""
    if len(shard) <= 3:
        return ", ".join(map(str, shard))
    return f"{shard[0]}, {shard[1]}, ... ({len(shard)} of them)"


def _run_on(executor: Executor, todo: list[int], plan: CollectionPlan):
    """Yield (index, trajectory) as the shards of ``todo`` finish on ``executor``."""
    n = min(len(todo), SHARDS_PER_SLOT * executor.slots)
    shards = [tuple(todo[k::n]) for k in range(n)]
    pending = {executor.submit(collect_shard, plan, shard,
                               name=f"collecting trajectories {_indices(shard)}"): shard
               for shard in shards}
    try:
        while pending:
            for fut in executor.wait_one(pending):
                del pending[fut]
                yield from fut.result()
    finally:
        for fut in pending:
            fut.cancel()
