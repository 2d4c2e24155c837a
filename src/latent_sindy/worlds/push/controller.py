"""The pushing world's policy: a trained model with its MPPI (:class:`Controller`), planning in
the latent, image or pose space (:data:`COSTS`), and how it chose each push (:class:`Push`);
the settings of the episodes it plays (:class:`ControlConfig`).

It is a policy of the project's closed loop (:mod:`latent_sindy.control.episodes`):
``reset(goal, seed)`` and ``act(observation)``, where an observation holds the camera image
and the block's true pose; the episodes it runs are :mod:`latent_sindy.worlds.push.episodes`.

    controller = Controller(model, normalizer, ControlConfig(space="latent"), env_config)
    controller.reset(Observation(goal_image, goal_pose), seed=0)
    action = controller.act(Observation(image, pose)); controller.last.replaced
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch
import tyro

from latent_sindy.control.costs import ImageCost, LatentCost, PoseCost, StateCost
from latent_sindy.control.episodes import Observation
from latent_sindy.control.mppi import MPPI, MPPIConfig, MPPIInfo, latent_step
from latent_sindy.control.planner import feasible_action
from latent_sindy.data.windows import OBSERVATIONS, Normalizer
from latent_sindy.errors import UserError, check_seed
from latent_sindy.models.state import pose_cost_weights
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.reach import Reach

__all__ = ["COSTS", "ControlConfig", "Controller", "Push", "check_space"]


def _latent_cost(controller: Controller, goal: torch.Tensor) -> StateCost:
    return LatentCost(controller.model.encode(goal[None])[0],
                      controller.model.autoencoder.cost_weights(controller.period))


def _image_cost(controller: Controller, goal: torch.Tensor) -> StateCost:
    return ImageCost(controller.model.decode, goal)


def _pose_cost(controller: Controller, goal: torch.Tensor) -> StateCost:
    head = controller.model.pose_head
    return PoseCost(head, head(controller.model.encode(goal[None])[0]),
                    pose_cost_weights(controller.period))


def check_space(model, space: str) -> None:
    """UserError unless ``model`` can compute the cost of planning ``space``: image space
    compares decoded images (an image model's), pose space reads a pose head."""
    kind = model.config.observation.kind
    if space == "image" and kind != "image":
        raise UserError(f"--space image compares decoded images with the goal image; this "
                        f"{kind} model decodes no images (it would plan on the raw {kind} "
                        "distance): use --space latent")
    if space == "pose" and model.pose_head is None:
        raise UserError("--space pose needs a model trained with a pose head (latent-sindy "
                        "train ... --pose-head linear --lambda-pose 10); this one has none: use "
                        "--space latent")


#: Planning space -> the cost MPPI minimises, built from the controller and the goal as the
#: model observes it (normalised goal image, or encoded goal pose for a state model).
COSTS: dict[str, Callable[[Controller, torch.Tensor], StateCost]] = {
    "latent": _latent_cost, "image": _image_cost, "pose": _pose_cost}


@dataclass(frozen=True)
class ControlConfig:
    """How episodes are posed and planned; the planner's own settings are nested."""

    task: Literal["paper", "random"] = "paper"
    """paper: start (0.4, 0, 0.2π), goal (0.7, 0, 0); random: start and goal from the seed."""
    episodes: int = 1
    """Number of episodes."""
    seed: int = 0
    """Seeds the random tasks and the controller's noise."""
    space: Literal["latent", "image", "pose"] = "latent"
    """Where MPPI's cost is computed: "latent" (distance to the encoded goal image), "image"
    (decode each predicted latent, compare with the goal image: the paper's variant) or
    "pose" (the pose head's reading of each predicted latent against the goal image's,
    2 cm or 10° costing 1: models trained with --pose-head)."""
    max_steps: int = 20
    """Pushes allowed per episode (the course: 20 latent, 30 image space)."""
    until: Literal["course", "strict"] = "course"
    """Stop an episode when this success criterion is met."""
    gif_episodes: int = 1
    """Save a GIF of the first this many episodes."""
    reach: bool = True
    """Replace a planned push the arm cannot make from the block's true pose by the
    lowest-cost sampled push it can (the world's reach answer, worlds/push/reach.py);
    --no-reach executes MPPI's push as planned (out of reach: the block stays)."""
    mppi: tyro.conf.OmitArgPrefixes[MPPIConfig] = field(default_factory=MPPIConfig)
    """The planner (K, H, Σ, λ)."""

    def __post_init__(self) -> None:
        if self.task not in ("paper", "random"):
            raise UserError(f"--task {self.task}: use paper or random")
        if self.space not in COSTS:
            raise UserError(f"--space {self.space}: use one of {', '.join(COSTS)}")
        if self.until not in ("course", "strict"):
            raise UserError(f"--until {self.until}: use course or strict")
        for name in ("episodes", "max_steps"):
            if getattr(self, name) < 1:
                raise UserError(f"--{name.replace('_', '-')} {getattr(self, name)}: use 1 or more")
        if self.gif_episodes < 0:
            raise UserError(f"--gif-episodes {self.gif_episodes}: use 0 or more")
        check_seed(self.seed, "--seed")




@dataclass(frozen=True)
class Push:
    """How the controller chose its last push: MPPI's info, whether the planned push was
    replaced by one within the arm's reach, and the seconds asking the reach."""

    plan: MPPIInfo
    replaced: bool
    reach_s: float


class Controller:
    """A trained model with its MPPI, ready to push: a policy of the closed loop,
    ``reset(goal, seed)`` and ``act(observation) -> action`` (how it chose: ``last``).

    The model takes from each observation what its encoder sees (the image, or the true
    pose for a state-space reference model). Building it runs the dynamics step once, so a
    one-time compilation (numba's, for SINDy) is not counted as planning: ``warmup_s``.
    """

    def __init__(self, model, normalizer: Normalizer, settings: ControlConfig,
                 env_config: PushEnvConfig) -> None:
        self.model = model.eval()
        self.normalizer = normalizer
        self.settings = settings
        self.box = (env_config.action_low, env_config.action_high)
        self._observe = OBSERVATIONS[model.config.observation.kind].one
        self.period = env_config.angle_period
        check_space(model, settings.space)  # its error, before any episode
        self._cost = COSTS[settings.space]
        self.step = latent_step(model.dynamics)  # active SINDy terms only
        self.reach = Reach(env_config) if settings.reach else None
        self.last: Push | None = None
        t0 = time.perf_counter()
        MPPI(self.step, torch.zeros(model.config.observation.latent_dim),
             dataclasses.replace(settings.mppi, samples=2, horizon=2), *self.box).command(
            torch.zeros(model.config.observation.latent_dim))
        self.warmup_s = time.perf_counter() - t0

    def observe(self, observation: Observation) -> torch.Tensor:
        """What the model sees of an observation (normalised image or encoded pose)."""
        return self._observe(observation.image, observation.state, self.normalizer,
                             self.period)

    @torch.no_grad()
    def encode(self, observation: Observation) -> torch.Tensor:
        """An observation -> latent (nz,)."""
        return self.model.encode(self.observe(observation)[None])[0]

    @torch.no_grad()
    def reset(self, goal: Observation, seed: int | None = None) -> None:
        """Plan toward ``goal`` (the goal image and the goal pose) with a fresh MPPI."""
        self.mppi = MPPI(self.step, self._cost(self, self.observe(goal)), self.settings.mppi,
                         *self.box, seed=seed)

    def act(self, observation: Observation) -> np.ndarray:
        """MPPI's push from this observation, or (with ``reach``) the lowest-cost sampled
        push the arm can make from the true pose (``observation.state``) when MPPI's is out
        of its reach; ``last`` says how it was chosen."""
        action, info = self.mppi.command(self.encode(observation))
        action = action.numpy()
        if self.reach is None:
            self.last = Push(info, False, 0.0)
            return action
        t0 = time.perf_counter()
        action, replaced = feasible_action(action, self.mppi,
                                           lambda a: self.reach(observation.state, a))
        self.last = Push(info, replaced, time.perf_counter() - t0)
        return action

    def close(self) -> None:
        if self.reach is not None:
            self.reach.close()


