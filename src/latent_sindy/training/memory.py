"""What training needs in memory, judged from the settings and the data's shapes alone before
anything is built or written: the latent dynamics (an order-2 library on 100000 latents has
5e9 terms) and the autoencoder (its weights, and its activations for one mini-batch).

    check_training_memory(model_cfg, cfg, data)   # UserError naming the largest part and the fix
"""

from __future__ import annotations

import math
from typing import Any

import torch

from latent_sindy.atomic import check_memory
from latent_sindy.data import SequenceData
from latent_sindy.models.latent_model import ModelConfig
from latent_sindy.training.config import TrainConfig

__all__ = ["check_training_memory"]


def check_training_memory(model_cfg: ModelConfig, cfg: TrainConfig, data: SequenceData
                          ) -> None:
    """Refuse, from the settings and the data's shapes alone, a model whose training cannot
    fit in memory, before anything is built or written: the latent dynamics (an order-2
    library on 100000 latents has 5e9 terms) and the autoencoder (its weights, and its
    activations for one mini-batch: 2048x2048 images need tens of GB). ``model_cfg`` is
    resolved against ``data``; ``cfg.batch_size`` is settled."""
    parts = [_dynamics_bytes(model_cfg, cfg), _autoencoder_bytes(model_cfg, cfg, data)]
    parts = [p for p in parts if p is not None]
    if parts:
        _, what, fix = max(parts)
        check_memory(sum(b for b, _, _ in parts), what, fix)


def _dynamics_bytes(model_cfg: ModelConfig, cfg: TrainConfig) -> tuple[int, str, str] | None:
    nz = model_cfg.observation.latent_dim
    nu = model_cfg.action_dim or 0
    dyn = model_cfg.dynamics
    fix = "use a smaller --latent-dim"
    if dyn.kind == "sindy":  # the polynomial part alone; a named library's other terms come on top
        terms = math.comb(nz + nu + dyn.order, dyn.order)
        terms += nz * (getattr(dyn, "include_sine", False) + getattr(dyn, "include_cosine", False))
        params = terms * nz  # Ψ (p, nz); Θ (B, p)
        activations = (cfg.batch_size or 1) * terms
        what = (f"SINDy of order {dyn.order} on --latent-dim {nz} ({terms:.3g} library terms "
                f"x {nz} coefficients)")
        fix += " or --order"
    elif dyn.kind == "linear":
        params = nz * (nz + nu + 1)
        activations = 0
        what = f"linear dynamics on --latent-dim {nz} ({nz} x {nz + nu + 1} coefficients)"
    elif dyn.kind == "mlp":
        width = dyn.hidden
        params = (nz + nu + 2 * dyn.harmonics) * width + (dyn.layers - 1) * width**2 + width * nz
        activations = 0
        what = f"an MLP of {dyn.layers} x {width} on --latent-dim {nz}"
    else:
        return None
    # float32 weights, gradients and two AdamW moments, a bool mask; the batch's activations
    # and their gradients
    return 17 * params + 8 * activations, what, fix


def _autoencoder_bytes(model_cfg: ModelConfig, cfg: TrainConfig, data: SequenceData
                       ) -> tuple[int, str, str] | None:
    """The autoencoder's weights (with gradients and AdamW's moments) and the activations of
    one mini-batch (with their gradients), counted on torch's meta device: shapes without
    storage, so nothing of the size being checked is allocated."""
    obs = model_cfg.observation
    if obs.kind != "image":
        return None
    c, h, w = data.frame_shape
    try:
        obs = obs.resolve(c, (h, w))
        with torch.device("meta"):
            auto = obs.build()
    except (RuntimeError, NotImplementedError, TypeError, ValueError):
        return None  # an encoder that cannot be built without storage goes unchecked here
    params = sum(p.numel() for p in auto.parameters())
    per_frame = _activations_per_frame(auto, (c, h, w))
    if model_cfg.dynamics.kind == "continuous":  # frames and their forward-mode tangents
        frames = (cfg.batch_size or 1) * (1 + model_cfg.dynamics.derivative_order)
    else:  # a window's frames, encoded and their predictions decoded
        frames = (cfg.batch_size or 1) * (cfg.window + 1)
    what = (f"the {obs.encoder_kind} encoder and {obs.decoder_kind} decoder on {h}x{w} images "
            f"({params:.3g} weights, {per_frame:.3g} activations a frame, {frames} frames a "
            "batch)")
    return (16 * params + 8 * per_frame * frames, what,
            "use smaller images, a smaller --batch-size, or a smaller autoencoder "
            "(--encoder-hidden, --decoder-hidden, --conv-channels)")


def _activations_per_frame(auto: torch.nn.Module, shape: tuple[int, int, int]) -> int:
    """How many values the modules of ``auto`` (built on the meta device) output for one
    frame, encoded and decoded; where its forward cannot run on the meta device (it reads a
    value), a feature map of every convolution's width at the image's size."""
    total = 0

    def count(_module: torch.nn.Module, _inputs: Any, out: Any) -> None:
        nonlocal total
        outs = out if isinstance(out, tuple | list) else (out,)
        total += sum(o.numel() for o in outs if isinstance(o, torch.Tensor))

    hooks = [m.register_forward_hook(count) for m in auto.modules()]
    try:
        with torch.no_grad():
            auto.decode(auto.encode(torch.empty(1, *shape, device="meta")))
    except (RuntimeError, NotImplementedError):
        total = sum(m.out_channels * shape[1] * shape[2] for m in auto.modules()
                    if isinstance(m, torch.nn.Conv2d)) + 2 * math.prod(shape)
    finally:
        for hook in hooks:
            hook.remove()
    return total
