"""How much of the physics state a latent learned from the frames alone holds: the geodesic
reader (:class:`~latent_sindy.models.geodesic_reader.GeodesicReader`) or the keypoint reader
(:class:`~latent_sindy.models.keypoint_reader.KeypointReader`), neither with world knowledge,
probed against the state a task's reward needs.

Per task: random-action episodes seen as two stacked frames; the reader fitted on the first
``--train`` of them; on the others (frames no fit saw; of those, the frames the reader
marks seen: all of them for the geodesic reader, those that show every part the keypoint
reader follows for it), each state feature regressed on the
latent (positions and rates, or an angle's cos, sin and turn rate where the coordinates
wind round; not the action) by least squares, once on the latent itself (a linear probe)
and once on its monomials to degree 2 (a rate on a circle is a product of position and
velocity, which a linear probe cannot see). Prints R² per feature and probe,
and the reader's fitting time.

Tasks: ``pendulum`` (Gymnasium's Pendulum-v1: cos θ, sin θ, θ̇) and ``cartpole``
(DeepMind Control's cartpole-swingup: x, cos θ, sin θ, ẋ, θ̇; needs the dmc extra).

    python benchmarks/latent_probe.py --task pendulum
    python benchmarks/latent_probe.py --task cartpole --dim 2 3 4
    python benchmarks/latent_probe.py --task cartpole --reader keypoints --parts 4
    python benchmarks/latent_probe.py --task pendulum --record results   # rows into
                                 # results/gym/latent-probe.csv (cartpole: results/dmc/)
    python benchmarks/latent_probe.py --smoke          # tiny sizes, seconds (the tests)

``--study OUT`` probes a model-based study's own latent instead (``latent-sindy reproduce
--world dmc|gym`` on a geodesic or keypoints scale): its reader made as the study made it,
fitted on a seed's random episodes (a keypoint reader's fit loads from ``OUT/readers``:
nothing is trained again), probed on that seed's planned episodes.

    python benchmarks/latent_probe.py --study runs/kp100k --seed 0
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from latent_sindy.models.geodesic_reader import GeodesicReader
from latent_sindy.models.keypoint_reader import KeypointReader
from latent_sindy.script_args import parse_with_smoke, positive_int

#: Each task's world (the result file's folder) and its features' column names.
WORLDS = {"pendulum": "gym", "cartpole": "dmc"}
COLUMNS = {"x": "x", "cos θ": "cos_theta", "sin θ": "sin_theta", "x'": "x_rate",
           "θ'": "theta_rate"}


#: Each task's state features: their names and how they come from the data's states.
FEATURES = {
    "pendulum": (("cos θ", "sin θ", "θ'"), lambda s: s),
    "cartpole": (("x", "cos θ", "sin θ", "x'", "θ'"), lambda s: np.stack(
        [s[..., 0], np.cos(s[..., 1]), np.sin(s[..., 1]), s[..., 2], s[..., 3]], -1)),
}


def _world(task: str, size: int):
    """The task's world and how its state features come from the data's states."""
    if task == "pendulum":
        from latent_sindy.worlds.gym import GymConfig, GymWorld

        world = GymWorld(GymConfig(id="Pendulum-v1", size=size, frames=2))
    else:
        from latent_sindy.worlds.dmc.config import DmcConfig
        from latent_sindy.worlds.dmc.world import DmcWorld

        world = DmcWorld(DmcConfig(task="cartpole-swingup", size=size, frames=2))
    return (world, *FEATURES[task])


def _quadratic(z: np.ndarray) -> np.ndarray:
    i, j = np.triu_indices(z.shape[1])
    return np.column_stack([z, z[:, i] * z[:, j]])


def _r2(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    a = np.column_stack([x, np.ones(len(x))])
    coef = np.linalg.lstsq(a, y, rcond=None)[0]
    return 1 - (y - a @ coef).var(0) / y.var(0)


def probe(task: str, episodes: int, train: int, steps: int, size: int, dims: list[int],
          seed: int, landmarks: int, reader_kind: str = "geodesic", updates: int = 6000
          ) -> list[dict]:
    """R² rows per latent size (``dims``: geodesic coordinates, or keypoints for
    ``reader_kind`` "keypoints", ``updates`` Adam updates) and probe."""
    world, names, features = _world(task, size)
    data = world.collect(episodes, steps, seed=seed)
    images = torch.from_numpy(np.asarray(data.images))
    actions = torch.from_numpy(np.asarray(data.actions, np.float64))
    y_all = features(np.asarray(data.states, np.float64)[train:]).reshape(-1, len(names))
    dt = _dt(data)
    rows = []
    for dim in dims:
        reader = (GeodesicReader(frames=2, dim=dim, landmarks=landmarks, seed=seed)
                  if reader_kind == "geodesic" else
                  KeypointReader(frames=2, parts=dim, steps=updates, seed=seed,
                                 progress=updates > 100))
        rows += _probed(reader, images[:train], images[train:], actions[train:], dt, y_all,
                        {"task": task, "dim": dim, "reader": reader_kind}, names)
    return rows


def _dt(data) -> float:
    """The data's time step (changes per second), else 1 (per step: the probe standardises)."""
    return float(data.dt) if data.dt is not None else 1.0


def _probed(reader, fit_on: torch.Tensor, images: torch.Tensor, actions: torch.Tensor,
            dt: float, y: np.ndarray, about: dict, names: tuple[str, ...]) -> list[dict]:
    """``reader`` fitted on the episodes ``fit_on`` and probed on the episodes ``images``
    (their features ``y``, flattened): a linear and a quadratic row."""
    t0 = time.perf_counter()
    reader.fit_episodes(fit_on)
    fit_s = time.perf_counter() - t0
    nu = actions.shape[-1]  # (the latent ends with the action held: not probed)
    read = [reader.episode(images[e], actions[e], dt) for e in range(len(images))]
    seen = torch.cat([s for _, s in read]).numpy()
    z = torch.cat([z[:, :-nu] for z, _ in read]).numpy()[seen]
    z = (z - z.mean(0)) / z.std(0).clip(1e-12)
    return [{**about, "probe": kind, "fit_s": fit_s, "seen": float(seen.mean()),
             "kept": len(reader.names) // 2, "read": "angle" if reader.circle else "coordinates",
             "found": reader.record()["summary"],
             **dict(zip(names, _r2(x, y[seen]).tolist(), strict=True))}
            for kind, x in (("linear", z), ("quadratic", _quadratic(z)))]


def probe_study(out: Path, seed: int) -> tuple[str, list[dict]]:
    """The rows of the study in ``out``'s latent at ``seed`` (the module docstring), and
    its task."""
    from latent_sindy.errors import UserError
    from latent_sindy.study.model_based import study_latent

    try:
        settings, s, make, data = study_latent(out, seed)
    except UserError as e:
        raise SystemExit(f"--study {e}") from None
    world = settings["world"]
    task = ("cartpole" if str(world.get("task", "")).startswith("cartpole") else
            "pendulum" if world.get("id") == "Pendulum-v1" else None)
    if task is None:
        raise SystemExit(f"--study {out}: its task ({world}) has no state features here: "
                         f"probe a cartpole task or Pendulum-v1")
    names, features = FEATURES[task]
    first = s.seed_episodes
    images = torch.from_numpy(np.asarray(data.images))
    actions = torch.from_numpy(np.asarray(data.actions, np.float64))
    y = features(np.asarray(data.states, np.float64)[first:]).reshape(-1, len(names))
    dt = _dt(data)
    return task, _probed(make(), images[:first], images[first:], actions[first:], dt, y,
                         {"task": task, "dim": s.latent_dim, "reader": s.latent,
                          "study": str(out), "episodes": data.n - first}, names)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", choices=("pendulum", "cartpole"), default="pendulum")
    p.add_argument("--episodes", type=positive_int, default=30, help="random episodes in all")
    p.add_argument("--train", type=positive_int, default=20,
                   help="episodes the reader is fitted on (the rest are probed)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="actions an episode (default: 200 pendulum, 125 cartpole)")
    p.add_argument("--size", type=positive_int, default=64)
    p.add_argument("--reader", choices=("geodesic", "keypoints"), default="geodesic",
                   help="the latent learned from the frames: their geodesic coordinates, or "
                        "keypoints of what moves (transported features)")
    p.add_argument("--dim", type=positive_int, nargs="+", default=[2],
                   help="geodesic coordinates (several: one probe each)")
    p.add_argument("--parts", type=positive_int, nargs="+", default=[4],
                   help="keypoints of the keypoint reader (several: one probe each)")
    p.add_argument("--updates", type=positive_int, default=6000,
                   help="the keypoint reader's Adam updates")
    p.add_argument("--landmarks", type=positive_int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--study", type=Path, default=None, metavar="OUT",
                   help="probe this model-based study's own latent at --seed (see above)")
    p.add_argument("--record", type=Path, default=None, metavar="DIR",
                   help="also write the rows into DIR/<world>/latent-probe.csv (the tracked "
                        "results: --record results)")
    args = parse_with_smoke(p, argv, {"episodes": 4, "train": 3, "steps": 12, "size": 16,
                                       "landmarks": 30, "updates": 5})
    if args.train >= args.episodes:
        p.error(f"--train {args.train}: use fewer than --episodes {args.episodes}, so that "
                "some episodes are probed")
    steps = args.steps or (200 if args.task == "pendulum" else 125)
    keypoints = args.reader == "keypoints"
    torch.set_num_threads(2 if keypoints else 1)
    if args.study is not None:
        if args.record is not None:
            p.error("--record takes the probe's own episodes; a study's probe is printed only")
        args.task, rows = probe_study(args.study, args.seed)
        keypoints = rows[0]["reader"] == "keypoints"
        print(f"{args.task}: the latent of the study {args.study}, seed {args.seed} "
              f"({rows[0]['reader']}: {rows[0]['found']}), probed on its "
              f"{rows[0]['episodes']} planned episodes")
    else:
        rows = probe(args.task, args.episodes, args.train, steps, args.size,
                     args.parts if keypoints else args.dim, args.seed, args.landmarks,
                     args.reader, args.updates)
        print(f"{args.task}: {args.reader} latent from {args.train} random episodes of "
              f"{steps} actions ({args.size}x{args.size}, 2 frames), probed on "
              f"{args.episodes - args.train} others")
    names = list(FEATURES[args.task][0])
    print(f"| {'keypoints (coordinates kept)' if keypoints else 'coordinates'} | read as | "
          "probe | " + " | ".join(names) + " | frames seen | reader fit s |")
    print("|---|---|---|" + "---|" * len(names) + "---|---|")
    for r in rows:
        size = f"{r['dim']} ({r['kept']})" if keypoints else f"{r['dim']}"
        print(f"| {size} | {r['read']} | {r['probe']} | "
              + " | ".join(f"{r[n]:.3f}" for n in names)
              + f" | {r['seen']:.2f} | {r['fit_s']:.1f} |")
    if args.record is not None:
        from latent_sindy.result_files import record_rows

        path = record_rows(args.record, WORLDS[args.task], "latent-probe", [
            {"model": (f"keypoints, {r['dim']} parts ({r['kept']} coordinates kept), "
                       f"{args.updates} updates, {r['probe']} probe" if keypoints else
                       f"geodesic, {r['dim']} coordinates read as {r['read']}, {r['probe']} "
                       "probe"), "seed": args.seed, "episodes": args.train, "steps": steps,
             "size": args.size, **{COLUMNS[n]: r[n] for n in names}, "seen": r["seen"],
             "fit_s": r["fit_s"]}
            for r in rows])
        print(f"recorded in {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
