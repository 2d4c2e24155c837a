"""The moments encoder against the learned-mask moments encoder ("mask_moments"), in the
standard and the textured pushing worlds: how well each latent holds the block's pose.

The moments encoder weighs each pixel by its difference from the training images' per-pixel
median and reads (x, y, cos 4φ, sin 4φ), 4 the block's symmetry set by hand from the world.
The mask_moments encoder weighs it by a learned mask (3×3 convolutions, sigmoid) times its
difference from the per-pixel median of per-image standardised training images, and reads
the same latent, its angular moment in a Gaussian window about the centroid (with
``--refine`` steps, the default 3, the centre first moves by mean shift onto the image's own
deviation, and the pose is read from that deviation rather than the masked weight). It learns
without pose labels: the autoencoder's reconstruction through the sprite decoder
(``LatentSINDy.fit``), with the symmetry order n chosen from the data: a first fit at a
provisional order, then :meth:`MaskMomentEncoder.symmetry_order` on the training images,
then a fresh fit at that order.

Each world's data file (train / val / test trajectories, ``latent-sindy collect``) is scored
on its test split, fitted on its training split:

* position error (cm): a least-squares linear map from the latent's (x, y) to the block's
  (x, y) in metres; orientation error (degrees, modulo the latent's symmetry 2π / n): the
  angle of (cos nφ, sin nφ) with its sign and constant phase fitted (as
  ``benchmarks/textured_world.py`` reads them; at random, 22.5° for n = 4);
* R² of the linear and the kernel probes (``worlds/push/study/probe.py``) for x, y and the angle
  (mean of the cos and sin features');
* a SINDy model (order-2 polynomial library, STLSQ at ``--min-share``) fitted to each
  latent's training transitions: active terms and its one-push latent squared error on the
  test split, in % of that of "nothing moves".

    .venv/bin/python benchmarks/learned_moments.py --standard results/demo/data.h5 \\
        --textured /tmp/ml23/textured.h5 --epochs 90 --seed 0
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import torch

from latent_sindy import LatentSINDy
from latent_sindy.data import SequenceData
from latent_sindy.data.store import read_sequences
from latent_sindy.data.windows import Normalizer
from latent_sindy.models import AutoencoderConfig, ModelConfig, SindyConfig
from latent_sindy.models.latent_model import LatentModel, LossWeights
from latent_sindy.sindy import STLSQ
from latent_sindy.training import TrainConfig
from latent_sindy.worlds.push.study.probe import latent_probes


def encode(model: LatentModel, data: SequenceData, norm: Normalizer) -> torch.Tensor:
    """Latents (N, T+1, 4) of every image of ``data``."""
    with torch.no_grad():
        return model.encode(norm.normalize(data.images))


def readout(z_tr: np.ndarray, p_tr: np.ndarray, z_te: np.ndarray, p_te: np.ndarray,
            order: int) -> dict[str, float]:
    """Position (cm) and orientation (degrees modulo 2π / order) errors on the test frames
    of readouts fitted on the training frames: z (M, 4) latents, p (M, 3) poses."""
    a_tr, a_te = np.c_[z_tr[:, :2], np.ones(len(z_tr))], np.c_[z_te[:, :2], np.ones(len(z_te))]
    coef, *_ = np.linalg.lstsq(a_tr, p_tr[:, :2], rcond=None)
    pos = 100 * np.linalg.norm(a_te @ coef - p_te[:, :2], axis=1)
    best = None
    for sign in (1, -1):
        d_tr = sign * np.arctan2(z_tr[:, 3], z_tr[:, 2]) - order * p_tr[:, 2]
        d_te = sign * np.arctan2(z_te[:, 3], z_te[:, 2]) - order * p_te[:, 2]
        phase = np.angle(np.exp(1j * d_tr).mean())
        err = np.degrees(np.abs(np.angle(np.exp(1j * (d_te - phase))))) / order
        if best is None or err.mean() < best.mean():
            best = err
    return {"position (cm)": float(pos.mean()), "orientation (deg)": float(best.mean()),
            "within 10 deg (%)": float(100 * (best < 10).mean())}


def sindy_fit(model: LatentModel, data: SequenceData, norm: Normalizer, min_share: float
              ) -> dict[str, float]:
    """Active terms of STLSQ on the training transitions, and its one-push latent squared
    error on the test split in % of "nothing moves" (z_t for z_t+1)."""
    train, test = data.split("train"), data.split("test")
    z, zt = encode(model, train, norm), encode(model, test, norm)
    u = torch.as_tensor(train.actions, dtype=torch.float32)
    ut = torch.as_tensor(test.actions, dtype=torch.float32)
    dyn = model.dynamics
    nz, nu = z.shape[-1], u.shape[-1]
    dyn.fit_state_data(z[:, :-1].reshape(-1, nz), u.reshape(-1, nu), z[:, 1:].reshape(-1, nz),
                       optimizer=STLSQ(min_share=min_share))
    with torch.no_grad():
        pred = model.step(zt[:, :-1].reshape(-1, nz), ut.reshape(-1, nu))
    nxt = zt[:, 1:].reshape(-1, nz)
    err = (pred - nxt).square().sum() / (zt[:, :-1].reshape(-1, nz) - nxt).square().sum()
    return {"SINDy active terms": float(dyn.mask.sum()), "SINDy 1-push error (%)":
            float(100 * err)}


def measure(model: LatentModel, data: SequenceData, norm: Normalizer, order: int,
            min_share: float, seed: int) -> dict[str, float]:
    """Every figure of one encoder on one world's data."""
    model.eval()
    train, test = data.split("train"), data.split("test")
    z_tr = encode(model, train, norm).double().numpy().reshape(-1, 4)
    z_te = encode(model, test, norm).double().numpy().reshape(-1, 4)
    out = readout(z_tr, train.poses.reshape(-1, 3), z_te, test.poses.reshape(-1, 3), order)
    probes = latent_probes(model, data, norm, "test", seed=seed)
    out |= {"linear R2 x": probes["x"], "linear R2 y": probes["y"],
            "linear R2 angle": (probes["cos"] + probes["sin"]) / 2,
            "kernel R2 x": probes["kernel/x"], "kernel R2 y": probes["kernel/y"],
            "kernel R2 angle": probes["kernel/angle"]}
    return out | sindy_fit(model, data, norm, min_share)


def moments_model(data: SequenceData, norm: Normalizer, order: int) -> LatentModel:
    """The moments encoder (nothing learned; its background from the training images)."""
    c, s = data.images.shape[2], data.images.shape[-1]
    obs = AutoencoderConfig(encoder_kind="moments", decoder_kind="sprite", latent_dim=4,
                            moment_order=order)
    model = LatentModel(ModelConfig(dynamics=SindyConfig(order=2), observation=obs)
                        .resolve(c, s, data.actions.shape[-1]))
    model.fit_statistics(norm.normalize(data.split("train").images), None)
    return model


def learned_model(data: SequenceData, obs: AutoencoderConfig, args: argparse.Namespace,
                  epochs: int) -> tuple[LatentModel, Normalizer, float]:
    """A mask_moments autoencoder trained on ``data`` (reconstruction, plus the SINDy
    prediction terms at the given weights); (model, normalizer, seconds)."""
    t0 = time.perf_counter()
    est = LatentSINDy(model=ModelConfig(dynamics=SindyConfig(order=2), observation=obs),
                      settings=TrainConfig(lr=args.lr, batch_size=args.batch_size,
                                           prune_every=0),
                      loss=LossWeights(lambda_pred_x=args.lambda_pred_x,
                                       lambda_pred_z=args.lambda_pred_z, lambda_l1=1e-3),
                      seed=args.seed)
    est.fit(data, epochs=epochs)
    return est.model_, est.normalizer_, time.perf_counter() - t0


def world(path: Path, args: argparse.Namespace) -> tuple[dict[str, dict[str, float]], str]:
    """The moments and the mask_moments figures on one data file, and a note of the order
    chosen."""
    data = read_sequences(path)
    norm = Normalizer.from_trajectories(data.split("train"))
    block_order = round(2 * math.pi / data.world_config.angle_period)
    rows = {"moments": measure(moments_model(data, norm, block_order), data, norm,
                               block_order, args.min_share, args.seed)}
    obs = AutoencoderConfig(encoder_kind="mask_moments", decoder_kind="sprite", latent_dim=4,
                            moment_order=args.provisional_order,
                            mask_channels=args.mask_channels, mask_weight=args.weight,
                            mask_window=args.window, mask_refine=args.refine)
    if args.order is None:
        model, norm, seconds = learned_model(data, obs, args, args.choose_epochs)
        x = norm.normalize(data.split("train").images).flatten(0, 1)
        order = model.autoencoder.encoder.symmetry_order(x)
        note = (f"order {order}, chosen after {args.choose_epochs} epochs at order "
                f"{args.provisional_order} ({seconds:.0f} s)")
    else:
        order, note = args.order, f"order {args.order} (given)"
    model, norm, seconds = learned_model(data, dataclasses.replace(obs, moment_order=order),
                                         args, args.epochs)
    note += f", fitted at order {order} ({seconds:.0f} s)"
    rows["mask_moments"] = measure(model, data, norm, order, args.min_share, args.seed)
    return rows, note


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--standard", type=Path, default=None,
                    help="data file of the standard world (results/demo/data.h5 of make demo)")
    ap.add_argument("--textured", type=Path, default=None,
                    help="data file of the textured world (latent-sindy collect "
                         "--table-look textured --lighting varied --distractor)")
    ap.add_argument("--epochs", type=int, default=90, help="epochs of each fit")
    ap.add_argument("--lr", type=float, default=3e-3, help="AdamW learning rate")
    ap.add_argument("--batch-size", type=int, default=100,
                    help="windows per mini-batch (whole trajectories of 10)")
    ap.add_argument("--lambda-pred-x", type=float, default=0.0,
                    help="weight of the image prediction term")
    ap.add_argument("--lambda-pred-z", type=float, default=0.0,
                    help="weight of the latent prediction term")
    ap.add_argument("--provisional-order", type=int, default=2,
                    help="the order of the first fit, whose encoder chooses the order")
    ap.add_argument("--choose-epochs", type=int, default=30, help="epochs of the first fit")
    ap.add_argument("--order", type=int, default=None,
                    help="use this order instead of choosing one")
    ap.add_argument("--mask-channels", type=int, default=16)
    ap.add_argument("--weight", choices=("background", "image", "mask"), default="background",
                    help="the mask_moments encoder's --mask-weight")
    ap.add_argument("--window", type=float, default=3.0,
                    help="the mask_moments encoder's --mask-window (pixels; 0: none)")
    ap.add_argument("--refine", type=int, default=3,
                    help="the mask_moments encoder's --mask-refine (mean-shift steps; 0: the "
                         "masked weights' own pose, as first measured)")
    ap.add_argument("--min-share", type=float, default=0.2,
                    help="STLSQ's min_share")
    ap.add_argument("--seed", type=int, default=0, help="seed of the weights, batches, probes")
    args = ap.parse_args()
    if args.standard is None and args.textured is None:
        ap.error("give --standard or --textured data, or both")
    torch.set_num_threads(1)
    worlds = {"standard": args.standard, "textured": args.textured}
    for name, path in worlds.items():
        if path is None:
            continue
        t0 = time.perf_counter()
        rows, note = world(path, args)
        print(f"\n{name} world ({path}): mask_moments {note}; {time.perf_counter() - t0:.0f} s")
        width = max(map(len, rows["moments"])) + 2
        print(" " * width + "".join(f"{k:>14}" for k in rows))
        for k in rows["moments"]:
            print(f"{k:<{width}}" + "".join(f"{r[k]:>14.3f}" for r in rows.values()))


if __name__ == "__main__":
    main()
