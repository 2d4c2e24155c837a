"""The principal-component front of a large video: subspace iteration against the exact
eigendecomposition, in one process.

The front (``models/pca_front.py``) takes the first k principal directions of up to 8192
training frames. Where frames and pixels both number more than ``EXACT_BELOW`` it finds them
by subspace iteration; this script times both ways on one video of the drawn family and
prints how close the directions are (the cosines of the principal angles between the two
subspaces: 1 is the same subspace) and the variance each captures.

    python benchmarks/pca_front.py                   # draw 0 of seed 1 (113 x 138 frames of 75 px)
    python benchmarks/pca_front.py --seed 0 --draw 3 --components 48
    python benchmarks/pca_front.py --smoke     # a 16-px video, the iteration forced (tests)
"""

from __future__ import annotations

import argparse
import sys
import time

import torch


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=1, help="the family's draw seed")
    p.add_argument("--draw", type=int, default=0, help="which draw of the seed")
    p.add_argument("--components", type=int, default=48, help="principal directions (k)")
    p.add_argument("--smoke", action="store_true",
                   help="a 16-px video of 20 x 30 frames, k = 8, subspace iteration forced")
    args = p.parse_args(argv)

    import dataclasses

    import numpy as np

    import latent_sindy.models.pca_front as front
    from latent_sindy.worlds.pendulum.video_draws import draw

    d = draw(np.random.default_rng([args.seed, args.draw]))
    if args.smoke:
        d = dataclasses.replace(d, size=16, trajectories=20, frames=30)
        args.components = min(args.components, 8)
    video = d.video()
    x = torch.as_tensor(video.images).flatten(0, 1).flatten(1).float()
    x = (x - x.mean()) / x.std()
    print(f"draw {args.draw} of seed {args.seed}: {d.describe()}")
    print(f"{len(x)} frames of {x.shape[1]} pixels; the front fits on "
          f"{min(len(x), front.FRONT_FRAMES)} of them, k = {args.components}")
    results = {}
    for name, below in (("exact eigendecomposition", 10 ** 12),
                        ("subspace iteration", 16 if args.smoke else front.EXACT_BELOW)):
        saved = front.EXACT_BELOW
        front.EXACT_BELOW = below
        try:
            t0 = time.perf_counter()
            _, basis, spread = front.principal_components(x, args.components)
            results[name] = (time.perf_counter() - t0, basis.double(), spread)
        finally:
            front.EXACT_BELOW = saved
    (t_exact, b_exact, s_exact), (t_iter, b_iter, s_iter) = results.values()
    cosines = torch.linalg.svdvals(b_exact.T @ b_iter)
    print(f"exact eigendecomposition: {t_exact:7.2f} s   rms coordinate {s_exact:.6f}")
    print(f"subspace iteration:       {t_iter:7.2f} s   rms coordinate {s_iter:.6f}")
    print(f"subspace iteration / exact: {t_iter / t_exact:.3f} of the time; cosines of the "
          f"principal angles: min {float(cosines.min()):.8f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
