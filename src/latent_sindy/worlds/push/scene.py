"""The pushing world's scene without the arm: table, block, their looks, and the camera view.

:func:`add_table_and_block` builds the table and the block in a PyBullet client, the same in
the simulation and in the camera world; :class:`CameraView` is the camera world (table and
block only) that renders every observation, cheap to build alone.

    python -c "from latent_sindy.worlds.push.scene import CameraView; \
print(CameraView().observe((0.5, 0.0, 0.3)).shape)"
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from latent_sindy.worlds.push._bullet import BulletClient, quiet_c_output
from latent_sindy.worlds.push._bullet import pybullet as pb
from latent_sindy.worlds.push.camera import Camera
from latent_sindy.worlds.push.config import BLOCK_SIZE, PushEnvConfig

__all__ = ["CameraView", "add_table_and_block", "place", "yaw_quaternion"]

TABLE_HALF = (0.6, 0.6, 0.02)
TABLE_CENTRE = (0.55, 0.0, -0.02)
TABLE_RGBA = (0.82, 0.80, 0.74, 1.0)
BLOCK_RGBA = (0.30, 0.45, 0.85, 1.0)
MARK_RGBA = (0.55, 0.10, 0.10, 1.0)  # the marked block's +x half: darker in grayscale too
GOAL_RGBA = (0.10, 0.90, 0.10, 0.4)
PARKED = (0.0, 0.0, -5.0)  # far below the table: out of every view


def yaw_quaternion(theta: float) -> list[float]:
    """The quaternion (x, y, z, w) of a turn by `theta` about the vertical."""
    return [0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2)]


def add_table_and_block(c: BulletClient, cfg: PushEnvConfig) -> int:
    """Table (top at z = 0) and block; returns the block's body id."""
    c.createMultiBody(
        0,
        c.createCollisionShape(pb.GEOM_BOX, halfExtents=TABLE_HALF),
        c.createVisualShape(pb.GEOM_BOX, halfExtents=TABLE_HALF, rgbaColor=TABLE_RGBA),
        basePosition=TABLE_CENTRE,
    )
    half = [s / 2 for s in BLOCK_SIZE]
    if cfg.block_look == "marked":
        # two half-blocks side by side: the +x half light, so a quarter turn shows
        quarter = [half[0] / 2, half[1], half[2]]
        visual = c.createVisualShapeArray(
            [pb.GEOM_BOX, pb.GEOM_BOX], halfExtents=[quarter, quarter],
            visualFramePositions=[[-quarter[0], 0, 0], [quarter[0], 0, 0]],
            rgbaColors=[BLOCK_RGBA, MARK_RGBA])
    else:
        visual = c.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=BLOCK_RGBA)
    block = c.createMultiBody(
        cfg.block_mass,
        c.createCollisionShape(pb.GEOM_BOX, halfExtents=half),
        visual,
        basePosition=[0.5, 0.0, half[2]],
    )
    c.changeDynamics(block, -1, lateralFriction=cfg.block_friction)
    return block


def place(c: BulletClient, body: int, pose) -> None:
    """Put `body` at rest on the table at planar pose (x, y, theta)."""
    x, y, th = (float(v) for v in pose)
    c.resetBasePositionAndOrientation(body, [x, y, BLOCK_SIZE[2] / 2], yaw_quaternion(th))
    c.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])


class CameraView:
    """The camera world: table and block only, and the observation camera.

    What :meth:`~latent_sindy.worlds.push.world.PushWorld.observe` renders, and cheap to
    build alone (no arm to load): e.g. for images of the block at given poses.
    """

    def __init__(self, cfg: PushEnvConfig | None = None) -> None:
        self.cfg = cfg or PushEnvConfig()
        with quiet_c_output():
            self.client = BulletClient(connection_mode=pb.DIRECT)
        self.block = add_table_and_block(self.client, self.cfg)
        self.camera = Camera(self.cfg)

    def observe(self, pose) -> np.ndarray:
        """The camera's image (C, S, S) uint8 with the block at `pose` (x, y, theta)."""
        place(self.client, self.block, pose)
        return self.to_obs(self.render(self.client, self.cfg.image_size))

    def render(self, c: BulletClient, size: int) -> np.ndarray:
        """An (S, S, 3) RGB frame of client `c`'s scene through the camera."""
        _, _, rgba, _, _ = c.getCameraImage(
            size, size, self.camera.view, self.camera.projection,
            renderer=pb.ER_TINY_RENDERER, shadow=0,
            flags=pb.ER_NO_SEGMENTATION_MASK)
        return np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4)[..., :3]

    def to_obs(self, rgb: np.ndarray) -> np.ndarray:
        """RGB frame -> observation (C, S, S) uint8 (grayscale unless the config says 3)."""
        if self.cfg.channels == 3:
            return np.ascontiguousarray(rgb.transpose(2, 0, 1))
        gray = rgb.astype(np.float32) @ np.array([0.2989, 0.587, 0.114], dtype=np.float32)
        return np.clip(np.rint(gray), 0, 255).astype(np.uint8)[None]

    def close(self) -> None:
        with quiet_c_output(), contextlib.suppress(pb.error):
            self.client.disconnect()
