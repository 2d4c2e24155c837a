"""The settings of the DeepMind Control world: which task, and how the camera sees it.

Checked without dm_control (the task's name against the suite's list only once the suite is
loaded, :mod:`.suite`), so the world's record reads back anywhere.

    >>> DmcConfig(task="reacher-easy", size=32).action_repeat    # PlaNet's repeat for reacher
    4
"""

from __future__ import annotations

from dataclasses import dataclass

from latent_sindy.errors import UserError

__all__ = ["ACTION_REPEAT", "CAMERA", "DmcConfig"]

#: Actions repeated per domain, as PlaNet (Hafner et al. 2019) used them for the tasks of its
#: benchmark; 4 for every other domain (PlaNet's most common value).
ACTION_REPEAT = {"cartpole": 8, "reacher": 4, "cheetah": 4, "ball_in_cup": 4, "finger": 2,
                 "walker": 2}
DEFAULT_REPEAT = 4
#: The camera per domain (PlaNet's: the quadruped's third, camera 0 elsewhere).
CAMERA = {"quadruped": 2}


@dataclass(frozen=True)
class DmcConfig:
    """Settings of the DeepMind Control world."""

    task: str = "cartpole-swingup"
    """The suite's domain and task as DOMAIN-TASK (e.g. cartpole-swingup, reacher-easy,
    ball_in_cup-catch, cheetah-run)."""
    size: int = 64
    """Side of the square camera image in pixels (PlaNet's 64)."""
    frames: int = 2
    """Frames stacked as channels, oldest first (2: a first-order latent sees velocity)."""
    action_repeat: int | None = None
    """Physics control steps per action (rewards summed over them); None: PlaNet's value for
    the domain (cartpole 8, finger and walker 2, 4 elsewhere)."""
    gray: bool = False
    """One gray channel per frame (0.2989 R + 0.587 G + 0.114 B) instead of three colours."""
    camera: int | None = None
    """The camera's index in the domain's model; None: PlaNet's (2 for quadruped, else 0)."""

    def __post_init__(self) -> None:
        domain, sep, task = self.task.partition("-") if isinstance(self.task, str) else ("",) * 3
        if not (sep and domain and task):
            raise UserError(f"dmc task {self.task!r}: write it as DOMAIN-TASK, e.g. "
                            "cartpole-swingup or reacher-easy")
        for name, low, high in (("size", 8, 512), ("frames", 1, 16)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise UserError(f"dmc {name} {value!r}: use an integer in {low}..{high}")
        repeat = self.action_repeat
        if repeat is None:  # resolved once, so the record names the number used
            object.__setattr__(self, "action_repeat", ACTION_REPEAT.get(domain, DEFAULT_REPEAT))
        elif isinstance(repeat, bool) or not isinstance(repeat, int) or not 1 <= repeat <= 100:
            raise UserError(f"dmc action_repeat {repeat!r}: use an integer in 1..100")
        if self.camera is None:
            object.__setattr__(self, "camera", CAMERA.get(domain, 0))
        elif isinstance(self.camera, bool) or not isinstance(self.camera, int) \
                or self.camera < 0:
            raise UserError(f"dmc camera {self.camera!r}: use a camera index (0, 1, ...)")

    @property
    def domain(self) -> str:
        return self.task.partition("-")[0]

    @property
    def task_name(self) -> str:
        return self.task.partition("-")[2]

    @property
    def channels(self) -> int:
        """Channels of one observation: frames × (1 gray or 3 colours)."""
        return self.frames * (1 if self.gray else 3)
