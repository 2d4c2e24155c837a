"""How closely can anything predict where pushes take the block? A reference for the study's
block-position errors after 1, 5 and 10 pushes.

Fits, on a trajectory file's training split, models that know the true pose and write the
push in the pushed face's frame (what the frame library does), and rolls them out open loop
on the test split from every start t, as the study's position errors do (mean over every start
with t + h <= T):

* ``extra-trees``: a nonparametric regression (scikit-learn's ExtraTreesRegressor, 400 trees)
  of the displacement along and across the face normal and of the turn, from the contact
  offset p, the push's angle a from the face normal and the push length: no functional form
  assumed, so its errors are near what the data and the world allow;
* ``frame library, lsq``: least squares on every term of the frame library (no sparsity),
  the true pose as the state, the orientation features updated and projected, or turned by
  the angle one equation gives (``turn``): the library's own limit;
* ``nothing moves``: the block stays where it was, for scale;
* ``... , unchanged pushes known``: the same two models fitted on the pushes that moved the
  block, rolled out with the pushes that left the image unchanged (pixel for pixel: the arm
  could not reach the push's start, or the push was too short to show) known to leave the
  block where it was: what foreseeing the arm's reach would buy;
* ``... , from the image's reading``: rolled out from the pose the image moments read
  (:class:`~latent_sindy.models.autoencoder.MomentEncoder`, mapped to the world by least
  squares on the training images) rather than the true one: what an image model that
  reads the start as well as the moments do can reach, before its predicted image is read;
* with ``--replay N``: the simulator itself, N random test pushes replayed from a fresh reset
  at the recorded pose (the arm starting at home rather than where the previous push left
  it), against the recorded next pose: how repeatable the world is.

Prints the position error (cm) and the orientation error (degrees, modulo the block's
symmetry) per horizon. Uses the uniform block's world (pushes in world directions).

    .venv/bin/python benchmarks/prediction_floor.py --data results/demo/data.h5
    .venv/bin/python benchmarks/prediction_floor.py --smoke   # a tiny collection, 10 trees
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np
import torch

from latent_sindy.data import read_sequences
from latent_sindy.data.windows import Normalizer
from latent_sindy.models import SindyConfig
from latent_sindy.models.autoencoder import AutoencoderConfig, MomentEncoder
from latent_sindy.script_args import parse_with_smoke
from latent_sindy.sindy import STLSQ
from latent_sindy.worlds.push.library import face_variables

HORIZONS = (1, 2, 5, 10)


def _face_frame(poses: np.ndarray, actions: np.ndarray, f: float) -> tuple[np.ndarray, ...]:
    """(p, a, push length in m, n) of pushes ``actions`` (..., 3) on ``poses`` (..., 3)."""
    t = torch.as_tensor
    a, n = face_variables(t(actions[..., 1]), t(np.cos(f * poses[..., 2])),
                          t(np.sin(f * poses[..., 2])), (0, 0, 0, f, 1, 0.0))
    return actions[..., 0], a.numpy(), 0.1 * actions[..., 2], n.numpy()


def _features(poses: np.ndarray, f: float) -> torch.Tensor:
    """(x, y, θ) -> (x, y, cos fθ, sin fθ) in float64 (the state encoder's features)."""
    return torch.as_tensor(np.stack([poses[..., 0], poses[..., 1], np.cos(f * poses[..., 2]),
                                     np.sin(f * poses[..., 2])], -1))


def _unchanged(images: np.ndarray) -> np.ndarray:
    """(N, T) pushes whose next image equals the one before, pixel for pixel."""
    return (images[:, 1:] == images[:, :-1]).all(axis=(2, 3, 4))


def _cm(poses: np.ndarray, true: np.ndarray) -> float:
    return float(100 * np.linalg.norm(poses[..., :2] - true[..., :2], axis=-1).mean())


def _deg(poses: np.ndarray, true: np.ndarray, period: float) -> float:
    turn = np.remainder(poses[..., 2] - true[..., 2] + period / 2, period) - period / 2
    return float(np.degrees(np.abs(turn)).mean())


def _fit_trees(P: np.ndarray, U: np.ndarray, f: float, mask: np.ndarray, seed: int,
               n_trees: int = 400):
    """A step of extra trees on (p, a, ℓ) -> the displacement in the pushed face's frame and
    the turn, fitted on the training pushes ``mask`` (N, T)."""
    from sklearn.ensemble import ExtraTreesRegressor

    p, a, length, n = _face_frame(P[:, :-1], U, f)
    d = P[:, 1:] - P[:, :-1]
    d[..., 2] = np.remainder(d[..., 2] + math.pi, 2 * math.pi) - math.pi  # θ is kept in (-π, π]
    along = d[..., 0] * np.cos(n) + d[..., 1] * np.sin(n)
    across = -d[..., 0] * np.sin(n) + d[..., 1] * np.cos(n)
    X = np.stack([p, a, length], -1)[mask]
    Y = np.stack([along, across, d[..., 2]], -1)[mask]
    trees = ExtraTreesRegressor(n_trees, min_samples_leaf=2, random_state=seed).fit(X, Y)

    def step(pose: np.ndarray, u: np.ndarray) -> np.ndarray:
        p, a, length, n = _face_frame(pose, u, f)
        y = trees.predict(np.stack([p, a, length], -1))
        return pose + np.stack([y[:, 0] * np.cos(n) - y[:, 1] * np.sin(n),
                                y[:, 0] * np.sin(n) + y[:, 1] * np.cos(n), y[:, 2]], -1)
    return step


def _fit_frame(P: np.ndarray, U: np.ndarray, f: float, mask: np.ndarray, turn: bool = True):
    """Every term of the frame library, least squares on the training pushes ``mask``."""
    z, u, m = _features(P, f), torch.as_tensor(U), torch.as_tensor(mask.reshape(-1))
    model = SindyConfig(order=1, library="frame", include_sine=False,
                        library_options={"frequency": f}).build(4, 3, circle=(2, 3),
                                                                turn=turn).double()
    model.fit_state_data(z[:, :-1].reshape(-1, 4)[m], u.reshape(-1, 3)[m],
                         z[:, 1:].reshape(-1, 4)[m], optimizer=STLSQ(min_share=0.0))
    return _frame_step(model, f)


def _frame_step(model, f: float):
    @torch.no_grad()
    def step(pose: np.ndarray, act: np.ndarray) -> np.ndarray:
        nxt = model.step(_features(pose, f), torch.as_tensor(act)).numpy()
        return np.c_[nxt[:, :2], np.arctan2(nxt[:, 3], nxt[:, 2]) / f]
    return step


def _moment_reading(train, test) -> tuple[np.ndarray, np.ndarray]:
    """(N, T+1, 3) the training and test images' poses as the image moments read them: the moments
    encoder's centroid mapped to the world's (x, y) and its angle to θ by least squares on
    the training images (an affine map; the sense and offset of the angle that fit best)."""
    period = test.world_config.angle_period
    n = round(2 * math.pi / period)
    cfg = AutoencoderConfig(encoder_kind="moments", latent_dim=4, decoder_kind="sprite",
                            moment_order=n,
                            channels=train.images.shape[2], image_size=train.images.shape[-1])
    encoder = MomentEncoder(cfg.encoder_part(), cfg.image_shape)
    norm = Normalizer.from_trajectories(train)
    encoder.fit_statistics(norm.normalize(train.images).flatten(0, 1))

    @torch.no_grad()
    def read(split) -> np.ndarray:
        return encoder(norm.normalize(split.images).flatten(0, 1)).double().numpy()

    z_tr, z_te = read(train), read(test)
    pose_tr = train.poses.reshape(-1, 3).astype(np.float64)
    affine = np.linalg.lstsq(np.c_[z_tr[:, :2], np.ones(len(z_tr))], pose_tr[:, :2],
                             rcond=None)[0]
    angle_tr, angle_te = np.arctan2(z_tr[:, 3], z_tr[:, 2]), np.arctan2(z_te[:, 3], z_te[:, 2])
    best = None
    for sense in (1, -1):  # n φ = sense n θ + offset
        rest = angle_tr - sense * n * pose_tr[:, 2]
        offset = float(np.angle(np.exp(1j * rest).mean()))
        miss = np.abs(np.angle(np.exp(1j * (rest - offset)))).mean()
        if best is None or miss < best[0]:
            best = (miss, sense, offset)
    _, sense, offset = best
    def pose(z: np.ndarray, angle: np.ndarray, split) -> np.ndarray:
        xy = np.c_[z[:, :2], np.ones(len(z))] @ affine
        return np.c_[xy, (angle - offset) / (sense * n)].reshape(*split.poses.shape)
    return pose(z_tr, angle_tr, train), pose(z_te, angle_te, test)


def _foresee_unchanged(train, test, reading_train, reading_test, seed: int) -> str:
    """How well the image's reading and the push foresee the pushes that leave the image
    unchanged: an MLP classifier (scikit-learn, 64 x 64, on the standardised moments
    reading and the push) fitted on the training pushes, scored on the test pushes."""
    from sklearn.neural_network import MLPClassifier

    f = 2 * math.pi / train.world_config.angle_period

    def inputs(reading: np.ndarray, split) -> np.ndarray:
        u, pose = split.actions.astype(np.float64), reading[:, :-1]
        return np.concatenate([pose[..., :2], np.cos(f * pose[..., 2:]),
                               np.sin(f * pose[..., 2:]), u[..., :1], np.cos(u[..., 1:2]),
                               np.sin(u[..., 1:2]), u[..., 2:]], -1).reshape(-1, 8)

    x_tr, x_te = inputs(reading_train, train), inputs(reading_test, test)
    y_tr, y_te = _unchanged(train.images).reshape(-1), _unchanged(test.images).reshape(-1)
    if y_tr.all() or not y_tr.any():
        return "every training push alike (all changed or all unchanged): nothing to learn"
    mu, sd = x_tr.mean(0), x_tr.std(0) + 1e-12
    clf = MLPClassifier((64, 64), alpha=1e-3, max_iter=3000, random_state=seed)
    said = clf.fit((x_tr - mu) / sd, y_tr).predict((x_te - mu) / sd)
    return (f"an MLP on the moments reading and the push foresees {(said & y_te).sum()} of "
            f"the {y_te.sum()} unchanged test pushes, with {(said & ~y_te).sum()} false alarms")


def _rollout_errors(step, poses: np.ndarray, actions: np.ndarray, period: float,
                    still: np.ndarray | None = None, starts: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Mean position (cm) and angle (deg) error per horizon of ``step(pose, action)``.

    ``still`` (N, T): pushes known to leave the block where it was; ``starts`` (N, T+1, 3):
    the poses the rollouts start from (default: the true ones)."""
    steps = actions.shape[1]
    starts = poses if starts is None else starts
    pos, ang, count = np.zeros(steps), np.zeros(steps), np.zeros(steps)
    for t0 in range(steps):
        pose = starts[:, t0].copy()
        for h in range(1, steps - t0 + 1):
            nxt = step(pose, actions[:, t0 + h - 1])
            pose = nxt if still is None else np.where(still[:, t0 + h - 1, None], pose, nxt)
            true = poses[:, t0 + h]
            pos[h - 1] += 100 * np.linalg.norm(pose[:, :2] - true[:, :2], axis=1).sum()
            turn = np.remainder(pose[:, 2] - true[:, 2] + period / 2, period) - period / 2
            ang[h - 1] += np.degrees(np.abs(turn)).sum()
            count[h - 1] += len(pose)
    return pos / count, ang / count


def tiny_data(folder: Path) -> Path:
    """A tiny trajectory file of the default world (the smoke run's, when no --data)."""
    from latent_sindy.worlds.push.collect import CollectionPlan, collect

    return collect(folder / "data.h5", CollectionPlan(trajectories=8, steps=3,
                                                      val_fraction=0.25, test_fraction=0.25),
                   workers=1)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", help="a trajectory file (required, but with --smoke: a tiny "
                                   "one is collected)")
    ap.add_argument("--trees", type=int, default=400, help="extra trees in the regression")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--replay", type=int, default=0, metavar="N",
                    help="replay N random test pushes in the simulator (about 0.5 s each)")
    args = parse_with_smoke(ap, argv, {"trees": 10})
    if args.data is None and not args.smoke:
        ap.error("--data is required: a trajectory file, e.g. results/demo/data.h5")
    with tempfile.TemporaryDirectory() as folder:
        floor(args.data or tiny_data(Path(folder)), args)


def floor(path: str | Path, args: argparse.Namespace) -> None:
    """The reference's tables for the trajectory file at ``path``."""
    data = read_sequences(path)
    if data.world_config.push != "symmetric":
        raise SystemExit(f"{path}: pushes relative to the block; this reference is for "
                         "the symmetric world's world-direction pushes")
    period = data.world_config.angle_period
    f = 2 * math.pi / period
    train, test = data.split("train"), data.split("test")
    P, U = train.poses.astype(np.float64), train.actions.astype(np.float64)
    moved = ~_unchanged(train.images)
    fits = {"": np.ones_like(moved), "moved": moved}
    trees = {k: _fit_trees(P, U, f, m, args.seed, args.trees) for k, m in fits.items()}
    frame = {k: _fit_frame(P, U, f, m) for k, m in fits.items()}

    Pt, Ut = test.poses.astype(np.float64), test.actions.astype(np.float64)
    still = _unchanged(test.images)
    reading_train, reading = _moment_reading(train, test)
    print(f"{path}: {train.n} training and {test.n} test trajectories of {test.steps} "
          f"pushes; errors after h pushes, mean over every start (position cm / angle deg)")
    print(f"pushes that left the image unchanged: {(~moved).sum()} of {moved.size} (training), "
          f"{still.sum()} of {still.size} (test); "
          + _foresee_unchanged(train, test, reading_train, reading, args.seed))
    print(f"the moments read the test images' block {_cm(reading, Pt):.2f} cm and "
          f"{_deg(reading, Pt, period):.2f} deg off")
    rows = [("extra-trees (true pose, face frame)", trees[""], {}),
            ("frame library, lsq, projected", _fit_frame(P, U, f, fits[""], turn=False), {}),
            ("frame library, lsq, turning", frame[""], {}),
            ("nothing moves", lambda pose, u: pose, {}),
            ("extra-trees, unchanged pushes known", trees["moved"], {"still": still}),
            ("frame, turning, unchanged pushes known", frame["moved"], {"still": still}),
            ("extra-trees, from the image's reading", trees[""], {"starts": reading}),
            ("frame, turning, from the image's reading", frame[""], {"starts": reading})]
    print(f"{'model':42s}" + "".join(f"{f'h={h}':>16s}" for h in HORIZONS))
    for name, step, kw in rows:
        pos, ang = _rollout_errors(step, Pt, Ut, period, **kw)
        print(f"{name:42s}" + "".join(f"{pos[h - 1]:8.2f} /{ang[h - 1]:6.2f}" for h in HORIZONS
                                       if h <= len(pos)))
    if args.replay:
        pos, ang = _replay(test, args.replay, args.seed)
        print(f"{'the simulator, replayed (h=1)':38s}{pos:8.2f} /{ang:6.2f}   "
              f"({args.replay} pushes; median {np.median(_replay.last):.2f} cm)")


def _replay(test, n: int, seed: int) -> tuple[float, float]:
    """Mean position (cm) and angle (deg) gap between n recorded test pushes and the same
    pushes replayed from a fresh reset at the recorded pose."""
    from latent_sindy.worlds.push import PandaPushEnv

    env = PandaPushEnv(test.world_config)
    rng = np.random.default_rng(seed)
    pairs = [(i, t) for i in range(test.n) for t in range(test.steps)]
    pos, ang = [], []
    period = test.world_config.angle_period
    try:
        for k in rng.choice(len(pairs), size=min(n, len(pairs)), replace=False):
            i, t = pairs[k]
            env.reset(seed=seed, options={"start": tuple(float(v) for v in test.poses[i, t])})
            env.step(test.actions[i, t].astype(np.float64))
            got, want = np.asarray(env.world.block_pose()), test.poses[i, t + 1]
            pos.append(100 * np.linalg.norm(got[:2] - want[:2]))
            turn = np.remainder(got[2] - want[2] + period / 2, period) - period / 2
            ang.append(np.degrees(abs(turn)))
    finally:
        env.close()
    _replay.last = pos
    return float(np.mean(pos)), float(np.mean(ang))


if __name__ == "__main__":
    main()
