"""Model-based reinforcement learning from pixels: the online loop that collects episodes,
refits a latent model with a reward head on all the data so far and plans against the
predicted reward (:mod:`.online`), its warm-started refits (:mod:`.warm_start`), and several
models side by side through the same loop (:mod:`.compare`). Planning itself is
:mod:`latent_sindy.control`'s; the estimator is any with ``fit(data)`` and ``planner(...)``
(:class:`latent_sindy.LatentSINDy`, :class:`latent_sindy.read_latent.ReadLatent`).

    from latent_sindy.model_based import ModelBasedConfig, model_based
    result = model_based(world, make, ModelBasedConfig(iterations=10), out="runs/mbrl")
"""

from latent_sindy.model_based.compare import compare_models
from latent_sindy.model_based.online import ModelBasedConfig, ModelBasedResult, model_based

__all__ = ["ModelBasedConfig", "ModelBasedResult", "compare_models", "model_based"]
