"""What the DeepMind Control world costs on this machine: a camera frame, and a collection.

Renders the camera of a task's physics (headless: ``MUJOCO_GL``, egl unless set) at a few
sizes, then collects random-action sequences through the world's collect hook (an action
repeat of physics steps, one frame rendered per action), and prints ms a frame and actions
a second.

    python benchmarks/dmc.py                              # cartpole-swingup
    python benchmarks/dmc.py --task reacher-easy --sequences 5 --steps 20
    python benchmarks/dmc.py --smoke                      # tiny sizes, seconds (the tests)
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from latent_sindy.script_args import parse_with_smoke


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="cartpole-swingup")
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 84])
    p.add_argument("--frames", type=int, default=50, help="renders timed per size")
    p.add_argument("--sequences", type=int, default=10)
    p.add_argument("--steps", type=int, default=20)
    args = parse_with_smoke(p, argv, {"sizes": [32], "frames": 2, "sequences": 1, "steps": 3})

    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.env import DmcPixelEnv
    from latent_sindy.worlds.dmc.plugin import DmcWorld

    print(f"task {args.task}, MUJOCO_GL={os.environ.get('MUJOCO_GL', '(egl, set on load)')}")
    for size in args.sizes:
        env = DmcPixelEnv(DmcConfig(task=args.task, size=size))
        env.reset(seed=0)
        t0 = time.perf_counter()
        for _ in range(args.frames):
            env.render_frame()
        ms = (time.perf_counter() - t0) / args.frames * 1e3
        t0 = time.perf_counter()
        for _ in range(args.frames):
            env.dm.step(np.zeros(env.action_low.shape))
        physics_ms = (time.perf_counter() - t0) / args.frames * 1e3
        env.close()
        print(f"  {size}x{size}: {ms:.1f} ms a frame rendered, {physics_ms:.2f} ms a control "
              "step of physics")
    world = DmcWorld(DmcConfig(task=args.task))
    world.collect(1, 1, seed=0)  # (the model loaded once, as any first use does)
    t0 = time.perf_counter()
    data = world.collect(args.sequences, args.steps, seed=0)
    wall = time.perf_counter() - t0
    actions = data.n * data.steps
    print(f"  collect {data.n} x {data.steps} at {world.config.size}x{world.config.size}, "
          f"{world.config.frames} frames, repeat {world.config.action_repeat}: {wall:.1f} s, "
          f"{actions / wall:.1f} actions/s ({data.n * (data.steps + 1) / wall:.1f} frames/s); "
          f"rewards {data.rewards.mean():.3f} mean an action")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
