"""How the hand-made moments encoder reads the block's pose in the textured world, beside the
symmetric one (and each of the textured world's three parts alone).

The same random block poses (uniform in the workspace) are rendered in every world, each
picture its own episode: the look (light, distractor) drawn from a per-picture seed that is
the same in every world. The first half of the pictures stands in for training data: the
moments encoder's background is their per-pixel median (as training sets it) and a linear map
from its centroid to the block's (x, y) in metres is fitted on them by least squares; the
orientation's constant phase and sign (the camera's turn and the image's downward y) are
fitted there too. The second half is scored: position error in cm, orientation error in
degrees modulo the block's symmetry, and how much of the encoder's weight |image -
background| falls on the block (pixels within 3 of its centre): 100 % is a block cleanly
isolated. An orientation read at random errs by 22.5 degrees on average (modulo 90).

    .venv/bin/python benchmarks/textured_world.py --poses 400 --seed 0
    .venv/bin/python benchmarks/textured_world.py --smoke     # 12 poses (the tests)
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np
import torch

from latent_sindy.models.autoencoder import MomentEncoder
from latent_sindy.models.autoencoder_parts import MomentEncoderConfig
from latent_sindy.script_args import parse_with_smoke
from latent_sindy.worlds.push.config import BLOCK_SIZE, PushEnvConfig
from latent_sindy.worlds.push.scene import CameraView, draw_look

TEXTURED = PushEnvConfig.named("textured")
PLAIN = {"table_look": "plain", "lighting": "fixed", "distractor": False}
#: The worlds compared: name -> config (the textured world, then its parts one at a time).
WORLDS = {
    "symmetric": PushEnvConfig.named("symmetric"),
    "textured": TEXTURED,
    "table only": dataclasses.replace(TEXTURED, lighting="fixed", distractor=False),
    "light only": dataclasses.replace(TEXTURED, **{**PLAIN, "lighting": "varied"}),
    "distractor only": dataclasses.replace(TEXTURED, **{**PLAIN, "distractor": True}),
}


def render(cfg: PushEnvConfig, poses: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """(N, C, S, S) uint8: pose i in world ``cfg``, seen in the look of seed i."""
    view = CameraView(cfg)
    try:
        out = []
        for pose, seed in zip(poses, seeds, strict=True):
            view.set_look(draw_look(cfg, int(seed)))
            out.append(view.observe(pose))
        return np.stack(out)
    finally:
        view.close()


def score(cfg: PushEnvConfig, images: np.ndarray, poses: np.ndarray) -> dict[str, float]:
    """The moments encoder's errors on the second half, fitted on the first."""
    n, c, s, _ = images.shape
    order = round(2 * math.pi / cfg.angle_period)
    enc = MomentEncoder(MomentEncoderConfig(order=order), (c, s, s))
    x = torch.from_numpy(images).float() / 255
    train, test = slice(0, n // 2), slice(n // 2, n)
    enc.fit_statistics(x[train])
    with torch.no_grad():
        z = enc(x).double().numpy()  # (N, 4): centroid, cos n phi, sin n phi
        w = (x - enc.background).abs().sum(1).numpy()  # (N, S, S): the encoder's weights
    a = np.c_[z[:, :2], np.ones(n)]
    coef, *_ = np.linalg.lstsq(a[train], poses[train, :2], rcond=None)
    pos = 100 * np.linalg.norm(a[test] @ coef - poses[test, :2], axis=1)
    read = np.arctan2(z[:, 3], z[:, 2])
    best = None
    for sign in (1, -1):
        d = sign * read - order * poses[:, 2]
        phase = np.angle(np.exp(1j * d[train]).mean())
        err = np.degrees(np.abs(np.angle(np.exp(1j * (d[test] - phase))))) / order
        if best is None or err.mean() < best.mean():
            best = err
    cam = CameraView(cfg).camera
    rc = cam.world_to_pixel(np.c_[poses[test, :2], np.full(n - n // 2, BLOCK_SIZE[2])])
    rr, cc = np.mgrid[:s, :s]
    near = np.hypot(rr[None] - rc[:, :1, None], cc[None] - rc[:, 1:, None]) <= 3
    share = (w[test] * near).sum((1, 2)) / np.maximum(w[test].sum((1, 2)), 1e-12)
    return {"position mean (cm)": pos.mean(), "position 90th pct (cm)": np.quantile(pos, 0.9),
            "orientation mean (deg)": best.mean(),
            "orientation 90th pct (deg)": np.quantile(best, 0.9),
            "orientation within 10 deg (%)": 100 * (best < 10).mean(),
            "weight on the block (%)": 100 * share.mean()}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--poses", type=int, default=400, help="pictures per world (half fit)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the poses and the looks")
    ap.add_argument("--channels", type=int, default=1, choices=(1, 3))
    args = parse_with_smoke(ap, argv, {"poses": 12})
    torch.set_num_threads(1)
    rng = np.random.default_rng(args.seed)
    low, high = np.array(TEXTURED.workspace_low), np.array(TEXTURED.workspace_high)
    poses = rng.uniform(low, high, size=(args.poses, 3))
    seeds = rng.integers(2**63, size=args.poses)
    t0 = time.perf_counter()
    rows: dict[str, list[float]] = {}
    for cfg in WORLDS.values():
        cfg = dataclasses.replace(cfg, channels=args.channels)
        for k, v in score(cfg, render(cfg, poses, seeds), poses).items():
            rows.setdefault(k, []).append(float(v))
    print(f"moments encoder, {args.poses} poses ({args.poses - args.poses // 2} scored), seed "
          f"{args.seed}, {args.channels} channel(s), {time.perf_counter() - t0:.0f} s")
    width = max(map(len, rows)) + 2
    print(" " * width + "".join(f"{name:>17}" for name in WORLDS))
    for k, values in rows.items():
        print(f"{k:<{width}}" + "".join(f"{v:>17.2f}" for v in values))


if __name__ == "__main__":
    main()
