"""The study's models: each row's name, label and training recipe (:mod:`.spec`); a study's
choice of them (``--models``, ``--sweep``) is :func:`.config.study_specs`.

Rows are looked up by name, never by position. Why each row is set as it is, with the
measurements behind it: RESULTS.md, "Why the catalogue's rows are set as they are".

    latent-sindy reproduce --models sindy2 sindy_moments state_sindy

    >>> from latent_sindy.worlds.push.study.scales import SCALES
    >>> [s.name for s in model_specs(SCALES["demo"])][:6]
    ['sindy1', 'sindy2', 'sindy3', 'sindy4', 'linear', 'mlp']
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

from latent_sindy.models.autoencoder import AutoencoderConfig
from latent_sindy.models.dynamics import LinearConfig, MlpConfig, SindyConfig
from latent_sindy.models.latent_model import LossWeights, ModelConfig
from latent_sindy.models.state import StateConfig
from latent_sindy.worlds.push.study.scales import Scale
from latent_sindy.worlds.push.study.spec import SINGLE_STEP, ModelSpec

__all__ = ["SINGLE_STEP", "ModelSpec", "model_specs"]


def model_specs(scale: Scale, decoder: Literal["conv", "fc"] = "conv",
                angle_period: float = math.pi / 2,
                push: Literal["symmetric", "paper"] = "symmetric") -> tuple[ModelSpec, ...]:
    """SINDy orders 1-4, linear (E2C), MLP, SINDy order 2 trained on H-step windows, SINDy
    order 2 with the push library, and the same with a privileged pose head planning on its
    pose cost, all with the same autoencoder architecture; the pose latents (privileged, read
    from the image's moments, and learned: a learned mask's moments at an order the data
    chooses); then SINDy (face library), linear
    and MLP on the true state (the reference rows the image models are measured against).
    ``angle_period`` is the world's visible symmetry, which sets the face library's angle
    frequency; ``push`` its push style: the face library writes pushes given as world
    directions, so a world whose push angle is relative to the block ("paper", "marked")
    keeps the push library in those rows."""
    h = scale.multistep_window
    auto = AutoencoderConfig(decoder_kind=decoder)
    library = "face" if push == "symmetric" else "push"
    pose_dynamics = SindyConfig(order=1, library=library, include_sine=False,
                                library_options={"frequency": 2 * math.pi / angle_period}
                                if library == "face" else ())
    frame = library == "face"  # the frame library, like the face one, needs world directions
    moments = dataclasses.replace(auto, encoder_kind="moments", latent_dim=4,
                                  decoder_kind="sprite",
                                  moment_order=round(2 * math.pi / angle_period))
    frame_dynamics = dataclasses.replace(pose_dynamics, library="frame") if frame else None
    # (8 maps in 2 layers read the same poses as 16 in 3, in 60 % of the time: RESULTS.md,
    # "The learned row")
    learned = dataclasses.replace(moments, encoder_kind="mask_moments", moment_order=0,
                                  mask_channels=8, mask_layers=2)

    def model(dynamics: Any) -> ModelConfig:
        return ModelConfig(observation=auto, dynamics=dynamics)

    def state(dynamics: Any) -> ModelConfig:
        return ModelConfig(observation=StateConfig(), dynamics=dynamics)

    return (
        *(ModelSpec(f"sindy{k}", f"SINDy-{k}", model(SindyConfig(order=k)),
                    relative_time=(1.0, 1.1, 1.2, 1.6)[k - 1], headline=k == 2,
                    image_space=k == 2)
          for k in (1, 2, 3, 4)),
        ModelSpec("linear", "linear (E2C)", model(LinearConfig()), relative_time=0.8,
                  headline=True),
        ModelSpec("mlp", "MLP", model(MlpConfig()), relative_time=0.9),
        ModelSpec(f"sindy2_h{h}", f"SINDy-2, H={h}", model(SindyConfig(order=2)),
                  window=h, relative_time=1.1 * (h + 1) / 2),
        # The latent model with the push's geometry in its library (u2 sin(u1),
        # z_i u2 cos(u1), ...): it plans better than the classic library (RESULTS.md, "The
        # push-library row").
        ModelSpec("sindy2_push", "SINDy-2 (push library)",
                  model(SindyConfig(order=2, library="push")), relative_time=1.15, headline=True),
        # The same with a pose head trained on the simulator's poses (privileged, training
        # only) and MPPI's cost on the head's reading (goal read from the goal image): the
        # unsupervised latents drop the block's orientation (issue 11). λ4 = 10: where the
        # angle probe stops rising (RESULTS.md, "The pose rows").
        ModelSpec("sindy2_pose", "SINDy-2 (push library), pose-supervised (privileged)",
                  dataclasses.replace(model(SindyConfig(order=2, library="push")),
                                      pose_head="linear"),
                  loss=LossWeights(lambda_pose=10.0), relative_time=1.2, headline=True,
                  latent_cost="pose"),
        # The latent is the pose read from the image: four coordinates supervised to be
        # (x, y, cos 4θ, sin 4θ) (privileged, training only), a wider encoder (16 channels:
        # with 4 the pose regression stalled), and the state row's face library on them;
        # MPPI's cost on those coordinates, the goal read from the goal image. Its encoder
        # needs data (RESULTS.md, "The pose rows").
        ModelSpec("sindy_pose", f"SINDy ({library} library), pose latent (privileged)",
                  ModelConfig(observation=dataclasses.replace(auto, latent_dim=4,
                                                          conv_channels=(16, 16)),
                              dynamics=pose_dynamics, pose_head="coordinates"),
                  loss=LossWeights(lambda_pose=10.0, lambda_l1=1e-3), relative_time=1.3,
                  headline=True, latent_cost="pose"),
        # The latent is the block's pose read from the image's moments (nothing learned and no
        # simulator pose: the centroid and the n-th angular moment of what differs from the
        # empty table, :class:`~latent_sindy.models.autoencoder.MomentEncoder`) and the state
        # row's library writes the dynamics on it. The encoder is fixed, so its latents are
        # data and SINDy is fitted as SINDy is meant to be: sequentially thresholded least
        # squares of the encoded training transitions, kept as they are (λ3 = 0, τ = 0; the
        # image prediction term would only bend them toward what the decoder draws: λ1 = 0).
        # The sprite decoder draws a learned template of the block at the latent's pose.
        # STLSQ at 0.2, the sprite decoder: RESULTS.md, "The moments row".
        ModelSpec("sindy_moments", f"SINDy ({library} library), image moments",
                  ModelConfig(observation=moments, dynamics=pose_dynamics),
                  loss=LossWeights(lambda_pred_x=0.0, lambda_l1=0.0), prune_below=0.0,
                  init_share=0.2,
                  relative_time=0.6, headline=True),
        # The frame library on the moments latent (its orientation sense and offset taken
        # from the data's camera at training), fitted as the face row but at a lower STLSQ
        # share: the image row that predicts pushes best, at less sparsity (RESULTS.md,
        # "The moments frame row").
        *((ModelSpec("sindy_moments_frame", "SINDy (frame library, turning), image moments",
                     dataclasses.replace(ModelConfig(observation=moments, dynamics=frame_dynamics),
                                         turn=True),
                     loss=LossWeights(lambda_pred_x=0.0, lambda_l1=0.0), prune_below=0.0,
                     init_share=0.05, relative_time=0.6, headline=True),
           ) if frame else ()),
        # The same latent with nothing set by hand: the mask that says which pixels count is
        # learned (mask_moments: 3x3 convolutions, trained by reconstruction through the
        # sprite decoder, no pose labels), the angular moment's order n is chosen from the
        # training images (a short fit at order 2 first) and the library's angle frequency is
        # that n. SINDy is fitted after the autoencoder, by STLSQ at 0.2 on its latents (the
        # prediction terms erase the orientation: RESULTS.md, "A learned object mask").
        ModelSpec("sindy_learned", f"SINDy ({library} library), learned mask moments",
                  ModelConfig(observation=learned,
                              dynamics=pose_dynamics.with_options(frequency=0.0)
                              if library == "face" else pose_dynamics),
                  loss=LossWeights(lambda_pred_x=0.0, lambda_pred_z=0.0, lambda_l1=0.0),
                  prune_below=0.0, init_share=0.2, sindy_fit="after", relative_time=1.0,
                  headline=True),
        # The face library: the push as it is (x += 0.080 ℓ cos ψ, y += 0.080 ℓ sin ψ) and the
        # turn, through the push angle relative to the pushed face (sin 4ψ, cos 4ψ times the
        # orientation features); the push library cannot write the turn. State losses are in
        # metres, far below the images': λ3 = 1e-3 (not the images' 1e-2) keeps the push
        # terms, with fewer terms than 1e-4 (RESULTS.md, "The state rows").
        # (The push library's row, kept for the worlds with pushes relative to the block:
        # λ3 = 1e-4, as the images' 1e-2 shrank its push terms.)
        ModelSpec("state_sindy", f"SINDy ({library} library), state", state(pose_dynamics),
                  loss=LossWeights(lambda_l1=1e-3 if library == "face" else 1e-4),
                  relative_time=0.1, headline=True, epochs_factor=10),
        # The frame library (the push in the pushed face's frame: its angle a from the face
        # normal, the normal's direction n): the best state row, at λ3 = 1e-4 (RESULTS.md,
        # "The state rows").
        *((ModelSpec("state_sindy_frame", "SINDy (frame library, turning), state",
                     dataclasses.replace(state(frame_dynamics), turn=True),
                     loss=LossWeights(lambda_l1=1e-4), relative_time=0.1, headline=True,
                     epochs_factor=10),
           ) if frame else ()),
        ModelSpec("state_linear", "linear, state", state(LinearConfig()), relative_time=0.1,
                  headline=True, epochs_factor=10),
        # The push angle also as cos / sin of 1-4 times it: a square block's pose features turn
        # 4 times per revolution. 10 times the epochs: it still improves after the images'
        # schedule (RESULTS.md, "The state rows").
        ModelSpec("state_mlp", "MLP, state", state(MlpConfig(harmonics=4)), relative_time=0.1,
                  headline=True, epochs_factor=10),
    )
