"""The settings of the gym world: which environment, and how its frames are seen.

Checked without gymnasium (the id against gymnasium's registry only when the environment is
made, :mod:`.env`), so the world's record reads back anywhere.

    >>> GymConfig(id="Pendulum-v1", size=32).channels     # two RGB frames stacked
    6
"""

from __future__ import annotations

from dataclasses import dataclass

from latent_sindy.errors import UserError

__all__ = ["GymConfig"]


@dataclass(frozen=True)
class GymConfig:
    """Settings of the gym world."""

    id: str = "Pendulum-v1"
    """The environment's id in gymnasium's registry (``Pendulum-v1``, ``MountainCarContinuous-v0``,
    ...); ``module:Name-v0`` imports ``module`` first, where a user's own environment
    registers itself."""
    size: int = 64
    """Side of the square image in pixels (each rendered frame resized to it, by area)."""
    frames: int = 2
    """Frames stacked as channels, oldest first (2: a first-order latent sees velocity)."""
    action_repeat: int = 1
    """Environment steps per action, the rewards summed over them."""
    gray: bool = False
    """One gray channel per frame (0.2989 R + 0.587 G + 0.114 B) instead of three colours."""

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id.strip():
            raise UserError(f"gym id {self.id!r}: name a registered environment, e.g. "
                            "Pendulum-v1")
        for name, low, high in (("size", 8, 512), ("frames", 1, 16), ("action_repeat", 1, 100)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise UserError(f"gym {name} {value!r}: use an integer in {low}..{high}")
        if not isinstance(self.gray, bool):
            raise UserError(f"gym gray {self.gray!r}: use true or false")

    @property
    def channels(self) -> int:
        """Channels of one observation: frames × (1 gray or 3 colours)."""
        return self.frames * (1 if self.gray else 3)
