"""Settings and fixed facts of the planar pushing world.

Everything that changes what the camera sees or how the block moves lives in
:class:`PushEnvConfig`, so a data file can record it and a later command can rebuild the
same world from that record alone. The config also owns the action box
(:attr:`PushEnvConfig.action_low` / ``action_high`` / ``action_dim`` / ``action_names``) and
the block's visible rotational symmetry (:attr:`PushEnvConfig.angle_period`).

Named worlds (:data:`ENV_PRESETS`, :meth:`PushEnvConfig.named`):

* ``"symmetric"`` (the default): u = [p, psi, ell] with psi the push direction as a *world*
  angle in [-pi, pi]; the pushed face is the one whose outward normal is most opposite to
  psi, p the contact offset along that face. The uniform square block looks the same at
  theta and theta + pi/2, and so does every push: the same image and action always give the
  same next image, and every direction is available, so goals behind the block need no
  turning first. ``angle_period`` = pi/2.
* ``"paper"``: the course's world, for reproducing the paper's Table I as defined:
  u = [p, phi, ell] with phi relative to the block's x axis within +-pi/2, always from the
  block's -x face.
* ``"marked"``: the paper's push, but the block's +x half is painted dark red, so its
  orientation is visible over a whole turn (``angle_period`` = 2 pi).
* ``"textured"``: the symmetric world's block and pushes (the same poses for the same seed
  and actions) seen where hand-made image features break: a wood-grain table (one fixed
  pattern: planks, seams, knots), a light drawn anew each episode from its seed (direction,
  brightness, tint, ambient and diffuse shares), and a small dark cylinder, a distractor
  that stands each episode somewhere in a strip beyond the block's reach (x in 0.92..0.97 m)
  and touches nothing. A per-pixel median background then no longer isolates the block:
  measured by ``benchmarks/textured_world.py`` (400 poses, grayscale), the moments encoder
  reads the block's position to 0.44 cm and its orientation to 4.2 degrees (mean errors) in
  the symmetric world, to 16 cm and 22 degrees (chance: 22.5) here; the table alone costs
  little (0.69 cm, 5.5 degrees), the light alone or the distractor alone breaks it.

Why "symmetric" is the default, measured by the retired ``benchmarks/world_designs.py``
(docs/notes/2026-12-06-benchmarks-retired.md):
in the symmetric world 0 of 30 look-alike pairs pushed alike gave different next images
(paper: 27 of 30), 300 of 300 random pushes executed in every direction (paper and marked:
90 %, worst pushing towards the base), and MPPI with a perfect-information reference model
(poses as far as images show them) reached 40 of 40 random goals (marked: 24, paper: 12).
The marked block removes the ambiguity but keeps the paper's reach and the need to turn
the block before pushing it back, and its mark is two pixels at 32x32.

    >>> cfg = PushEnvConfig(channels=3)
    >>> cfg.action_dim
    3
    >>> PushEnvConfig.named("paper").action_names
    ('p', 'phi', 'ell')
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Literal

from latent_sindy.errors import UserError

#: The paper's task: start and goal block poses (x, y, theta).
PAPER_START = (0.4, 0.0, 0.2 * math.pi)
PAPER_GOAL = (0.7, 0.0, 0.0)

BLOCK_SIZE = (0.1, 0.1, 0.05)  # metres: length (block x), width (block y), height
MAX_PUSH = 0.1  # metres: push length at ell = 1
CONTACT_SPAN = 0.95  # p = +-1 reaches this fraction of the half-width
#: Largest camera image side: TinyRenderer's frame buffers grow with its square.
MAX_IMAGE_SIZE = 512
#: The paper world's action box of u = [p, phi, ell]. Kept for code that predates
#: :attr:`PushEnvConfig.action_low`; new code reads the box from the config.
ACTION_LOW = (-1.0, -math.pi / 2, 0.0)
ACTION_HIGH = (1.0, math.pi / 2, 1.0)
#: The symmetric world's box of u = [p, psi, ell]: psi is any world direction.
SYMMETRIC_ACTION_LOW = (-1.0, -math.pi, 0.0)
SYMMETRIC_ACTION_HIGH = (1.0, math.pi, 1.0)
PUSH_STYLES = ("symmetric", "paper")
BLOCK_LOOKS = ("uniform", "marked")
TABLE_LOOKS = ("plain", "textured")
LIGHTINGS = ("fixed", "varied")


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
    push: Literal["symmetric", "paper"] = "symmetric"
    """How u = [p, angle, ell] becomes a push. "symmetric": angle psi is a world direction
    (any), pushed from the face whose outward normal is most opposite to it; "paper": angle
    phi is relative to the block's x axis (within +-pi/2), always from its -x face."""
    block_look: Literal["uniform", "marked"] = "uniform"
    """"uniform": one colour (the block looks alike every quarter turn); "marked": the +x
    half is dark red, so its orientation shows over a whole turn."""
    table_look: Literal["plain", "textured"] = "plain"
    """"plain": one colour; "textured": a fixed wood-grain pattern (planks, seams, knots)."""
    lighting: Literal["fixed", "varied"] = "fixed"
    """"fixed": PyBullet's default light; "varied": a light drawn anew each episode from the
    episode's seed (direction, brightness, tint, ambient and diffuse shares)."""
    distractor: bool = False
    """Show a small dark cylinder that nothing touches (no collision shape), each episode
    somewhere in a strip beyond the block's reach, drawn from the episode's seed."""
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
        for name, choices, what in (("push", PUSH_STYLES, "push style"),
                                    ("block_look", BLOCK_LOOKS, "block look"),
                                    ("table_look", TABLE_LOOKS, "table look"),
                                    ("lighting", LIGHTINGS, "lighting")):
            if getattr(self, name) not in choices:
                raise UserError(f"{name}={getattr(self, name)!r} is not a {what}: use one of "
                                f"{', '.join(choices)}")

    # ------------------------------------------------------------------ the action
    @property
    def action_low(self) -> tuple[float, ...]:
        """Lower corner of the action box."""
        return SYMMETRIC_ACTION_LOW if self.push == "symmetric" else ACTION_LOW

    @property
    def action_high(self) -> tuple[float, ...]:
        """Upper corner of the action box."""
        return SYMMETRIC_ACTION_HIGH if self.push == "symmetric" else ACTION_HIGH

    @property
    def action_dim(self) -> int:
        """Number of action components (nu)."""
        return len(self.action_low)

    @property
    def action_names(self) -> tuple[str, ...]:
        """Names of the action components, in order."""
        return ("p", "psi", "ell") if self.push == "symmetric" else ("p", "phi", "ell")

    @property
    def angle_period(self) -> float:
        """The block's visible rotational symmetry (rad): poses theta and theta + period look
        the same, so orientation errors are compared modulo it."""
        return 2 * math.pi if self.block_look == "marked" else math.pi / 2

    @property
    def varies_by_episode(self) -> bool:
        """Whether each episode draws its own look (light, distractor) from its seed."""
        return self.lighting == "varied" or self.distractor

    # ------------------------------------------------------------------ records
    @property
    def world_key(self) -> tuple:
        """What makes a named world what it is (push, block, table, light, distractor):
        equal for two configs of the same world whatever their image size or camera."""
        return (self.push, self.block_look, self.table_look, self.lighting, self.distractor)

    @property
    def world_name(self) -> str | None:
        """The named world of :data:`ENV_PRESETS` this one is (by :attr:`world_key`), if any."""
        return next((name for name, w in ENV_PRESETS.items()
                     if w.world_key == self.world_key), None)

    @classmethod
    def named(cls, name: str, **overrides) -> PushEnvConfig:
        """A named world of :data:`ENV_PRESETS`, with any fields overridden."""
        if name not in ENV_PRESETS:
            raise UserError(f"environment {name!r} is not a named world: use one of "
                            f"{', '.join(ENV_PRESETS)}")
        return dataclasses.replace(ENV_PRESETS[name], **overrides)

    @classmethod
    def from_record(cls, d: dict, where: str) -> PushEnvConfig:
        """Rebuild from a record (a data file's or run folder's JSON, ``configs.to_json``);
        ``where`` names it in errors."""
        from latent_sindy.configs import from_json

        if not isinstance(d, dict):
            raise UserError(f"{where}: expected a mapping of environment settings")
        return from_json(cls, d, where)


#: The named worlds (see the module docstring).
ENV_PRESETS: dict[str, PushEnvConfig] = {
    "symmetric": PushEnvConfig(push="symmetric"),
    "paper": PushEnvConfig(push="paper"),
    "marked": PushEnvConfig(push="paper", block_look="marked"),
    "textured": PushEnvConfig(push="symmetric", table_look="textured", lighting="varied",
                              distractor=True),
}

#: What each named world is, in a phrase (``--help``, the report).
WORLD_ABOUT: dict[str, str] = {
    "symmetric": "symmetric pushes: the push direction is a world angle, pushed from the face "
                 "most opposite to it",
    "paper": "the paper's world: pushes from the block's −x face, angle relative to its x axis",
    "marked": "the paper's push on a block whose +x half is marked",
    "textured": "the symmetric world's pushes on a wood-grain table, under a light drawn per "
                "episode, beside an untouchable distractor",
}
