"""The pushing world's data: block poses as states, and its record.

A pushing data set is a :class:`~latent_sindy.data.SequenceData` whose states are the block's
poses (x, y, θ) with θ an angle of the block's visible symmetry, whose action box and names are
the world's, and whose ``record`` holds the world's settings (``env_config``) and how the data
were collected (``collection``).

    data = push_data(images, actions, poses, split_ids, PushEnvConfig())
    push_config(data)  # the PushEnvConfig that recorded it
"""

from __future__ import annotations

import numpy as np

from latent_sindy.configs import to_json
from latent_sindy.data.sequence import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.worlds.push.config import PushEnvConfig

__all__ = ["POSE_NAMES", "check_data", "push_config", "push_data"]

POSE_NAMES = ("x", "y", "θ")


def push_data(images: np.ndarray, actions: np.ndarray, poses: np.ndarray,
              split_ids: np.ndarray | None = None, env_config: PushEnvConfig | None = None,
              seed: int | None = None, collection: dict | None = None,
              source: str = "<memory>", executed: np.ndarray | None = None) -> SequenceData:
    """Sequences recorded in the pushing world ``env_config`` (validated against it);
    ``executed`` (N, T) bool: which pushes the arm made (``info["push_executed"]``)."""
    env = env_config or PushEnvConfig()
    _check_actions(actions, env, source)
    if np.asarray(poses).ndim != 3 or np.asarray(poses).shape[2] != 3:
        raise UserError(f"{source}: poses have shape {np.asarray(poses).shape}, expected "
                        "(N, T+1, 3)")
    data = SequenceData(
        images, actions, action_low=env.action_low, action_high=env.action_high,
        action_names=env.action_names, states=poses, state_names=POSE_NAMES,
        state_periods=(None, None, env.angle_period), split=split_ids, world="push",
        executed=executed,
        record={"env_config": to_json(env), "collection": collection or {}}, seed=seed,
        source=source)
    check_data(data)
    return data


def _check_actions(actions: np.ndarray, env: PushEnvConfig, where: str) -> None:
    """UserError unless ``actions`` (N, T, nu) are of the world's size and in its box."""
    actions = np.asarray(actions)
    if actions.ndim != 3 or actions.shape[2] != env.action_dim:
        raise UserError(f"{where}: actions have shape {actions.shape}, expected "
                        f"{(*actions.shape[:2], env.action_dim)} ({', '.join(env.action_names)} "
                        f"in the recorded {env.push!r} world)")
    if not np.issubdtype(actions.dtype, np.floating) or not np.all(np.isfinite(actions)):
        return  # SequenceData names the problem
    low, high = np.asarray(env.action_low), np.asarray(env.action_high)
    out = (actions < low - 1e-4) | (actions > high + 1e-4)
    if np.any(out):
        i, k, j = (int(v) for v in np.argwhere(out)[0])
        raise UserError(f"{where}: action {j} ({env.action_names[j]}) of step {k} of "
                        f"trajectory {i} is {float(actions[i, k, j]):.4g}, outside "
                        f"[{low[j]:.4g}, {high[j]:.4g}] of the recorded {env.push!r} world")


def push_config(data: SequenceData, where: str | None = None) -> PushEnvConfig:
    """The pushing world that recorded ``data``; UserError for data of another world."""
    where = where or data.source
    if data.world != "push":
        raise UserError(f"{where} was not recorded in the pushing world (world "
                        f"{data.world!r}): this needs the pushing world's data")
    return PushEnvConfig.from_record(data.record.get("env_config"), f"{where}: env_config")


def check_data(data: SequenceData) -> None:
    """UserError unless the images, actions and states fit the recorded world."""
    env = push_config(data)
    c, h, w = data.frame_shape
    if env.channels != c or env.image_size != h or env.image_size != w:
        raise UserError(f"{data.source}: images are {c}x{h}x{w} but the recorded environment "
                        f"renders {env.channels}x{env.image_size}x{env.image_size}")
    if data.images.dtype != np.uint8:
        raise UserError(f"{data.source}: the pushing world's images are uint8")
    _check_actions(data.actions, env, data.source)
    if data.states is None or data.states.shape[2] != 3:
        raise UserError(f"{data.source}: the pushing world's data carry the block poses "
                        "(x, y, θ) as states")

