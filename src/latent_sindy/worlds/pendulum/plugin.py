"""The pendulum worlds' plug-ins (entry points ``pendulum`` and ``pendulum-video`` of
``latent_sindy.worlds``).

:data:`WORLD` is the controlled pendulum (:class:`~.world.PendulumWorld`: swing up from
hanging, or from anywhere, to upright at rest, seen through two stacked 48×48 frames) with
its study, ``latent-sindy reproduce --world pendulum``. :data:`VIDEO` is the autonomous
pendulum video's plug-in: its data name it, and the core reads its settings back from a data
file's or run's record. Neither loads gymnasium until an environment is made.

    from latent_sindy.plugins import get_world
    world = get_world("pendulum")                  # or PendulumWorld(PendulumConfig(...))
    data = world.collect(sequences=100, steps=10, seed=0)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from latent_sindy.data.sequence import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.plugins import CONFIG_GIVEN
from latent_sindy.worlds.pendulum.world import STATE_NAMES, UPRIGHT, PendulumWorld

__all__ = ["STATE_NAMES", "UPRIGHT", "VIDEO", "WORLD", "PendulumPlugin", "PendulumVideo",
           "PendulumWorld", "VideoSettings"]


class PendulumPlugin(PendulumWorld):
    """The controlled pendulum's plug-in: the world (:class:`PendulumWorld`) and its study."""

    # ------------------------------------------------------ latent-sindy reproduce
    about = ("the controlled pendulum (Pendulum-v1's physics) from images: SINDy, MLP and "
             "linear image models and a state SINDy swing it up with latent MPPI")

    @property
    def scales(self) -> dict[str, str]:
        """``reproduce --scale`` names of this world's study, with what each runs."""
        from latent_sindy.worlds.pendulum.reproduce import PENDULUM_SCALES

        return PENDULUM_SCALES

    def reproduce(self, scale: str, out: Path, seeds: tuple[int, ...] | None = None,
                  device: str = "auto", threads: int = 1,
                  say: Callable[[str], None] = print) -> Any:
        """The swing-up study at ``scale`` in ``out``: a
        :class:`~latent_sindy.world_study.WorldStudy` for the report. The world's settings
        given on the command line (``--world-config``: image_size, start, perturbation)
        replace the scale's camera and the tasks' starts."""
        from latent_sindy.worlds.pendulum.reproduce import pendulum_study

        given = {k: getattr(self.config, k) for k in getattr(self, CONFIG_GIVEN, ())}
        return pendulum_study(scale, out, seeds, device, threads, say, given)


@dataclass(frozen=True)
class VideoSettings:
    """The pendulum video's settings (``--world-config KEY=VALUE``)."""

    omega2: float = 1.0
    """ω² of the video's pendulum, θ̈ = −ω² sin θ (the benchmark's: 1); a seed is recovered
    when its sin z coefficient is within 2 % of −ω²."""
    starts: Literal["own_time", "benchmark"] = "own_time"
    """At ω² ≠ 1: the benchmark's starts in the pendulum's own time, or drawn as at ω² = 1."""


class PendulumVideo:
    """The pendulum video's plug-in, on its :class:`VideoSettings`: reads the settings its
    data record."""

    name = "pendulum-video"
    about = ("the SINDy autoencoder's pendulum video (PNAS 2019): does z'' = -sin z come "
             "back from the frames, over seeds, beside the published and replicated figures")

    def __init__(self, config: VideoSettings | None = None) -> None:
        self.config = config or VideoSettings()

    @property
    def scales(self) -> dict[str, str]:
        """``reproduce --scale`` names of the recovery study, with what each runs."""
        from latent_sindy.worlds.pendulum.reproduce import VIDEO_SCALES

        return VIDEO_SCALES

    def reproduce(self, scale: str, out: Path, seeds: tuple[int, ...] | None = None,
                  device: str = "auto", threads: int = 1,
                  say: Callable[[str], None] = print) -> Any:
        """The recovery study at ``scale`` in ``out`` (finished seeds reused): a
        :class:`~latent_sindy.world_study.WorldStudy` for the report."""
        from latent_sindy.worlds.pendulum.reproduce import pendulum_video_study

        return pendulum_video_study(scale, out, seeds, device, threads, say, self.config.omega2,
                                    self.config.starts)

    @staticmethod
    def config_from_record(record: dict[str, Any], where: str) -> dict[str, Any]:
        if "video" not in record:
            raise UserError(f"{where}: the pendulum video's record lacks its settings ('video')")
        return dict(record["video"])

    @staticmethod
    def data(**settings: Any) -> SequenceData:
        """:func:`~latent_sindy.worlds.pendulum.video.pendulum_video` (same arguments)."""
        from latent_sindy.worlds.pendulum.video import pendulum_video

        return pendulum_video(**settings)


WORLD = PendulumPlugin()
VIDEO = PendulumVideo()
