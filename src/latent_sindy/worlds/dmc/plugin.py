"""The DeepMind Control world's plug-in (entry point ``dmc`` of ``latent_sindy.worlds``):
:data:`WORLD` is the world (:class:`~.world.DmcWorld`, cartpole-swingup by default) with its
study, ``latent-sindy reproduce --world dmc``. Importing this module does not import
dm_control.

    latent-sindy reproduce --world dmc --world-config task=cartpole-swingup --scale tiny
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from latent_sindy.plugins import CONFIG_GIVEN
from latent_sindy.worlds.dmc.world import GOALS, DmcWorld

__all__ = ["GOALS", "WORLD", "DmcPlugin", "DmcWorld"]


class DmcPlugin(DmcWorld):
    """The DeepMind Control world's plug-in: the world (:class:`DmcWorld`) and its study."""

    # ------------------------------------------------------ latent-sindy reproduce
    about = ("a DeepMind Control task from pixels (--world-config task=...; cartpole-swingup "
             "by default): PlaNet's model-based loop with SINDy, linear and MLP latent "
             "dynamics side by side, return against environment steps")

    @property
    def scales(self) -> dict[str, str]:
        """``reproduce --scale`` names of this world's study, with what each runs."""
        from latent_sindy.worlds.dmc.study import SCALES

        return {name: s.about for name, s in SCALES.items()}

    #: ``reproduce --workers N`` runs N of the study's (seed, model) loops at a time.
    study_options = ("workers",)

    def reproduce(self, scale: str, out: Path, seeds: tuple[int, ...] | None = None,
                  device: str = "auto", threads: int = 1,
                  say: Callable[[str], None] = print, workers: int = 1) -> Any:
        """The model-based study of this world's task at ``scale`` in ``out`` (finished
        loops reused, ``workers`` loops at a time): a
        :class:`~latent_sindy.world_study.WorldStudy` for the report. The suite and the
        task are checked first: without them nothing is written in ``out``."""
        from latent_sindy.worlds.dmc.study import dmc_study
        from latent_sindy.worlds.dmc.suite import check_task

        check_task(self.config)
        return dmc_study(self.config, scale, out, seeds, device, threads, say, workers,
                         getattr(self, CONFIG_GIVEN, None))


WORLD = DmcPlugin()
