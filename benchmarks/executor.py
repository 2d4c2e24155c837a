"""The study's executors: wall time of a tiny study locally, on a one-node Ray and on a two-node
Ray on this machine; and the paper-scale study projected onto N nodes from measured job times.

Part 1 runs ``reproduce --scale tiny`` three times into fresh folders (local executor with
--workers 2; Ray started here with 2 CPUs; a two-node Ray cluster, 1 CPU per node, both on this
machine) and prints each wall time and its stages. On one machine Ray can only add overhead:
the same 2 cores do the same jobs.

Part 2 (with --data, a trajectory file of the paper's size, e.g. results/demo/data.h5) measures
one job of every model of the paper scale on one thread: 2 training epochs at the paper's batch
(seconds per epoch from the run record's time_s of the last epoch), the evaluation (losses,
prediction error) and one closed-loop episode per condition. A job at paper scale is projected as
3000 epochs x s/epoch + evaluation + episodes x s/episode for each condition; the (model, seed)
chains are then scheduled longest first on N nodes of this machine's size.

    .venv/bin/python benchmarks/executor.py --data results/demo/data.h5 --seeds 3
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import tempfile
import time
from pathlib import Path

from latent_sindy.training import RunDir, TrainConfig
from latent_sindy.worlds.push.study.catalogue import model_specs
from latent_sindy.worlds.push.study.config import ReproduceConfig
from latent_sindy.worlds.push.study.jobs import EvalJob, TrainJob, eval_job, train_job
from latent_sindy.worlds.push.study.pipeline import reproduce
from latent_sindy.worlds.push.study.scales import SCALES

PROBE_EPOCHS = 2


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


# ----------------------------------------------------------------------------- part 1
def tiny_study(work: Path, name: str, **settings) -> dict:
    out = work / name
    t0 = time.perf_counter()
    reproduce(ReproduceConfig(scale="tiny", out=out, verbose=False, **settings), lambda _: None)
    wall = time.perf_counter() - t0
    timings = json.loads((out / "summary.json").read_text())["timings_s"]
    return {"wall": wall, **timings}


def part1(work: Path) -> None:
    from ray.cluster_utils import Cluster

    rows = [("local, 2 processes", tiny_study(work, "local", workers=2))]
    rows.append(("Ray, 1 node (2 CPUs)", tiny_study(work, "ray1", executor="ray", workers=2)))
    cluster = Cluster(initialize_head=True,
                      head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        rows.append(("Ray, 2 nodes (1 CPU each)",
                     tiny_study(work, "ray2", executor="ray", ray_address=cluster.address)))
    finally:
        cluster.shutdown()
    base = rows[0][1]["wall"]
    print(f"tiny study (10 models x 1 seed, 2 epochs), load average after: {load()}")
    print(f"{'executor':28s} {'wall s':>7s} {'collect':>8s} {'jobs':>7s} {'outputs':>8s}"
          f" {'x local':>8s}")
    for name, t in rows:
        print(f"{name:28s} {t['wall']:7.1f} {t['collect']:8.1f} "
              f"{t['train_evaluate_control']:7.1f} {t['outputs']:8.1f} {base / t['wall']:8.2f}")


# ----------------------------------------------------------------------------- part 2
def probe(data: Path, work: Path, world: str) -> list[dict]:
    """Measured one-thread job times of every paper-scale model (see the module docstring)."""
    paper = SCALES["paper"]
    found = []
    for spec in model_specs(paper):
        out = work / "probe" / spec.name
        tc = TrainConfig(data=data, out=out, model=spec.model, loss=spec.loss,
                         window=spec.window, epochs=PROBE_EPOCHS, batch_size=paper.batch_size,
                         prune_below=paper.prune_below, prune_every=paper.prune_every,
                         eval_every=1, seed=0)
        train_job(TrainJob(tc, spec.name, 0, 1, False, spec.relative_time))
        s_epoch = RunDir(out).read_metrics()[-1]["time_s"]
        base = eval_job(EvalJob(out, data, spec.name, 0, (), 1)).seconds  # losses, cached
        episodes = {}
        for cond in paper.conditions(spec):
            one = dataclasses.replace(paper.control_config(cond, 0, world), episodes=1)
            t = eval_job(EvalJob(out, data, spec.name, 0, ((cond, one),), 1)).seconds
            episodes[cond.name] = (t, cond.episodes)
        train_s = paper.epochs * s_epoch
        eval_s = base + sum(t * n for t, n in episodes.values())
        found.append({"model": spec.name, "s_epoch": s_epoch, "train_s": train_s,
                      "eval_base_s": base, "episodes": episodes, "eval_s": eval_s})
        print(f"  {spec.name:12s} {s_epoch:6.2f} s/epoch -> train {train_s / 3600:5.2f} h; "
              f"evaluation {base:5.1f} s; per episode "
              + ", ".join(f"{c} {t:.1f} s x {n}" for c, (t, n) in episodes.items())
              + f" -> {eval_s / 3600:5.2f} h  (load {load()})", flush=True)
    return found


def schedule(chains: list[float], slots: int) -> float:
    """Makespan of the chains placed longest first, each on the least loaded slot."""
    loads = [0.0] * slots
    for c in sorted(chains, reverse=True):
        i = loads.index(min(loads))
        loads[i] += c
    return max(loads)


def part2(data: Path, work: Path, seeds: int, cores: int, nodes: list[int], world: str) -> None:
    print(f"paper scale: one-thread job times measured on {data} ({PROBE_EPOCHS} epochs at "
          f"batch {SCALES['paper'].batch_size}, 1 episode per condition)")
    jobs = probe(data, work, world)
    chains = [j["train_s"] + j["eval_s"] for j in jobs] * seeds
    total = sum(chains)
    print(f"\nprojected paper-scale study, {len(jobs)} models x {seeds} seed(s) = "
          f"{len(chains)} jobs, {total / 3600:.1f} CPU-hours; nodes of {cores} cores, "
          "1 thread per job")
    print(f"{'nodes':>5s} {'slots':>5s} {'hours':>7s} {'x 1 node':>8s}")
    one = schedule(chains, cores)
    for n in nodes:
        t = schedule(chains, n * cores)
        print(f"{n:5d} {n * cores:5d} {t / 3600:7.1f} {one / t:8.2f}")
    print(f"floor: the longest job, {max(chains) / 3600:.1f} h "
          f"({max(jobs, key=lambda j: j['train_s'] + j['eval_s'])['model']})")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, help="paper-sized trajectory file for the projection")
    p.add_argument("--seeds", type=int, default=3, help="seeds of the projected study")
    p.add_argument("--cores", type=int, default=os.cpu_count() or 1,
                   help="cores per projected node (default: this machine's)")
    p.add_argument("--nodes", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    p.add_argument("--world", default="symmetric", help="world of the planner settings")
    p.add_argument("--skip-tiny", action="store_true", help="only the projection")
    args = p.parse_args()
    import torch

    print(f"machine: {os.cpu_count()} cores, torch {torch.__version__}, load average {load()}")
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        if not args.skip_tiny:
            part1(work)
        if args.data is not None:
            part2(args.data, work, args.seeds, args.cores, args.nodes, args.world)


if __name__ == "__main__":
    main()
