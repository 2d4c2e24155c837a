"""Several latent models through the same model-based loop (:func:`.model_based`), side by
side: one loop each, with the same settings, the same seed (hence the same seed episodes,
tasks and exploration draws) and the same planner, in a folder each, so that a study
compares the dynamics (SINDy, linear, MLP) and nothing else.

    results = compare_models(world, {"sindy": make_sindy, "linear": make_linear},
                             ModelBasedConfig(iterations=10), out="runs/compare")
    results["sindy"].returns
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from latent_sindy.control.world import World
from latent_sindy.errors import UserError
from latent_sindy.model_based.online import ModelBasedConfig, ModelBasedResult, model_based
from latent_sindy.progress import Progress

__all__ = ["compare_models"]


def compare_models(world: World, makers: Mapping[str, Callable[[int], Any]],
                   cfg: ModelBasedConfig, out: str | Path | None = None,
                   progress: Callable[[str], Progress | None] | None = None,
                   fit_settings: dict[str, Any] | Mapping[str, dict[str, Any]] | None = None
                   ) -> dict[str, ModelBasedResult]:
    """One loop of ``cfg`` per named estimator factory (``makers``, in their order), each
    in ``out/<name>`` (resumable as :func:`.model_based` is); ``progress(name)`` gives each
    loop's progress; ``fit_settings``: one dict for all, or one per name."""
    bad = [n for n in makers if not n or "/" in n or n.startswith(".")]
    if bad or not makers:
        raise UserError(f"compare_models: model names {bad or '(none)'}: give at least one, "
                        "each a plain folder name")
    per_name = isinstance(fit_settings, Mapping) and set(fit_settings) == set(makers) and all(
        isinstance(v, Mapping) for v in fit_settings.values())
    results = {}
    for name, make in makers.items():
        settings = dict(fit_settings[name]) if per_name else dict(fit_settings or {})
        results[name] = model_based(world, make, cfg,
                                    out=None if out is None else Path(out) / name,
                                    progress=progress(name) if progress else None,
                                    fit_settings=settings)
    return results
