"""The DeepMind Control study as ``latent-sindy reproduce`` writes it: the
:class:`~latent_sindy.world_study.WorldStudy` of :func:`.study.run_dmc_study`'s runs, made by
the generic model-based report (:mod:`latent_sindy.study.model_based_report`: tables of
return against environment steps per model with intervals over seeds, costs, active terms;
the last SINDy equations; a figure) with the published reference rows of cartpole-swingup.

    study = dmc_study(DmcConfig(), "tiny", Path("/tmp/dmc"), None, "cpu", 1, print)
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from pathlib import Path

from latent_sindy.study.model_based_report import Reference, model_based_study
from latent_sindy.world_study import WorldStudy
from latent_sindy.worlds.dmc.config import DmcConfig
from latent_sindy.worlds.dmc.study import REFERENCE, REFERENCE_STEPS, REFERENCE_TASK, run_dmc_study

__all__ = ["dmc_study"]

Say = Callable[[str], None]

#: The published lines with where each was published.
_REFERENCE = Reference(REFERENCE_TASK, REFERENCE_STEPS, REFERENCE,
                       {name: "DrQ's paper, Table 1" if name == "DrQ" else
                        "CURL's paper, Table 1" for name in REFERENCE})


def dmc_study(config: DmcConfig, scale: str, out: Path, seeds: tuple[int, ...] | None,
              device: str, threads: int, say: Say, workers: int = 1,
              given: Collection[str] | None = None) -> WorldStudy:
    """The study at ``scale`` in ``out`` (finished loops reused, ``workers`` loops at a
    time), as a WorldStudy; ``given``: the fields of ``config`` a user set."""
    result = run_dmc_study(config, scale, out, seeds, device, threads, say, workers, given)
    task = result["settings"]["world"]["task"]
    return model_based_study(
        result, scale, out, f"DeepMind Control from pixels: {task}, model-based, SINDy / "
        "linear / MLP", task, _REFERENCE)
