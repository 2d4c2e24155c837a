"""Planning toward a goal image with a trained latent model: encode, run MPPI, act.

:class:`ImagePlanner` joins a latent model, the normaliser of its data and MPPI. ``act(image,
goal_image)`` encodes both images and returns the first action of the plan that drives the
latent state toward the goal's (``space="latent"``) or the decoded prediction toward the goal
image (``space="image"``). With ``objective="reward"`` it needs no goal: the plan maximises
the model's predicted reward summed over the horizon (a model with a reward head). It is what
:meth:`latent_sindy.LatentSINDy.planner` returns; the closed loop
(:mod:`latent_sindy.control.episodes`) drives it as ``ImagePolicy(planner)``.

    planner = ImagePlanner(model, normalizer, MPPIConfig(), action_low, action_high)
    u = planner.act(image, goal_image)      # (nu,) numpy
    u = ImagePlanner(model, ..., objective="reward").act(image)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Literal

import numpy as np
import torch

from latent_sindy.control.costs import ImageCost, LatentCost, RewardCost, StateCost
from latent_sindy.control.mppi import MPPI, MPPIConfig, MPPIInfo, latent_step
from latent_sindy.data.sequence import check_pixels
from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError

__all__ = ["OBJECTIVES", "ImagePlanner", "Objective", "feasible_action"]

#: What a plan pursues: a goal image, or the most predicted reward.
Objective = Literal["goal", "reward"]
OBJECTIVES = ("goal", "reward")


class ImagePlanner:
    """MPPI in a latent model's space toward a goal image, ``act(image, goal_image)``, or
    (``objective="reward"``) toward the most predicted reward, ``act(image)``."""

    def __init__(self, model: torch.nn.Module, normalizer: Normalizer, mppi: MPPIConfig,
                 action_low: Sequence[float], action_high: Sequence[float],
                 space: Literal["latent", "image"] = "latent",
                 Q: float | Sequence[float] | torch.Tensor = 1.0, seed: int = 0,
                 pixel_dtype: str | None = None, objective: Objective = "goal") -> None:
        if space not in ("latent", "image"):
            raise UserError(f"space {space!r}: plan in 'latent' or 'image' space")
        if objective not in OBJECTIVES:
            raise UserError(f"objective {objective!r}: use {' or '.join(OBJECTIVES)}")
        if objective == "reward" and getattr(model, "reward_head", None) is None:
            raise UserError("objective 'reward' plans on a model's predicted reward, and this "
                            "model has no reward head: fit one with ModelConfig(reward_head="
                            "64) on data with rewards, or plan toward a goal image")
        if objective == "reward" and space != "latent":
            raise UserError("objective 'reward' plans in latent space: drop space='image'")
        if len(action_low) == 0:
            raise UserError("this model has no actions (an autonomous system): nothing to plan")
        self.model = model.eval()
        self.normalizer = normalizer
        self.settings = mppi
        self.box = (tuple(action_low), tuple(action_high))
        self.space = space
        self.Q = Q
        self.seed = seed
        self.objective = objective
        self.pixel_dtype = pixel_dtype  # (None: images of any pixel type are taken)
        self.step = latent_step(model.dynamics)  # active SINDy terms only
        self.mppi: MPPI | None = None
        self._goal: np.ndarray | None = None
        self.last: MPPIInfo | None = None

    def _check(self, image: np.ndarray, name: str) -> np.ndarray:
        """``image`` as an array; UserError unless it is one observation of the model: an
        image (C, H, W) of its size (and of its pixel type, where known)."""
        x = np.asarray(image)
        obs = self.model.config.observation
        if obs.kind != "image":
            return x
        size = obs.image_size
        shape = (obs.channels, *(size if isinstance(size, list | tuple) else (size, size)))
        if x.shape != tuple(shape):
            raise UserError(f"{name} of shape {x.shape}: the planner takes one image (C, H, W) "
                            f"= {tuple(shape)} of this model")
        if self.pixel_dtype is not None:
            check_pixels(x, self.pixel_dtype, name)
        return x

    @torch.no_grad()
    def encode(self, image: np.ndarray) -> torch.Tensor:
        """An image (C, H, W) in the data's pixel scale -> latent (nz,)."""
        x = self._check(image, "image")
        return self.model.encode(self.normalizer.normalize(x)[None])[0]

    @torch.no_grad()
    def reset(self, goal_image: np.ndarray | None = None, seed: int | None = None) -> None:
        """Plan toward ``goal_image`` from now on (a fresh nominal plan); a planner of the
        reward takes none."""
        cost: StateCost | RewardCost
        if self.objective == "reward":
            if goal_image is not None:
                raise UserError("a planner of the reward has no goal: drop goal_image")
            self.mppi = MPPI(self.step, RewardCost(self.model.reward_head), self.settings,
                             *self.box, seed=self.seed if seed is None else seed)
            return
        if goal_image is None:
            raise UserError("give the planner a goal image: reset(goal_image), or plan "
                            "against a reward head (objective='reward')")
        goal = self.normalizer.normalize(self._check(goal_image, "goal_image"))
        if self.space == "latent":
            cost = LatentCost(self.model.encode(goal[None])[0], self.Q)
        else:
            cost = ImageCost(self.model.decode, goal)
        self.mppi = MPPI(self.step, cost, self.settings, *self.box,
                         seed=self.seed if seed is None else seed)
        self._goal = np.array(goal_image, copy=True)

    def act(self, image: np.ndarray, goal_image: np.ndarray | None = None) -> np.ndarray:
        """The action (nu,) to take at ``image``; a new ``goal_image`` resets the plan."""
        z = self.encode(image)  # (checks the image before a new goal resets the plan)
        if goal_image is not None and (self._goal is None or self._goal.shape != np.shape(
                goal_image) or not np.array_equal(self._goal, goal_image)):
            self.reset(goal_image)
        elif self.mppi is None and self.objective == "reward":
            self.reset()
        if self.mppi is None:
            raise UserError("give the planner a goal image first: act(image, goal_image)")
        action, self.last = self.mppi.command(z)
        return action.numpy()


def feasible_action(action: np.ndarray, mppi: MPPI, feasible: Callable[[np.ndarray], np.ndarray],
                    tries: int | None = None, chunk: int = 8) -> tuple[np.ndarray, bool]:
    """The action to execute after ``mppi.command``: ``action`` (nu,) if ``feasible`` says so,
    else the first action of the lowest-cost sample of that update that is feasible.

    ``feasible(actions (k, nu)) -> (k,) bool`` answers for the world's true state now (a
    world's ``feasible`` with the state bound). Samples are asked in order of cost, ``chunk``
    at a time, until one is feasible (at most ``tries``; None: every sample with a finite
    cost); when none is, ``action`` is kept. Returns the action and whether it was replaced.
    """
    if feasible(np.asarray(action)[None])[0]:
        return action, False
    costs = mppi.costs  # (K,) of the last update; inf for discarded samples
    order = torch.argsort(costs)[:tries]
    order = order[torch.isfinite(costs[order])]
    firsts = mppi.actions[order, 0].numpy()  # (tries, nu), lowest cost first
    for k in range(0, len(firsts), chunk):
        ok = np.flatnonzero(feasible(firsts[k:k + chunk]))
        if len(ok):
            return firsts[k + ok[0]].copy(), True
    return action, False
