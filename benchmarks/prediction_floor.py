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
* with ``--replay N``: the simulator itself, N random test pushes replayed from a fresh reset
  at the recorded pose (the arm starting at home rather than where the previous push left
  it), against the recorded next pose: how repeatable the world is.

Prints the position error (cm) and the orientation error (degrees, modulo the block's
symmetry) per horizon. Uses the uniform block's world (pushes in world directions).

    .venv/bin/python benchmarks/prediction_floor.py --data results/demo/data.h5
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from latent_sindy.data.store import read_trajectories
from latent_sindy.models import SindyConfig
from latent_sindy.sindy import STLSQ, face_variables

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


def _rollout_errors(step, poses: np.ndarray, actions: np.ndarray, period: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Mean position (cm) and angle (deg) error per horizon of ``step(pose, action)``."""
    steps = actions.shape[1]
    pos, ang, count = np.zeros(steps), np.zeros(steps), np.zeros(steps)
    for t0 in range(steps):
        pose = poses[:, t0].copy()
        for h in range(1, steps - t0 + 1):
            pose = step(pose, actions[:, t0 + h - 1])
            true = poses[:, t0 + h]
            pos[h - 1] += 100 * np.linalg.norm(pose[:, :2] - true[:, :2], axis=1).sum()
            turn = np.remainder(pose[:, 2] - true[:, 2] + period / 2, period) - period / 2
            ang[h - 1] += np.degrees(np.abs(turn)).sum()
            count[h - 1] += len(pose)
    return pos / count, ang / count


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--replay", type=int, default=0, metavar="N",
                    help="replay N random test pushes in the simulator (about 0.5 s each)")
    args = ap.parse_args()
    from sklearn.ensemble import ExtraTreesRegressor

    data = read_trajectories(args.data)
    if data.env_config.push != "symmetric":
        raise SystemExit(f"{args.data}: pushes relative to the block; this reference is for "
                         "the symmetric world's world-direction pushes")
    period = data.env_config.angle_period
    f = 2 * math.pi / period
    train, test = data.split("train"), data.split("test")
    P, U = train.poses.astype(np.float64), train.actions.astype(np.float64)
    p, a, length, n = _face_frame(P[:, :-1], U, f)
    d = P[:, 1:] - P[:, :-1]
    d[..., 2] = np.remainder(d[..., 2] + math.pi, 2 * math.pi) - math.pi  # θ is kept in (-π, π]
    along = d[..., 0] * np.cos(n) + d[..., 1] * np.sin(n)
    across = -d[..., 0] * np.sin(n) + d[..., 1] * np.cos(n)
    X = np.stack([p, a, length], -1).reshape(-1, 3)
    Y = np.stack([along, across, d[..., 2]], -1).reshape(-1, 3)
    trees = ExtraTreesRegressor(400, min_samples_leaf=2, random_state=args.seed).fit(X, Y)

    def trees_step(pose: np.ndarray, u: np.ndarray) -> np.ndarray:
        p, a, length, n = _face_frame(pose, u, f)
        y = trees.predict(np.stack([p, a, length], -1))
        return pose + np.stack([y[:, 0] * np.cos(n) - y[:, 1] * np.sin(n),
                                y[:, 0] * np.sin(n) + y[:, 1] * np.cos(n), y[:, 2]], -1)

    z = _features(P, f)
    u = torch.as_tensor(U)
    Z, Zn = z[:, :-1].reshape(-1, 4), z[:, 1:].reshape(-1, 4)

    def sindy_step(turn: bool):
        model = SindyConfig(order=1, library="frame", include_sine=False,
                            angle_frequency=f).build(4, 3, circle=(2, 3), turn=turn).double()
        model.fit_state_data(Z, u.reshape(-1, 3), Zn, optimizer=STLSQ(threshold=0.0))

        @torch.no_grad()
        def step(pose: np.ndarray, act: np.ndarray) -> np.ndarray:
            nxt = model.step(_features(pose, f), torch.as_tensor(act)).numpy()
            return np.c_[nxt[:, :2], np.arctan2(nxt[:, 3], nxt[:, 2]) / f]
        return step

    Pt, Ut = test.poses.astype(np.float64), test.actions.astype(np.float64)
    print(f"{args.data}: {train.n} training and {test.n} test trajectories of {test.steps} "
          f"pushes; errors after h pushes, mean over every start (position cm / angle deg)")
    rows = {"extra-trees (true pose, face frame)": trees_step,
            "frame library, lsq, projected": sindy_step(False),
            "frame library, lsq, turning": sindy_step(True),
            "nothing moves": lambda pose, u: pose}
    print(f"{'model':38s}" + "".join(f"{f'h={h}':>16s}" for h in HORIZONS))
    for name, step in rows.items():
        pos, ang = _rollout_errors(step, Pt, Ut, period)
        print(f"{name:38s}" + "".join(f"{pos[h - 1]:8.2f} /{ang[h - 1]:6.2f}" for h in HORIZONS
                                       if h <= len(pos)))
    if args.replay:
        pos, ang = _replay(test, args.replay, args.seed)
        print(f"{'the simulator, replayed (h=1)':38s}{pos:8.2f} /{ang:6.2f}   "
              f"({args.replay} pushes; median {np.median(_replay.last):.2f} cm)")


def _replay(test, n: int, seed: int) -> tuple[float, float]:
    """Mean position (cm) and angle (deg) gap between n recorded test pushes and the same
    pushes replayed from a fresh reset at the recorded pose."""
    from latent_sindy.envs import PandaPushEnv

    env = PandaPushEnv(test.env_config)
    rng = np.random.default_rng(seed)
    pairs = [(i, t) for i in range(test.n) for t in range(test.steps)]
    pos, ang = [], []
    period = test.env_config.angle_period
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
