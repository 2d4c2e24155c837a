"""Settings and fixed facts of the planar pushing world.

Everything that changes what the camera sees or how the block moves lives in
:class:`PushEnvConfig`, so a data file can record it and a later command can rebuild the
same world from that record alone.

    >>> cfg = PushEnvConfig(channels=3)
    >>> cfg.action_dim
    3
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from latent_sindy.errors import UserError

#: The paper's task: start and goal block poses (x, y, theta).
PAPER_START = (0.4, 0.0, 0.2 * math.pi)
PAPER_GOAL = (0.7, 0.0, 0.0)

BLOCK_SIZE = (0.1, 0.1, 0.05)  # metres: length (block x), width (block y), height
MAX_PUSH = 0.1  # metres: push length at ell = 1
CONTACT_SPAN = 0.95  # p = +-1 reaches this fraction of the half-width
#: Largest camera image side: TinyRenderer's frame buffers grow with its square.
MAX_IMAGE_SIZE = 512
#: The action box of u = [p, phi, ell].
ACTION_LOW = (-1.0, -math.pi / 2, 0.0)
ACTION_HIGH = (1.0, math.pi / 2, 1.0)


@dataclass(frozen=True)
class CameraConfig:
    """The overhead camera (the course's settings)."""

    target: tuple[float, float, float] = (0.595, 0.0, 0.01)
    """Point the camera looks at (m)."""
    distance: float = 0.7
    """Distance from the target (m)."""
    yaw: float = 90.0
    """Degrees."""
    pitch: float = -95.0
    """Degrees."""
    fov: float = 60.0
    """Vertical field of view in degrees."""
    near: float = 0.01
    far: float = 100.0


@dataclass(frozen=True)
class PushEnvConfig:
    """Everything that defines the pushing world and its observations."""

    image_size: int = 32
    """Observation side length in pixels."""
    channels: int = 1
    """1: grayscale (0.2989 R + 0.587 G + 0.114 B); 3: RGB."""
    block_mass: float = 10.0
    """kg (the course's value)."""
    block_friction: float = 0.1
    """Lateral friction coefficient of the block (the course's value)."""
    workspace_low: tuple[float, float, float] = (0.35, -0.35, -math.pi / 2)
    """Lower corner (x, y, theta) of the region start and goal poses are sampled from."""
    workspace_high: tuple[float, float, float] = (0.7, 0.35, math.pi / 2)
    """Upper corner (x, y, theta) of the sampling region."""
    bounds_low: tuple[float, float] = (0.25, -0.4)
    """The episode ends when the block's (x, y) leaves [bounds_low, bounds_high]: the part
    of the table the camera sees (|y| < 0.4) and the arm reaches (x < 0.8). It is wider than
    the sampling region so that goals on its edge (the paper's x = 0.7) stay reachable."""
    bounds_high: tuple[float, float] = (0.8, 0.4)
    """Upper corner (x, y) of the in-bounds region."""
    success_distance: float = 0.1
    """Course success criterion: block position within this distance of the goal (m)."""
    success_angle_deg: float | None = None
    """Course criterion ignores orientation (None); set degrees to also require it."""
    strict_distance: float = 0.02
    """Strict criterion: position within this distance (m) ..."""
    strict_angle_deg: float = 10.0
    """... and orientation within this many degrees."""
    render_size: int = 256
    """Side of the frame `render()` returns for people."""
    camera: CameraConfig = field(default_factory=CameraConfig)

    def __post_init__(self) -> None:
        if not 8 <= self.image_size <= MAX_IMAGE_SIZE:
            raise UserError(f"--image-size {self.image_size}: use 8 to {MAX_IMAGE_SIZE} pixels")
        if not 16 <= self.render_size <= 4 * MAX_IMAGE_SIZE:
            raise UserError(f"--render-size {self.render_size}: use 16 to "
                            f"{4 * MAX_IMAGE_SIZE} pixels")
        if self.channels not in (1, 3):
            raise UserError(f"channels={self.channels} is not supported: use 1 (gray) or 3 (RGB)")
        if self.block_mass <= 0 or self.block_friction < 0:
            raise UserError("block_mass must be > 0 and block_friction >= 0")
        for lo, hi in zip(self.workspace_low, self.workspace_high, strict=True):
            if not lo < hi:
                raise UserError(f"workspace_low {self.workspace_low} must lie below workspace_high")
        for lo, hi, wlo, whi in zip(self.bounds_low, self.bounds_high, self.workspace_low,
                                    self.workspace_high, strict=False):
            if not lo <= wlo < whi <= hi:
                raise UserError(f"bounds {self.bounds_low}..{self.bounds_high} must contain the "
                                f"workspace {self.workspace_low}..{self.workspace_high}")
        if self.success_distance <= 0 or self.strict_distance <= 0:
            raise UserError("success distances must be positive")

    @property
    def action_low(self) -> tuple[float, ...]:
        """Lower corner of the action box."""
        return ACTION_LOW

    @property
    def action_high(self) -> tuple[float, ...]:
        """Upper corner of the action box."""
        return ACTION_HIGH

    @property
    def action_dim(self) -> int:
        """Action size nu."""
        return len(ACTION_LOW)

    @property
    def action_names(self) -> tuple[str, ...]:
        return ("p", "phi", "ell")

    @property
    def angle_period(self) -> float:
        """The block's visible rotational symmetry (a uniform square: π/2)."""
        return math.pi / 2
