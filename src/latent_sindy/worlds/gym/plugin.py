"""The gym world's plug-in (entry point ``gym`` of ``latent_sindy.worlds``): :data:`WORLD` is
the world (:class:`~.world.GymWorld`, Pendulum-v1 by default) with its study, ``latent-sindy
reproduce --world gym``. Importing this module does not import gymnasium.

    latent-sindy reproduce --world gym --world-config id=Pendulum-v1 --scale tiny --out /tmp/g
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from latent_sindy.plugins import CONFIG_GIVEN
from latent_sindy.worlds.gym.world import GymWorld

__all__ = ["WORLD", "GymPlugin", "GymWorld"]


class GymPlugin(GymWorld):
    """The gym world's plug-in: the world (:class:`GymWorld`) and its study."""

    # ------------------------------------------------------ latent-sindy reproduce
    about = ("any Gymnasium environment with rgb_array frames (--world-config id=...; "
             "Pendulum-v1 by default): the dmc world's model-based loop against its own "
             "reward, SINDy, linear and MLP latent dynamics side by side")

    @property
    def scales(self) -> dict[str, str]:
        """``reproduce --scale`` names of this world's study, with what each runs."""
        from latent_sindy.worlds.gym.study import SCALES

        return {name: s.about for name, s in SCALES.items()}

    #: ``reproduce --workers N`` runs N of the study's (seed, model) loops at a time.
    study_options = ("workers",)

    def reproduce(self, scale: str, out: Path, seeds: tuple[int, ...] | None = None,
                  device: str = "auto", threads: int = 1,
                  say: Callable[[str], None] = print, workers: int = 1) -> Any:
        """The model-based study of this world's environment at ``scale`` in ``out``
        (finished loops reused, ``workers`` loops at a time): a
        :class:`~latent_sindy.world_study.WorldStudy` for the report. The environment is
        made first: an id it cannot make or a missing renderer writes nothing in ``out``."""
        from latent_sindy.worlds.gym.study import gym_study

        return gym_study(self.config, scale, out, seeds, device, threads, say, workers,
                         getattr(self, CONFIG_GIVEN, None))


WORLD = GymPlugin()
