"""How well the moments encoder reads the block's pose from a trajectory file's images.

Fits the encoder's background on the training split (as training does), encodes every image,
fits a linear map from the centroid to the block's (x, y) in metres by least squares, and
compares the angle of the n-th moment with nθ after removing one constant phase (the
camera's turn) and the sign (the image's y axis points down). Prints the position error in
cm and the orientation error in degrees modulo the block's symmetry.

    .venv/bin/python benchmarks/moments.py --data results/demo/data.h5
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from latent_sindy.data import read_sequences
from latent_sindy.data.windows import Normalizer
from latent_sindy.models.autoencoder import MomentEncoder
from latent_sindy.models.autoencoder_parts import MomentEncoderConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True)
    args = ap.parse_args()
    data = read_sequences(args.data)
    order = round(2 * math.pi / data.world_config.angle_period)
    _, _, c, s, _ = data.images.shape
    enc = MomentEncoder(MomentEncoderConfig(order=order), (c, s, s))
    norm = Normalizer.from_trajectories(data)
    enc.fit_statistics(norm.normalize(data.split("train").images).reshape(-1, c, s, s))
    with torch.no_grad():
        z = enc(norm.normalize(data.images).reshape(-1, c, s, s)).double().numpy()
    pose = data.poses.reshape(-1, 3).astype(np.float64)
    a = np.c_[z[:, :2], np.ones(len(z))]
    coef, *_ = np.linalg.lstsq(a, pose[:, :2], rcond=None)
    pos = 100 * np.linalg.norm(a @ coef - pose[:, :2], axis=1)
    read = np.arctan2(z[:, 3], z[:, 2])
    best = None
    for sign in (1, -1):
        d = sign * read - order * pose[:, 2]
        phase = np.angle(np.exp(1j * d).mean())
        err = np.degrees(np.abs(np.angle(np.exp(1j * (d - phase))))) / order
        if best is None or err.mean() < best.mean():
            best = err
    r2 = 1 - ((a @ coef - pose[:, :2]) ** 2).sum(0) / ((pose[:, :2] - pose[:, :2].mean(0)) ** 2
                                                      ).sum(0)
    print(f"{args.data}: {len(z)} images, moment order {order}")
    print(f"position: mean {pos.mean():.2f} cm, 90th percentile {np.quantile(pos, 0.9):.2f} cm, "
          f"R² x {r2[0]:.4f} y {r2[1]:.4f}")
    print(f"orientation (modulo {360 / order:g}°): mean {best.mean():.2f}°, 90th percentile "
          f"{np.quantile(best, 0.9):.2f}°, within 10°: {100 * (best < 10).mean():.1f} %")


if __name__ == "__main__":
    main()
