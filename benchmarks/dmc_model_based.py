"""A smoke run of the model-based loop (PlaNet's: seed episodes, fit, plan against the learned
reward, refit) on a DeepMind Control task from pixels: times and returns, not the benchmark.

Prints, per episode, its kind (random or planned), return and environment steps so far, and
the wall time of every fit and planned episode; with ``--out`` the run is resumable.

    python benchmarks/dmc_model_based.py                     # cartpole-swingup, SINDy, tiny
    python benchmarks/dmc_model_based.py --dynamics linear --iterations 3 --out runs/mb
    python benchmarks/dmc_model_based.py --smoke          # tiny sizes, seconds (the tests)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from latent_sindy.script_args import parse_with_smoke


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="cartpole-swingup")
    p.add_argument("--size", type=int, default=32)
    p.add_argument("--dynamics", default="sindy", choices=["sindy", "linear", "mlp"])
    p.add_argument("--latent-dim", type=int, default=6)
    p.add_argument("--seed-episodes", type=int, default=5)
    p.add_argument("--iterations", type=int, default=2)
    p.add_argument("--steps", type=int, default=100, help="actions an episode")
    p.add_argument("--epochs", type=int, default=60)
    p.add_argument("--window", type=int, default=4)
    p.add_argument("--samples", type=int, default=300)
    p.add_argument("--horizon", type=int, default=12)
    p.add_argument("--warm-updates", type=int, default=100,
                   help="updates of each refit after the first, continuing the last model; "
                        "0: every fit from scratch (as the smoke run of RESULTS.md)")
    p.add_argument("--lambda", dest="lambda_", type=float, default=1.0)
    p.add_argument("--foreground-weight", type=float, default=0.0,
                   help="extra weight of the moving pixels in the image terms")
    p.add_argument("--eval-episodes", type=int, default=0,
                   help="test episodes after each fit, without exploration noise")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None)
    args = parse_with_smoke(p, argv, {"size": 16, "seed_episodes": 1, "iterations": 1,
                                      "steps": 4, "epochs": 1, "window": 2, "samples": 8,
                                      "horizon": 2, "warm_updates": 0})

    import torch

    from latent_sindy import LatentSINDy
    from latent_sindy.control import MPPIConfig
    from latent_sindy.model_based import ModelBasedConfig, model_based
    from latent_sindy.models import DYNAMICS_KINDS, AutoencoderConfig, LossWeights, ModelConfig
    from latent_sindy.progress import say_stderr
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.plugin import DmcWorld

    torch.set_num_threads(1)
    world = DmcWorld(DmcConfig(task=args.task, size=args.size))
    repeat = world.config.action_repeat
    model = ModelConfig(dynamics=DYNAMICS_KINDS[args.dynamics](),
                        observation=AutoencoderConfig(latent_dim=args.latent_dim),
                        reward_head=64)

    def make(iteration: int) -> LatentSINDy:
        return LatentSINDy(model=model, seed=args.seed * 1000 + iteration,
                           loss=LossWeights(foreground_weight=args.foreground_weight))

    class Say:
        def start(self, total: int, initial: int) -> None: ...
        def update(self, epoch: int, metrics: dict) -> None:
            say_stderr(f"iteration {epoch}: {metrics}")
        def note(self, text: str) -> None:
            say_stderr(text)
        def close(self) -> None: ...

    cfg = ModelBasedConfig(seed_episodes=args.seed_episodes, iterations=args.iterations,
                           episode_steps=args.steps, steps_per_action=repeat, seed=args.seed,
                           warm_updates=args.warm_updates, eval_episodes=args.eval_episodes,
                           mppi=MPPIConfig(samples=args.samples, horizon=args.horizon,
                                           sigma=0.3, lambda_=args.lambda_, shift="repeat"))
    t0 = time.perf_counter()
    result = model_based(world, make, cfg, out=args.out, progress=Say(),
                         fit_settings={"epochs": args.epochs, "window": args.window})
    wall = time.perf_counter() - t0
    print(f"task {args.task}, {args.size}x{args.size}, {world.config.frames} frames, repeat "
          f"{repeat}; {args.dynamics}, nz {args.latent_dim}, {args.epochs} epochs, window "
          f"{args.window}; MPPI K {args.samples} H {args.horizon}")
    print("episode  kind     return  env_steps  seconds")
    for e in result.log["episodes"]:
        print(f"{e['episode']:7d}  {e['kind']:7s}  {e['return']:6.2f}  {e['env_steps']:9d}  "
              f"{e['seconds']:7.2f}")
    for it in result.log["iterations"]:
        test = it.get("evaluation") or []
        print(f"iteration {it['iteration']}: fit {it['fit_seconds']:.1f} s"
              + (f"; test returns {', '.join(f'{r:.1f}' for r in test)} (fit on "
                 f"{it['fit_env_steps']} environment steps)" if test else ""))
    kinds = np.array([e["kind"] for e in result.log["episodes"]])
    returns = np.array(result.returns)
    for kind in ("random", "planned"):
        if (kinds == kind).any():
            print(f"{kind}: mean return {returns[kinds == kind].mean():.2f} "
                  f"over {(kinds == kind).sum()} episodes")
    print(f"wall {wall:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
