"""The latent model: an observation encoder + one latent dynamics model, and its loss.

``LatentModel`` joins an observation of :data:`OBSERVATION_CONFIGS` (the image
:class:`~latent_sindy.models.autoencoder.Autoencoder`, or the identity codec of the true
state, :mod:`latent_sindy.models.state`) and any latent
dynamics model of :data:`~latent_sindy.models.dynamics.DYNAMICS_CONFIGS` (SINDy, linear,
MLP). Where the latent is a pose, (x, y, cos fθ, sin fθ, ...) (:attr:`ModelConfig.pose_latent`:
the state and moments encoders, a coordinates pose head), the dynamics are built to scale
(z2, z3) back onto the unit circle after every step, so the loss's rollouts, predictions,
evaluation and control all step through the same projected dynamics; the projection follows
from the config, so a saved run gets it back when it is loaded.
Its :meth:`LatentModel.loss` is the paper's loss (eq. 1–4, docs/design.md) on one batch
of windows x_0..x_H, u_0..u_{H-1}, every term a mean squared error per element of normalised
pixels (or latent coordinates), so values do not depend on the image size, batch or horizon:

    recon  = mean_{b,t=0..H} ‖x_t − dec(enc(x_t))‖² / (C·h·w)
    pred_x = mean_{b,t=1..H} ‖x_t − dec(ẑ_t)‖² / (C·h·w)      ẑ rolled out from ẑ_0 = enc(x_0)
    pred_z = mean_{b,t=1..H} ‖enc(x_t) − ẑ_t‖² / nz
    l1     = ‖M ⊙ Ψ‖₁ (SINDy; 0 for the other models)
    pose   = mean_{b,t=0..H} ‖P(enc(x_t)) − s̃_t‖² / 4 + mean_{b,t=1..H} ‖P(ẑ_t) − s̃_t‖² / 4
             (a model with a pose head P given the true poses, :mod:`.pose_head`; s̃ the
             standardised pose features; else 0)
    reward = mean_{b,t=0..H-1} (r̂(ẑ_t, u_t) − r_t)²   (a model with a reward head given the
             rewards, :mod:`.reward_head`; ẑ_0 = enc(x_0); else 0)
    objective = recon + λ1 pred_x + λ2 pred_z   (what train/val/test losses report, comparable
                                                across models)
    total  = objective + λ3 l1 + λ4 pose + λ5 reward  (what training minimises; with a
                                  foreground weight, recon and pred_x in it weight the object's
                                  pixels more; the pose term only with λ4 > 0, the reward term
                                  only with a reward head and rewards)

Given longer sequences x_0..x_T and ``window=H``, it computes the terms of every window of H
actions in them while encoding and reconstructing each frame once (the trainer's
``--batching trajectories``): pred_x and pred_z are then the means over the same windows,
and recon (and the pose term on encoded frames) weighs every frame once instead of once per
window that holds it.

A continuous-time model (:attr:`LatentDynamics.continuous`) is a
:class:`~latent_sindy.models.continuous_model.ContinuousLatentModel`, which
``LatentModel(config)`` builds for such a config: its loss, the SINDy autoencoder's, is on a
frame and its time derivatives instead (formulas in :mod:`latent_sindy.models.continuous_model`).

Dimensions: B batch, H horizon, C channels, h × w image, nz latent size, nu action size.

    >>> cfg = ModelConfig(dynamics=SindyConfig(order=2)).resolve(1, 32, 3)
    >>> terms = LatentModel(cfg).loss(torch.zeros(8, 2, 1, 32, 32), torch.zeros(8, 1, 3))
    >>> sorted(terms)
    ['l1', 'objective', 'pose', 'pred_x', 'pred_z', 'recon', 'reward', 'total']
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar, Literal, Union

import torch
import tyro
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.models.autoencoder import AutoencoderConfig, ImageSize
from latent_sindy.models.dynamics import (
    DynamicsConfig,
    LatentDynamics,
    SindyConfig,
    SparseDynamics,
)
from latent_sindy.models.loss import DEFAULT_WEIGHTS, LossWeights, foreground, latent_error
from latent_sindy.models.pose_head import POSE_HEADS, PoseHead
from latent_sindy.models.reward_head import RewardHead, Targets, reward_error
from latent_sindy.models.state import ANGLE_FEATURES, StateConfig

__all__ = ["LOSS_TERMS", "OBSERVATION_CONFIGS", "LatentModel", "LossWeights", "ModelConfig",
           "ObservationConfig"]

#: The registry of observations: images (the autoencoder) or the true state.
OBSERVATION_CONFIGS: tuple[type, ...] = (AutoencoderConfig, StateConfig)
#: A tagged union of them; on the command line a subcommand after the dynamics' one
#: (``latent-sindy train sindy state``); images are the default.
ObservationConfig = Union[tuple(  # noqa: UP007  (built from the registry at import time)
    Annotated[c, tyro.conf.subcommand(c.kind)] for c in OBSERVATION_CONFIGS)]

#: The names of the loss terms :meth:`LatentModel.loss` returns, in report order.
LOSS_TERMS = ("total", "recon", "pred_x", "pred_z", "l1", "pose", "objective", "reward")


@dataclass(frozen=True)
class ModelConfig:
    """Everything that defines a latent model's architecture; it rebuilds the model alone.

    The image shape and the action size left as None are taken from the training data (see
    :meth:`resolve`); a model can only be built from a resolved config.
    """

    dynamics: DynamicsConfig = field(default_factory=SindyConfig)
    """Latent dynamics: a subcommand on the command line (sindy, linear, mlp)."""
    observation: ObservationConfig = field(default_factory=AutoencoderConfig)
    """What the model sees, and how it encodes it: "image" (the autoencoder; the latent size
    included) or "state" (the true pose: a reference model)."""
    action_dim: int | None = None
    """Action size nu; None: from the data file."""
    pose_head: Literal["none", "linear", "coordinates"] = "none"
    """Image models: a readout of the pose features from the latent, trained with the data's
    true poses (privileged; weight --lambda-pose) and usable as MPPI's cost (--space pose):
    "linear" (learned), or "coordinates" (the first four latent coordinates are the pose
    features, x, y, cos fθ, sin fθ, f the object's symmetry, so a library written on a pose
    latent can write the dynamics on them). Control reads the goal's pose from the goal
    image, never the true state."""
    turn: bool = False
    """A pose latent's orientation features (z2, z3) are turned, after every step, by the
    angle ω that the dynamics give as z2's update (z2 + i z3 times e^(iω); z3's own update is
    unused), instead of being updated like the others: a turn of any size is one equation."""
    reward_head: int = 0
    """Hidden width of a reward head r̂(z, u), trained on the data's rewards (weight
    --lambda-reward) and what a planner against the reward maximises; 0: no head."""

    def __post_init__(self) -> None:
        if self.action_dim is not None and self.action_dim < 0:  # 0: an autonomous system
            raise UserError(f"model action_dim {self.action_dim}: use 0 (no actions) or more, "
                            "or leave it unset to use the data's")
        if self.pose_head not in ("none", *POSE_HEADS):
            raise UserError(f"--pose-head {self.pose_head!r}: use none, "
                            + ", ".join(POSE_HEADS))
        if self.has_pose_head and self.observation.kind != "image":
            raise UserError(f"--pose-head is for image models: a {self.observation.kind} "
                            "model's latent is the pose already; drop --pose-head")
        if isinstance(self.dynamics, SindyConfig) and self.dynamics.pose_library and (
                not self.pose_latent):
            raise UserError(f"--library {self.dynamics.library} writes the dynamics on the pose "
                            "features (z2, z3 = cos, sin of the angle): use it with the state "
                            "encoder, the moments encoder (--encoder moments --latent-dim 4) or "
                            "--pose-head coordinates, or use a library written on any latent "
                            "(e.g. poly)")
        if isinstance(self.dynamics, SindyConfig) and self.dynamics.follows_latent and (
                getattr(self.observation, "encoder_kind", None) not in ("moments",
                                                                      "mask_moments")):
            raise UserError(f"--library-options {self.dynamics.named.latent_frequency}=0 takes "
                            "the moments encoder's --moment-order: use it with --encoder "
                            "moments or mask_moments, or give the angle frequency of the "
                            "object's symmetry")
        if self.turn and not self.pose_latent:
            raise UserError("--turn turns the pose latent's orientation features (z2, z3): use "
                            "it with the state or moments encoder or --pose-head coordinates")
        if self.dynamics.kind == "continuous" and (
                self.observation.kind != "image" or self.has_pose_head
                or self.observation.decoder_kind in ("conv", "sprite")):
            raise UserError("continuous-time dynamics are trained on image derivatives through "
                            "the encoder and decoder: use an image model without a pose head "
                            "and with --decoder mlp or fc (the conv and sprite decoders have no "
                            "forward-mode derivative here)")
        if self.reward_head < 0 or (self.reward_head and self.dynamics.kind == "continuous"):
            raise UserError(f"--reward-head {self.reward_head}: give a hidden width > 0 (0: no "
                            "head), on discrete-time dynamics")
        if self.pose_head == "coordinates" and self.observation.latent_dim < 4:
            raise UserError(f"--pose-head coordinates puts the pose in the first 4 latent "
                            f"coordinates: use --latent-dim 4 or more, not "
                            f"{self.observation.latent_dim}")

    @property
    def has_pose_head(self) -> bool:
        return self.pose_head != "none"

    @property
    def pose_latent(self) -> bool:
        """Whether the first four latent coordinates are the pose features (x, y, cos fθ,
        sin fθ): the state and moments encoders, or a coordinates pose head. The dynamics then
        keep (z2, z3) on the unit circle."""
        return self.observation.pose_latent or self.pose_head == "coordinates"

    @property
    def resolved(self) -> bool:
        return self.observation.resolved and self.action_dim is not None and not (
            getattr(self.dynamics, "follows_latent", False))

    def with_moment_order(self, order: int) -> ModelConfig:
        """This config with the moments encoder's order ``order``, and the named library's
        angle frequency too where it was left to it (:attr:`SindyConfig.follows_latent`)."""
        dyn = self.dynamics
        if isinstance(dyn, SindyConfig):
            dyn = dyn.with_latent_frequency(order)
        return dataclasses.replace(self, observation=dataclasses.replace(
            self.observation, moment_order=order), dynamics=dyn)

    @property
    def dynamics_kind(self) -> str:
        """The dynamics kind ("sindy", "linear", "mlp")."""
        return self.dynamics.kind

    def resolve(self, channels: int, image_size: ImageSize, action_dim: int,
                source: str = "the data") -> ModelConfig:
        """This config with the data's shapes filled in (``image_size``: the side S of square
        images, or (H, W)); UserError if it contradicts them."""
        if self.action_dim is not None and self.action_dim != action_dim:
            raise UserError(f"--action-dim {self.action_dim} but {source} has actions of "
                            f"size {action_dim}: leave it unset to use the data's")
        out = dataclasses.replace(
            self, observation=self.observation.resolve(channels, image_size, source),
            action_dim=action_dim)
        order = getattr(self.observation, "moment_order", 0)
        if getattr(self.dynamics, "follows_latent", False) and order:
            out = out.with_moment_order(order)
        return out


class LatentModel(nn.Module):
    """Autoencoder + latent dynamics; ``step(z, u)`` is the dynamics model's step (with the
    angle features of a pose latent projected onto the unit circle: ``dynamics.circle``).

    Args:
        config: a resolved :class:`ModelConfig`. The parameters are initialised from the
            global torch generator (seed it for reproducible runs).
    """

    #: The model types of the dynamics kinds that have their own (the kind's module
    #: registers it by subclassing: ``class ContinuousLatentModel(LatentModel,
    #: dynamics_kind="continuous")``; :mod:`latent_sindy.models` imports them all).
    _by_dynamics: ClassVar[dict[str, type[LatentModel]]] = {}

    def __init_subclass__(cls, dynamics_kind: str | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if dynamics_kind is not None:
            LatentModel._by_dynamics[dynamics_kind] = cls

    def __new__(cls, config: ModelConfig | None = None, *args: Any, **kwargs: Any
                ) -> LatentModel:
        """``LatentModel(config)`` is the model type of the config's dynamics kind (the one
        place that chooses it); None (unpickling, copying): ``cls`` itself."""
        if cls is LatentModel and config is not None:
            cls = LatentModel._by_dynamics.get(config.dynamics.kind, cls)
        return super().__new__(cls)

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        if not config.resolved:
            raise ValueError("ModelConfig needs the data's shapes: call resolve() first")
        self.config = config
        self.autoencoder = config.observation.build()
        self.dynamics: LatentDynamics = config.dynamics.build(
            config.observation.latent_dim, config.action_dim,
            circle=ANGLE_FEATURES if config.pose_latent else None, turn=config.turn)
        # Built last, so that the autoencoder and the dynamics draw the same initial weights
        # with or without it.
        self.pose_head: PoseHead | None = (
            POSE_HEADS[config.pose_head](config.observation.latent_dim)
            if config.has_pose_head else None)
        self.reward_head: RewardHead | None = (
            RewardHead(config.observation.latent_dim, config.action_dim, config.reward_head)
            if config.reward_head else None)

    @torch.no_grad()
    def fit_statistics(self, frames: torch.Tensor, poses: torch.Tensor | None) -> None:
        """Set what the model takes from the training split rather than learns: the moments
        encoder's background from the normalised frames (..., C, h, w) (other encoders take
        none) and a pose head's standardisation from the pose features (..., 4)."""
        self.autoencoder.fit_statistics(frames.reshape(-1, *frames.shape[-3:]))
        if self.pose_head is not None and poses is not None:
            self.pose_head.fit_statistics(poses)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """x (..., C, h, w) normalised images -> z (..., nz)."""
        return self.autoencoder.encode(x)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """z (..., nz) -> x̂ (..., C, h, w) normalised images."""
        return self.autoencoder.decode(z)

    def step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """One latent step: z (K, nz), u (K, nu) -> (K, nz)."""
        return self.dynamics.step(z, u)

    def rollout_latent(self, z0: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Open loop: z0 (B, nz), u (B, H, nu) -> ẑ (B, H+1, nz), ẑ_0 = z0."""
        return self.dynamics.rollout(z0, u)

    def predict(self, x0: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Predicted images: x0 (B, C, h, w), u (B, H, nu) -> x̂ (B, H+1, C, h, w)."""
        return self.decode(self.rollout_latent(self.encode(x0), u))

    def l1_penalty(self) -> torch.Tensor:
        """‖M ⊙ Ψ‖₁ for SINDy, a zero scalar for the other models."""
        if isinstance(self.dynamics, SparseDynamics):
            return self.dynamics.l1_penalty()
        return next(self.parameters()).new_zeros(())

    def loss(
        self, x: torch.Tensor, u: torch.Tensor, weights: LossWeights | None = None,
        poses: torch.Tensor | Targets | None = None, window: int | None = None,
    ) -> dict[str, torch.Tensor]:
        """The loss terms of :data:`LOSS_TERMS` on sequences x (B, T+1, C, h, w), u (B, T, nu).

        ``window`` H (1..T; None: T) cuts a window of H actions at every start t = 0..T-H of
        each sequence: the frames are encoded and reconstructed once each, ẑ is rolled out H
        steps from every encoded frame z_t, and every prediction is decoded in the same
        decoder pass. recon (and the pose head's term on encoded frames) is the mean over the
        B (T+1) frames; pred_x, pred_z (and the pose head's term on predictions) are the
        means over the B (T-H+1) windows, exactly those of the windows passed one by one
        (which count a frame in every window that holds it). ``weights`` None uses the
        defaults of :class:`LossWeights`. ``poses`` (B, T+1, 4): the true pose features of
        the sequences, for the pose head's term (0 without them or without a head), or
        :class:`Targets` holding them and the rewards (B, T) for a reward head's term.
        """
        weights = weights or DEFAULT_WEIGHTS
        poses, rewards = (poses.poses, poses.rewards) if isinstance(poses, Targets) else (
            poses, None)
        if x.ndim < 3 or u.ndim != 3 or u.shape[:2] != (x.shape[0], x.shape[1] - 1):
            raise ValueError(
                f"loss expects x (B, T+1, ...) and u (B, T, nu), got {tuple(x.shape)} and "
                f"{tuple(u.shape)}"
            )
        b, t = u.shape[:2]
        h = t if window is None else window
        if not 1 <= h <= t:
            raise ValueError(f"loss: window {h} does not fit sequences of {t} actions")
        starts = t - h + 1  # windows per sequence: W
        z = self.encode(x)  # (B, T+1, nz)
        u_win = u.unfold(1, h, 1).movedim(-1, 2)  # (B, W, H, nu): u_win[:, s, k] = u[:, s + k]
        z_hat = self.rollout_latent(z[:, :starts].reshape(b * starts, -1),
                                    u_win.reshape(b * starts, h, -1))[:, 1:]  # (B W, H, nz)
        z_hat = z_hat.reshape(b, starts * h, -1)  # (B, W H, nz)
        # One decoder pass for the reconstructions and the predictions.
        x_dec = self.decode(torch.cat([z, z_hat], dim=1))  # (B, T+1 + W H, C, h, w)

        def targets(v: torch.Tensor) -> torch.Tensor:
            """v (B, T+1, ...) -> v_{s+1..s+H} of every window s, (B, W H, ...)."""
            if starts == 1:
                return v[:, 1:]
            return v[:, 1:].unfold(1, h, 1).movedim(-1, 2).reshape(b, starts * h, *v.shape[2:])

        err_recon = (x_dec[:, : t + 1] - x).square()
        err_pred = (x_dec[:, t + 1 :] - targets(x)).square()
        recon, pred_x = err_recon.mean(), err_pred.mean()
        pred_z = latent_error(z_hat, targets(z), weights.relative_pred_z)
        l1 = self.l1_penalty()
        pose = self._pose_error(z, z_hat, poses, targets)
        objective = recon + weights.lambda_pred_x * pred_x + weights.lambda_pred_z * pred_z
        trained = objective
        if weights.foreground_weight and self.config.observation.kind == "image":
            w = 1 + weights.foreground_weight * foreground(x)  # (B, T+1, C, h, w)
            trained = ((w * err_recon).mean() + weights.lambda_pred_x * (targets(w) * err_pred)
                       .mean() + weights.lambda_pred_z * pred_z)
        total = trained + weights.lambda_l1 * l1
        if weights.lambda_pose > 0:  # 0 * a non-finite pose error would still be NaN
            total = total + weights.lambda_pose * pose
        reward = l1.new_zeros(())
        if self.reward_head is not None and rewards is not None:
            reward = reward_error(self.reward_head, z, z_hat, u_win, rewards)
            total = total + weights.lambda_reward * reward
        return {
            "total": total,
            "recon": recon,
            "pred_x": pred_x,
            "pred_z": pred_z,
            "l1": l1,
            "pose": pose,
            "objective": objective,
            "reward": reward,
        }

    def _pose_error(self, z: torch.Tensor, z_hat: torch.Tensor, poses: torch.Tensor | None,
                    targets: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
        """The pose head's mean squared error (standardised units) on the encoded images z
        (B, T+1, nz) and the predicted latents ẑ (B, W H, nz) against poses (B, T+1, 4);
        ``targets`` picks the poses of the predicted steps."""
        if self.pose_head is None or poses is None:
            return z.new_zeros(())
        if poses.shape != (*z.shape[:2], 4):
            raise ValueError(f"loss expects poses {(*z.shape[:2], 4)}, got {tuple(poses.shape)}")
        target = self.pose_head.standardize(poses)  # (B, T+1, 4)
        head = self.pose_head.standardized
        return ((head(z) - target).square().mean()
                + (head(z_hat) - targets(target)).square().mean())
