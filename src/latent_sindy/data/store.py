"""The trajectory file: HDF5 written atomically, validated on every open.

Layout (format ``latent-sindy-trajectories``, version 1)::

    /images    (N, T+1, C, S, S) uint8    camera images x_0..x_T, channels first
    /actions   (N, T, nu)        float32  pushes u_0..u_{T-1} (nu and box: the env config's)
    /poses     (N, T+1, 3)       float32  true block poses (x, y, theta)
    /split     (N,)              uint8    0 train, 1 validation, 2 test
    attributes: format, format_version, package_version, created, seed, steps,
                env_config (JSON), collection (JSON), pixel_mean, pixel_std (train split)

The recorded environment config owns the action box (`action_low`, `action_high`,
`action_dim`): actions are checked against it. A file recorded before the config had a
`push` setting means the paper's world (see :meth:`PushEnvConfig.from_record`).

A file is only ever written whole, to a temporary name that is renamed into place, so a
reader sees either nothing or a complete file.

    from latent_sindy.data.store import read_trajectories
    data = read_trajectories("data/push.h5")
    train = data.split("train")
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import h5py
import numpy as np

from latent_sindy.atomic import atomic_path
from latent_sindy.configs import to_json
from latent_sindy.errors import UserError
from latent_sindy.worlds.push.config import PushEnvConfig

FORMAT = "latent-sindy-trajectories"
FORMAT_VERSION = 1
SPLITS = ("train", "val", "test")
_SLACK = 1e-4


@dataclass
class Trajectories:
    """Trajectories held in memory, with what is needed to interpret them."""

    images: np.ndarray  # (N, T+1, C, S, S) uint8
    actions: np.ndarray  # (N, T, nu) float32, nu = env_config.action_dim
    poses: np.ndarray  # (N, T+1, 3) float32
    split_ids: np.ndarray  # (N,) uint8, index into SPLITS
    env_config: PushEnvConfig = field(default_factory=PushEnvConfig)
    seed: int | None = None
    collection: dict = field(default_factory=dict)
    source: str = "<memory>"

    def __post_init__(self) -> None:
        _check_arrays(self, self.source)

    @property
    def n(self) -> int:
        return len(self.images)

    @property
    def steps(self) -> int:
        return self.actions.shape[1]

    def split(self, name: str) -> Trajectories:
        """The trajectories of one split ('train', 'val' or 'test')."""
        if name not in SPLITS:
            raise UserError(f"split {name!r} does not exist: use one of {', '.join(SPLITS)}")
        keep = self.split_ids == SPLITS.index(name)
        return Trajectories(self.images[keep], self.actions[keep], self.poses[keep],
                            self.split_ids[keep], self.env_config, self.seed, self.collection,
                            self.source)

    def split_counts(self) -> dict[str, int]:
        return {s: int(np.sum(self.split_ids == i)) for i, s in enumerate(SPLITS)}

    def fingerprint(self) -> str:
        """SHA-256 of the arrays (images, actions, poses, splits): equal data, equal print."""
        import hashlib

        h = hashlib.sha256()
        for arr in (self.images, self.actions, self.poses, self.split_ids):
            a = np.ascontiguousarray(arr)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        return h.hexdigest()

    def pixel_stats(self) -> tuple[float, float]:
        """Scalar mean and std of the training split's pixels (the course normalised so)."""
        train = self.images[self.split_ids == 0]
        if train.size == 0:
            raise UserError(f"{self.source} has no training trajectories to normalise with")
        x = train.astype(np.float64)
        return float(x.mean()), float(x.std())


def _check_arrays(t: Trajectories, where: str) -> None:
    """Shapes, dtypes and values; raises UserError naming `where` and the problem."""
    def bad(msg: str) -> UserError:
        return UserError(f"{where}: {msg}")

    if t.images.dtype != np.uint8 or t.images.ndim != 5:
        raise bad(f"images must be uint8 (N, T+1, C, S, S), got {t.images.dtype} "
                  f"{t.images.shape}")
    n, t1, c, s, s2 = t.images.shape
    if c not in (1, 3) or s != s2:
        raise bad(f"images must have 1 or 3 channels and square frames, got {t.images.shape}")
    if t1 < 2:
        raise bad(f"trajectories need at least one step, images have {t1} frame(s)")
    nu = t.env_config.action_dim
    if t.actions.shape != (n, t1 - 1, nu):
        raise bad(f"actions have shape {t.actions.shape}, expected {(n, t1 - 1, nu)} "
                  f"({', '.join(t.env_config.action_names)} in the recorded world)")
    if t.poses.shape != (n, t1, 3):
        raise bad(f"poses have shape {t.poses.shape}, expected {(n, t1, 3)}")
    if t.split_ids.shape != (n,):
        raise bad(f"split has shape {t.split_ids.shape}, expected {(n,)}")
    for name, arr in (("actions", t.actions), ("poses", t.poses)):
        if not np.issubdtype(arr.dtype, np.floating):
            raise bad(f"{name} must be floating point, got {arr.dtype}")
        if not np.all(np.isfinite(arr)):
            i = int(np.argwhere(~np.isfinite(arr))[0][0])
            raise bad(f"{name} of trajectory {i} contain NaN or inf values; re-collect it")
    low, high = np.array(t.env_config.action_low), np.array(t.env_config.action_high)
    out = (t.actions < low - _SLACK) | (t.actions > high + _SLACK)
    if np.any(out):
        i, k, j = (int(v) for v in np.argwhere(out)[0])
        raise bad(f"action {j} ({t.env_config.action_names[j]}) of step {k} of trajectory {i} "
                  f"is {float(t.actions[i, k, j]):.4g}, outside [{low[j]:.4g}, {high[j]:.4g}] "
                  f"of the recorded {t.env_config.push!r} world")
    if (not np.issubdtype(t.split_ids.dtype, np.integer) or np.any(t.split_ids < 0)
            or np.any(t.split_ids >= len(SPLITS))):
        raise bad(f"split labels must be the integers 0 (train), 1 (val) or 2 (test), found "
                  f"{sorted(set(t.split_ids.tolist()))[:5]} ({t.split_ids.dtype}); re-collect it")
    if t.env_config.channels != c or t.env_config.image_size != s:
        raise bad(f"images are {c}x{s}x{s} but the recorded environment renders "
                  f"{t.env_config.channels}x{t.env_config.image_size}x{t.env_config.image_size}")


def write_trajectories(path: str | os.PathLike, data: Trajectories) -> None:
    """Write `data` to `path` atomically (temporary file, then rename)."""
    from latent_sindy import __version__

    mean, std = data.pixel_stats()
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        t1 = data.images.shape[1]
        f.create_dataset("images", data=data.images, chunks=(1, *data.images.shape[1:]),
                         compression="gzip", compression_opts=4, shuffle=True)
        f.create_dataset("actions", data=data.actions.astype(np.float32))
        f.create_dataset("poses", data=data.poses.astype(np.float32))
        f.create_dataset("split", data=data.split_ids.astype(np.uint8))
        f["split"].attrs["names"] = json.dumps(SPLITS)
        f.attrs.update({
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "package_version": __version__,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "seed": -1 if data.seed is None else int(data.seed),
            "steps": t1 - 1,
            "env_config": json.dumps(to_json(data.env_config)),
            "collection": json.dumps(data.collection),
            "pixel_mean": mean,
            "pixel_std": std,
        })


def read_trajectories(path: str | os.PathLike) -> Trajectories:
    """Open and validate a trajectory file; every problem is a one-line UserError."""
    path = Path(path)
    if not path.exists():
        raise UserError(f"{path} does not exist: collect data first with "
                        f"`latent-sindy collect --out {path}`")
    if path.is_dir():
        raise UserError(f"{path} is a directory, not a trajectory file (.h5)")
    if not h5py.is_hdf5(path):
        raise UserError(f"{path} is not an HDF5 file (truncated, or some other format); "
                        "re-collect it")
    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
            if fmt != FORMAT:
                raise UserError(f"{path} is an HDF5 file but not a latent-sindy trajectory file "
                                f"(format attribute {fmt!r})")
            version = int(f.attrs.get("format_version", -1))
            if version != FORMAT_VERSION:
                raise UserError(f"{path} has format version {version}; this latent-sindy reads "
                                f"version {FORMAT_VERSION}: re-collect it")
            missing = [k for k in ("images", "actions", "poses", "split") if k not in f]
            if missing:
                raise UserError(f"{path} lacks dataset(s) {', '.join(missing)}; re-collect it")
            arrays = {k: f[k][()] for k in ("images", "actions", "poses", "split")}
            env_config = PushEnvConfig.from_record(json.loads(f.attrs["env_config"]),
                                                   f"{path}: env_config")
            seed = int(f.attrs.get("seed", -1))
            collection = json.loads(f.attrs.get("collection", "{}"))
    except UserError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise UserError(f"{path} is damaged ({type(e).__name__}: {e}); re-collect it") from e
    return Trajectories(arrays["images"], arrays["actions"], arrays["poses"], arrays["split"],
                        env_config, None if seed < 0 else seed, collection, str(path))
