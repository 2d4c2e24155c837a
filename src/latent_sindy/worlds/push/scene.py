"""The pushing world's scene without the arm: table, block, their looks, and the camera view.

:func:`add_table_and_block` builds the table and the block in a PyBullet client, the same in
the simulation and in the camera world; :class:`CameraView` is the camera world (table and
block only) that renders every observation, cheap to build alone.

The textured world's parts are drawn by TinyRenderer itself, so a picture is what a camera
would see: the wood-grain table is a textured quad on the table's top face (one pattern, from
a fixed seed), the episode's light is getCameraImage's light settings (:class:`Light`), and
the distractor a visual-only cylinder (no collision shape: nothing can touch it). An
episode's :class:`Look` (light and distractor position) is drawn from its seed
(:func:`draw_look`); the physics never sees any of it.

    python -c "from latent_sindy.worlds.push.scene import CameraView; \
print(CameraView().observe((0.5, 0.0, 0.3)).shape)"
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import struct
import tempfile
import zlib
from dataclasses import dataclass

import numpy as np

from latent_sindy.worlds.push._bullet import BulletClient, quiet_c_output
from latent_sindy.worlds.push._bullet import pybullet as pb
from latent_sindy.worlds.push.camera import Camera
from latent_sindy.worlds.push.config import BLOCK_SIZE, PushEnvConfig

__all__ = ["CameraView", "Light", "Look", "add_distractor", "add_table_and_block", "draw_look",
           "place", "place_distractor", "table_texture", "yaw_quaternion"]

TABLE_HALF = (0.6, 0.6, 0.02)
TABLE_CENTRE = (0.55, 0.0, -0.02)
TABLE_RGBA = (0.82, 0.80, 0.74, 1.0)
BLOCK_RGBA = (0.30, 0.45, 0.85, 1.0)
MARK_RGBA = (0.55, 0.10, 0.10, 1.0)  # the marked block's +x half: darker in grayscale too
GOAL_RGBA = (0.10, 0.90, 0.10, 0.4)
PARKED = (0.0, 0.0, -5.0)  # far below the table: out of every view
WOOD_RGB = (0.93, 0.83, 0.67)  # the lightest wood: in grayscale as light as the plain table
TEXTURE_SEED = 7  # the textured table is one pattern, the same in every run
TEXTURE_SIDE = 256  # texels per table side: 4.7 mm each, finer than a 32x32 pixel (2.5 cm)
PLANK_WIDTH = 0.15  # m, across the planks (world y); they run along world x
DISTRACTOR_RGBA = (0.45, 0.12, 0.10, 1.0)  # dark in grayscale, like the block
DISTRACTOR_SIZE = (0.03, 0.04)  # radius, height (m): about 2x2 pixels at 32x32
#: Where the distractor stands (x, y low and high corners, m): in view (rows 27-29 of 32),
#: beyond any block the episode keeps (x < 0.8 plus its half-diagonal 0.07).
DISTRACTOR_REGION = ((0.92, -0.3), (0.97, 0.3))


@dataclass(frozen=True)
class Light:
    """The light of one episode: TinyRenderer's light settings (see getCameraImage)."""

    direction: tuple[float, float, float] = (-50.0, 30.0, 100.0)
    """Towards the light (any length); the default is PyBullet's own."""
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """RGB gain: brightness times tint."""
    ambient: float = 0.6
    diffuse: float = 0.35

    def keywords(self) -> dict:
        """getCameraImage's keywords; all of them, since TinyRenderer keeps the last ones."""
        return {"lightDirection": list(self.direction), "lightColor": list(self.color),
                "lightDistance": 2.0, "lightAmbientCoeff": self.ambient,
                "lightDiffuseCoeff": self.diffuse, "lightSpecularCoeff": 0.05}


@dataclass(frozen=True)
class Look:
    """What an episode looks like beyond the config: its light (None: PyBullet's default,
    never set) and where the distractor stands (x, y), if the world shows one."""

    light: Light | None = None
    distractor: tuple[float, float] = (0.945, 0.0)

    @classmethod
    def neutral(cls, cfg: PushEnvConfig) -> Look:
        """The look before any episode draws one: PyBullet's default light."""
        return cls(light=Light() if cfg.lighting == "varied" else None)


def draw_look(cfg: PushEnvConfig, seed: int) -> Look:
    """Episode look of world ``cfg`` drawn from ``seed``: the same seed, the same look.

    Every value is drawn whatever the config uses, so the distractor stands in the same
    place with or without varied lighting.
    """
    rng = np.random.default_rng(seed)
    azimuth = rng.uniform(0.0, 2 * math.pi)
    elevation = rng.uniform(math.radians(30), math.radians(90))
    brightness = rng.uniform(0.8, 1.05)
    tint = rng.uniform(0.9, 1.1, 3)
    ambient, diffuse = rng.uniform(0.45, 0.65), rng.uniform(0.25, 0.4)
    spot = rng.uniform(*DISTRACTOR_REGION)
    light = Light(
        direction=(math.cos(elevation) * math.cos(azimuth),
                   math.cos(elevation) * math.sin(azimuth), math.sin(elevation)),
        color=tuple(float(v) for v in brightness * tint), ambient=float(ambient),
        diffuse=float(diffuse))
    return Look(light=light if cfg.lighting == "varied" else None,
                distractor=(float(spot[0]), float(spot[1])))


@functools.cache
def table_texture() -> np.ndarray:
    """The textured table's pattern (S, S, 3) uint8: texel row i, column j lies at world
    (x, y) = table centre + (-hx + (j + 1/2) 2hx / S, hy - (i + 1/2) 2hy / S).

    Planks along x of varying tone, dark seams between them, grain lines bent by smooth
    noise, broad blotches and a few dark knots, all from :data:`TEXTURE_SEED`.
    """
    rng = np.random.default_rng(TEXTURE_SEED)
    n, (hx, hy, _) = TEXTURE_SIDE, TABLE_HALF
    x = -hx + (np.arange(n) + 0.5) * 2 * hx / n
    y = hy - (np.arange(n) + 0.5) * 2 * hy / n
    X, Y = np.meshgrid(x, y)  # (S, S) m from the table's centre

    def smooth(waves: int, shortest: float, longest: float) -> np.ndarray:
        """Sum of plane waves, about unit amplitude."""
        out = np.zeros_like(X)
        for _ in range(waves):
            k = 2 * math.pi / rng.uniform(shortest, longest)
            a = rng.uniform(0, 2 * math.pi)
            out += np.sin(k * (X * math.cos(a) + Y * math.sin(a)) + rng.uniform(0, 2 * math.pi))
        return out / math.sqrt(waves / 2)

    plank = np.floor((Y + hy) / PLANK_WIDTH).astype(int)
    tone = rng.uniform(0.84, 1.0, plank.max() + 1)[plank]
    grain = 0.5 + 0.5 * np.sin(2 * math.pi * (Y / 0.03 + 0.8 * smooth(5, 0.2, 0.6)) + plank)
    shade = tone * (1 - 0.12 * grain) * (1 + 0.07 * smooth(6, 0.08, 0.3))
    seam = np.abs((Y + hy) / PLANK_WIDTH - np.round((Y + hy) / PLANK_WIDTH)) * PLANK_WIDTH
    shade = np.where(seam < 0.006, 0.55 * shade, shade)
    for _ in range(6):  # knots: dark ellipses a few cm across
        cx, cy = rng.uniform(-hx, hx), rng.uniform(-hy, hy)
        rx, ry = rng.uniform(0.025, 0.045), rng.uniform(0.012, 0.025)
        r2 = ((X - cx) / rx) ** 2 + ((Y - cy) / ry) ** 2
        shade = shade * (1 - 0.45 * np.exp(-r2 * r2))
    rgb = np.clip(shade[..., None] * np.array(WOOD_RGB), 0, 1)
    return np.rint(255 * rgb).astype(np.uint8)


@functools.cache
def _table_png() -> bytes:
    return _png(table_texture())


def _png(rgb: np.ndarray) -> bytes:
    """A PNG file of an (H, W, 3) uint8 image (PyBullet loads textures from files)."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + row.tobytes() for row in rgb)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data)))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def _textured_top(c: BulletClient) -> int:
    """The table's visual shape in the textured world: its top face, wood-grain textured
    (the sides are never in view)."""
    hx, hy, hz = TABLE_HALF
    return c.createVisualShape(
        pb.GEOM_MESH, vertices=[[-hx, -hy, hz], [hx, -hy, hz], [hx, hy, hz], [-hx, hy, hz]],
        indices=[0, 1, 2, 0, 2, 3], uvs=[[0, 0], [1, 0], [1, 1], [0, 1]],
        normals=[[0, 0, 1]] * 4, rgbaColor=[1, 1, 1, 1])


def _load_table_texture(c: BulletClient) -> int:
    """Load :func:`table_texture` into client ``c``; returns the texture's id."""
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "table.png")
        with open(path, "wb") as f:
            f.write(_table_png())
        return c.loadTexture(path)


def yaw_quaternion(theta: float) -> list[float]:
    """The quaternion (x, y, z, w) of a turn by `theta` about the vertical."""
    return [0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2)]


def add_table_and_block(c: BulletClient, cfg: PushEnvConfig) -> int:
    """Table (top at z = 0) and block; returns the block's body id."""
    textured = cfg.table_look == "textured"
    table = c.createMultiBody(
        0,
        c.createCollisionShape(pb.GEOM_BOX, halfExtents=TABLE_HALF),
        _textured_top(c) if textured else
        c.createVisualShape(pb.GEOM_BOX, halfExtents=TABLE_HALF, rgbaColor=TABLE_RGBA),
        basePosition=TABLE_CENTRE,
    )
    if textured:
        c.changeVisualShape(table, -1, textureUniqueId=_load_table_texture(c))
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


def add_distractor(c: BulletClient) -> int:
    """The distractor: a visual-only cylinder (nothing collides with it), parked out of
    view until :func:`place_distractor` puts it on the table."""
    radius, height = DISTRACTOR_SIZE
    return c.createMultiBody(
        0, -1, c.createVisualShape(pb.GEOM_CYLINDER, radius=radius, length=height,
                                   rgbaColor=DISTRACTOR_RGBA), basePosition=PARKED)


def place_distractor(c: BulletClient, body: int, xy) -> None:
    """Stand the distractor at (x, y) on the table."""
    c.resetBasePositionAndOrientation(body, [*xy, DISTRACTOR_SIZE[1] / 2], [0, 0, 0, 1])


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
        self.distractor = add_distractor(self.client) if self.cfg.distractor else None
        self.camera = Camera(self.cfg)
        self.look = Look.neutral(self.cfg)
        self._light: dict = {}
        self.set_look(self.look)

    def set_look(self, look: Look) -> None:
        """Show ``look`` (an episode's light and distractor) from now on."""
        self.look = look
        self._light = look.light.keywords() if look.light is not None else {}
        if self.distractor is not None:
            place_distractor(self.client, self.distractor, look.distractor)

    def observe(self, pose) -> np.ndarray:
        """The camera's image (C, S, S) uint8 with the block at `pose` (x, y, theta)."""
        place(self.client, self.block, pose)
        return self.to_obs(self.render(self.client, self.cfg.image_size))

    def render(self, c: BulletClient, size: int) -> np.ndarray:
        """An (S, S, 3) RGB frame of client `c`'s scene through the camera."""
        _, _, rgba, _, _ = c.getCameraImage(
            size, size, self.camera.view, self.camera.projection,
            renderer=pb.ER_TINY_RENDERER, shadow=0,
            flags=pb.ER_NO_SEGMENTATION_MASK, **self._light)
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
