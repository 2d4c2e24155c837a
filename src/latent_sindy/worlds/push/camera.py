"""The overhead camera's geometry: world points to image pixels and back.

PyBullet's own view and projection matrices of a :class:`~latent_sindy.worlds.push.config.
CameraConfig` (pure functions: no physics client), so the mapping is the one the renderer
uses. Pixel coordinates are (row, col), pixel (0, 0) the top-left one, each pixel at its
integer coordinates. TinyRenderer samples pixel (row, col) at viewport point (col, S - 1 -
row), not at the pixel's centre (col + 1/2, S - 1/2 - row): measured, the block's top face
rendered at 32 and at 128 pixels lies half a pixel from where the centre convention puts it,
in both axes, and where this one puts it (tests/test_probe.py).

    >>> cam = Camera(PushEnvConfig())
    >>> rc = cam.world_to_pixel([0.5, 0.1, 0.0])
    >>> cam.pixel_to_world(rc, height=0.0)  # back on the table: [0.5, 0.1]
"""

from __future__ import annotations

import math

import numpy as np

from latent_sindy.worlds.push._bullet import pybullet as pb
from latent_sindy.worlds.push.config import PushEnvConfig

__all__ = ["Camera", "moment_frame"]


class Camera:
    """The observation camera of one world (its config's camera and image size)."""

    def __init__(self, cfg: PushEnvConfig) -> None:
        c = cfg.camera
        self.size = cfg.image_size
        self.target = tuple(c.target)
        #: PyBullet's view and projection matrices (column-major 16-tuples), for rendering
        self.view = pb.computeViewMatrixFromYawPitchRoll(c.target, c.distance, c.yaw, c.pitch,
                                                         0.0, 2)
        self.projection = pb.computeProjectionMatrixFOV(c.fov, 1.0, c.near, c.far)
        view = np.array(self.view).reshape(4, 4).T
        proj = np.array(self.projection).reshape(4, 4).T
        self._m = proj @ view  # world -> clip
        self._inv = np.linalg.inv(self._m)

    def world_to_pixel(self, xyz) -> np.ndarray:
        """World points (..., 3) -> (row, col) (..., 2), float pixel units."""
        p = np.asarray(xyz, dtype=float)
        clip = np.concatenate([p, np.ones((*p.shape[:-1], 1))], -1) @ self._m.T
        ndc = clip[..., :3] / clip[..., 3:]
        s = self.size
        return np.stack([(1 - ndc[..., 1]) / 2 * s - 1, (ndc[..., 0] + 1) / 2 * s], -1)

    def angle_map(self, height: float = 0.0) -> tuple[int, float]:
        """How the image turns world directions, at the workspace's centre (the camera's
        target): a direction at world angle β has the image angle γ0 + sense · β, in image
        axes x to the right (columns) and y down (rows). Returns (sense, γ0): sense -1 where
        the image mirrors the world (its axes swap the world's)."""
        x, y, _ = self.target
        step = 0.01
        rc0 = self.world_to_pixel((x, y, height))
        jx = self.world_to_pixel((x + step, y, height)) - rc0  # (row, col) per world x
        jy = self.world_to_pixel((x, y + step, height)) - rc0
        # image (col, row) vectors of the world axes
        ex, ey = np.array([jx[1], jx[0]]), np.array([jy[1], jy[0]])
        sense = 1 if ex[0] * ey[1] - ex[1] * ey[0] > 0 else -1
        return sense, float(math.atan2(ex[1], ex[0]))

    def pixel_to_world(self, rc, height: float) -> np.ndarray:
        """(row, col) (..., 2) -> (x, y) (..., 2) where each pixel's ray meets the plane
        z = ``height`` (m)."""
        rc = np.asarray(rc, dtype=float)
        s = self.size
        nx = rc[..., 1] * 2 / s - 1
        ny = 1 - (rc[..., 0] + 1) * 2 / s
        ends = []
        for nz in (-1.0, 1.0):  # the near and far plane
            ndc = np.stack([nx, ny, np.full_like(nx, nz), np.ones_like(nx)], -1)
            w = ndc @ self._inv.T
            ends.append(w[..., :3] / w[..., 3:])
        a, b = ends
        t = (height - a[..., 2]) / (b[..., 2] - a[..., 2])
        return (a + t[..., None] * (b - a))[..., :2]


def moment_frame(cfg: PushEnvConfig) -> tuple[int, float]:
    """(sense, offset) that map the angle nφ of the n-th angular moment of ``cfg``'s images
    (image axes: x to the right, y down; n = 2π / the block's visible period) to the world's
    fθ = sense · nφ + offset: what the frame library needs of the moments latent
    (the frame library's ``sense`` and ``offset`` options). The camera maps a world angle β to the
    image angle γ0 + sense · β (:meth:`Camera.angle_map`), and a square's 4th moment peaks at
    its corners, π / n off its faces, so nφ = n (γ0 + sense θ) + π."""
    n = 2 * math.pi / cfg.angle_period
    if n < 3:
        raise ValueError(f"moment_frame needs a block that looks alike at least 3 times a turn "
                         f"(its n-th moment then peaks at its corners), not {n:g}")
    sense, gamma0 = Camera(cfg).angle_map()
    return sense, math.remainder(-sense * (math.pi + n * gamma0), 2 * math.pi)
