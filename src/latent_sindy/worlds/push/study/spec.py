"""One model of the push study (a row of its tables): name, label and training recipe.

    ModelSpec("sindy2", "SINDy-2", ModelConfig(dynamics=SindyConfig(order=2)), headline=True)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from latent_sindy.models.latent_model import LossWeights, ModelConfig

__all__ = ["SINGLE_STEP", "ModelSpec"]

#: The name of the single-step model the multi-step one is compared with.
SINGLE_STEP = "sindy2"


@dataclass(frozen=True)
class ModelSpec:
    """One model of the study: its name (folder, table column), label and training recipe."""

    name: str
    label: str
    model: ModelConfig
    window: int = 1
    """Training window H (1: single-step)."""
    relative_time: float = 1.0
    """Relative training time, to start the longest jobs first."""
    loss: LossWeights = field(default_factory=LossWeights)
    """Weights of the loss terms."""
    headline: bool = False
    """A headline row: the most random-task episodes."""
    epochs_factor: int = 1
    """Train this many times the scale's epochs (and prune and validate that much less often):
    the state rows, whose epochs cost a small part of an image model's, are still improving
    after the images' schedule (RESULTS.md, "The state rows")."""
    image_space: bool = False
    """Also plan with image-space MPPI (the paper's variant; needs an image model). The study
    runs it for SINDy-2 only: a step decodes K·H images (Table I's "planning ms per step,
    image-space MPPI")."""
    prune_below: float | None = None
    """SINDy's pruning cut τ (|Ψ| < τ pruned, ``TrainConfig.prune_below``); None: the
    scale's."""
    init_share: float = 0.0
    """SINDy on a fixed encoder: the smallest share a term may contribute in the sparse
    regression its coefficients start from (``TrainConfig.sindy_init_share``)."""
    sindy_fit: Literal["joint", "after"] = "joint"
    """SINDy: trained with the autoencoder ("joint") or fitted by sparse regression to the
    trained encoder's latents ("after", ``TrainConfig.sindy_fit``)."""
    latent_cost: Literal["latent", "pose"] = "latent"
    """The cost of its latent MPPI: "latent" (the distance to the encoded goal image, every
    coordinate alike) or "pose" (its pose head's reading against the goal image's; a model
    with a pose head)."""

    def __post_init__(self) -> None:
        if self.latent_cost == "pose" and not self.model.has_pose_head:
            raise ValueError(f"model {self.name}: the pose cost needs a model with a pose head")
