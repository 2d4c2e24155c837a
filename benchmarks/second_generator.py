"""A second video generator, written apart from the family's, for the same ranges.

The estimator's default was chosen on :mod:`latent_sindy.worlds.pendulum.video_draws`.
A default that only works on that code's habits (its blob's profile, its starts, its
noise's scale, its float frames, its split) would fail on a video someone else renders.
This module renders the same three systems (a damped pendulum, a damped spring, two
pendulums side by side) within the same ranges (ω² in [0.3, 4], c/ω up to 0.3 and c up to
0.4, frames 24–80 px, 20–200 trajectories of 40–400 frames, dt 0.01–0.15 s with at least 8
frames a period, noise up to 2 % of the spread) but every choice its own way:

- pixel coordinates with rows downward, the blob exp(−d²/2σ²) with σ in pixels, its peak
  brightness drawn;
- starts by one of three styles: released from rest, kicked from hanging, or any energy
  below the top (the family draws the last only);
- the motion integrated by scipy's DOP853 at the frame times;
- noise as a share of the frames' range (max − min), not of their standard deviation;
- a textured background of random low-frequency waves;
- frames as uint8 in some draws without derivatives (a camera's video), else float64;
- no split in some draws (the library makes one), else 70/15/15 % at random;
- exact derivatives from the rendered frames' Taylor expansion in time (second-order
  differences of renderings at t ± h along the path's p, ṗ, p̈), not the chain rule.

``benchmarks/video_draws.py --generator second`` fits and judges these draws exactly as
the family's (the same literal default, the same criterion).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from latent_sindy.data.sequence import SequenceData
from latent_sindy.worlds.pendulum.video_draws import judge_equations, law_text, true_law

SYSTEMS = ("pendulum", "pendulum", "spring", "two_pendulums")
STYLES = ("rest", "kick", "energy")


@dataclass(frozen=True)
class SecondDraw:
    """One video of the second generator (every field drawn by :func:`second_draw`)."""

    system: str
    omega2: tuple[float, ...]
    damping: tuple[float, ...]
    size: int
    sigma: float
    """The blob's standard deviation in pixels."""
    peak: float
    pivot: tuple[tuple[float, float], ...]
    """Each blob's pivot (pendulum) or rest point (spring), (row, column) in pixels."""
    length: tuple[float, ...]
    """The pendulum's length, or the spring's pixels per unit of x, in pixels."""
    angle: tuple[float, ...]
    """The spring's line, radians from the columns' axis; unused by pendulums."""
    style: str
    trajectories: int
    frames: int
    dt: float
    noise: float
    texture: float
    exact: bool
    uint8: bool
    split: str
    """"none" (the library splits) or "random" (70/15/15 % drawn here)."""
    seed: int

    @property
    def latent_dim(self) -> int:
        return 2 if self.system == "two_pendulums" else 1

    def law(self) -> list[dict[str, float]]:
        return true_law(self.system, self.omega2, self.damping)

    def law_text(self) -> list[str]:
        return law_text(self.law())

    def judge(self, model: Any) -> dict[str, Any]:
        return judge_equations(self, model.get_feature_names(), model.coefficients())

    def shrunk(self, size: int, trajectories: int, frames: int) -> SecondDraw:
        """The same draw filmed smaller and shorter (the benchmark's smoke run)."""
        k = size / self.size
        return replace(self, size=size, sigma=max(1.0, self.sigma * k), trajectories=trajectories,
                       frames=frames, pivot=tuple((r * k, c * k) for r, c in self.pivot),
                       length=tuple(L * k for L in self.length))

    def to_dict(self) -> dict[str, Any]:
        return {"generator": "second", **asdict(self)}

    # ---------------------------------------------------------------- the motion
    def _starts(self, b: int, rng: np.random.Generator) -> np.ndarray:
        w2, n = self.omega2[b], self.trajectories
        w = math.sqrt(w2)
        if self.system == "spring":
            if self.style == "rest":
                return np.stack([rng.uniform(-1, 1, n), np.zeros(n)], 1)
            if self.style == "kick":
                return np.stack([np.zeros(n), rng.uniform(-w, w, n)], 1)
            a, ph = np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * math.pi, n)
            return np.stack([a * np.cos(ph), -a * w * np.sin(ph)], 1)
        if self.style == "rest":
            return np.stack([rng.uniform(-2.9, 2.9, n), np.zeros(n)], 1)
        if self.style == "kick":  # under the top: |v| < 2ω
            return np.stack([rng.normal(0, 0.1, n), rng.uniform(-1.95 * w, 1.95 * w, n)], 1)
        energy = rng.uniform(-1, 0.97, n) * w2  # v²/2 − ω² cos θ, below the separatrix
        th = np.empty(n)
        for k in range(n):  # a θ where the energy is reachable, then the speed from it
            th_max = math.acos(max(-1.0, min(1.0, -energy[k] / w2)))
            th[k] = rng.uniform(-th_max, th_max)
        v = np.sqrt(np.maximum(0.0, 2 * (energy + w2 * np.cos(th))))
        return np.stack([th, v * rng.choice([-1.0, 1.0], n)], 1)

    def motion(self) -> np.ndarray:
        """(N, F, blobs, 3): q, q̇, q̈ at the frames."""
        rng = np.random.default_rng(self.seed)
        t = np.arange(self.frames) * self.dt
        out = np.empty((self.trajectories, self.frames, self.latent_dim, 3))
        for b in range(self.latent_dim):
            w2, c = self.omega2[b], self.damping[b]
            spring = self.system == "spring"

            def f(_t, y, w2=w2, c=c, spring=spring):
                return [y[1], -w2 * (y[0] if spring else math.sin(y[0])) - c * y[1]]

            for i, y0 in enumerate(self._starts(b, rng)):
                sol = solve_ivp(f, (0, t[-1]), y0, method="DOP853", t_eval=t,
                                rtol=1e-10, atol=1e-12)
                q, v = sol.y
                out[i, :, b, 0], out[i, :, b, 1] = q, v
                out[i, :, b, 2] = -w2 * (q if spring else np.sin(q)) - c * v
        return out

    def _pixel_path(self, b: int, q: np.ndarray) -> tuple[np.ndarray, ...]:
        """Blob b's centre (row, col) and its first two time derivatives, (F, 2) each."""
        th, v, a = q[..., 0], q[..., 1], q[..., 2]
        r0, c0 = self.pivot[b]
        L = self.length[b]
        if self.system == "spring":
            d = np.array([-math.sin(self.angle[b]), math.cos(self.angle[b])])  # (row, col)
            return (np.array([r0, c0]) + L * th[:, None] * d, L * v[:, None] * d,
                    L * a[:, None] * d)
        # hanging down is +row; θ > 0 swings toward +col
        p = np.stack([r0 + L * np.cos(th), c0 + L * np.sin(th)], 1)
        dp = np.stack([-L * np.sin(th) * v, L * np.cos(th) * v], 1)
        ddp = np.stack([-L * (np.cos(th) * v ** 2 + np.sin(th) * a),
                        L * (np.cos(th) * a - np.sin(th) * v ** 2)], 1)
        return p, dp, ddp

    def _render(self, centres: list[np.ndarray]) -> np.ndarray:
        """(F, H, W) frames of blobs at ``centres`` (each (F, 2) row, col)."""
        rows = np.arange(self.size, dtype=np.float64)[None, :, None]
        cols = np.arange(self.size, dtype=np.float64)[None, None, :]
        img = np.zeros((len(centres[0]), self.size, self.size))
        for p in centres:
            d2 = (rows - p[:, 0, None, None]) ** 2 + (cols - p[:, 1, None, None]) ** 2
            img += self.peak * np.exp(-d2 / (2 * self.sigma ** 2))
        return img

    def video(self) -> SequenceData:
        q = self.motion()
        n, f = q.shape[:2]
        rng = np.random.default_rng([self.seed, 7])
        yy, xx = np.mgrid[0:self.size, 0:self.size] / self.size
        texture = np.zeros((self.size, self.size))
        for _ in range(4):
            k = rng.normal(0, 2.5, 2)
            texture += np.cos(2 * math.pi * (k[0] * yy + k[1] * xx) + rng.uniform(0, 6.3))
        texture = self.texture * (texture - texture.min()) / max(np.ptp(texture), 1e-9)
        frames = np.empty((n, f, 1, self.size, self.size))
        dot = np.empty_like(frames) if self.exact else None
        ddot = np.empty_like(frames) if self.exact else None
        h = 1e-3 * self.dt
        for i in range(n):
            paths = [self._pixel_path(b, q[i, :, b]) for b in range(self.latent_dim)]
            mid = self._render([p for p, _, _ in paths])
            frames[i, :, 0] = mid + texture
            if self.exact:  # renderings along p + ṗ s + p̈ s²/2 at s = ±h
                up = self._render([p + dp * h + ddp * h * h / 2 for p, dp, ddp in paths])
                down = self._render([p - dp * h + ddp * h * h / 2 for p, dp, ddp in paths])
                dot[i, :, 0] = (up - down) / (2 * h)
                ddot[i, :, 0] = (up - 2 * mid + down) / (h * h)
        spread = float(frames.max() - frames.min())
        if self.noise > 0:
            frames += self.noise * spread * rng.standard_normal(frames.shape)
        low, top = float(frames.min()), float(frames.max())
        frames = (frames - low) / (top - low)
        if self.exact:
            dot /= top - low
            ddot /= top - low
        if self.uint8:
            frames = np.round(frames * 255).astype(np.uint8)
        split = None
        if self.split == "random":
            split = rng.choice(3, size=n, p=[0.7, 0.15, 0.15]).astype(np.uint8)
            split[:2] = [0, 1]  # at least one sequence to train on and one to choose with
        return SequenceData(frames, None, split=split, dt=self.dt, images_dot=dot,
                            images_ddot=ddot, source=f"<second generator {self.seed}>")


def second_draw(rng: np.random.Generator) -> SecondDraw:
    """One draw of the second generator, every choice from ``rng``."""
    system = str(rng.choice(SYSTEMS))
    blobs = 2 if system == "two_pendulums" else 1
    omega2 = tuple(float(rng.uniform(0.3, 4.0)) for _ in range(blobs))
    damping = tuple(0.0 if rng.uniform() < 0.25 else
                    float(rng.uniform(0, min(0.4, 0.3 * math.sqrt(w2)))) for w2 in omega2)
    size = int(rng.integers(24, 81))
    sigma = float(rng.uniform(1.0, max(1.2, size / 12)))
    edge = 2.5 * sigma + 1
    if blobs == 1:
        half = size / 2 - edge
        length = (float(rng.uniform(0.45, 0.95)) * half,)
        room = half - length[0]
        pivot = ((size / 2 - 0.5 + float(rng.uniform(-room, room)),
                  size / 2 - 0.5 + float(rng.uniform(-room, room))),)
    else:  # side by side: each in its own half of the columns
        half = min(size / 4, size / 2) - edge / 2
        length = tuple(float(rng.uniform(0.45, 0.95)) * half for _ in range(2))
        pivot = tuple((size / 2 - 0.5 + float(rng.uniform(-0.2, 0.2)) * half,
                       (0.25 + 0.5 * k) * size - 0.5) for k in range(2))
    period = 2 * math.pi / math.sqrt(max(omega2))
    dt = float(rng.uniform(0.01, min(0.15, period / 8)))
    exact = bool(rng.uniform() < 0.5)
    return SecondDraw(
        system=system, omega2=omega2, damping=damping, size=size, sigma=sigma,
        peak=float(rng.uniform(0.5, 1.0)), pivot=pivot, length=length,
        angle=tuple(float(rng.uniform(0, math.pi)) for _ in range(blobs)),
        style=str(rng.choice(STYLES)),
        trajectories=round(math.exp(rng.uniform(math.log(20), math.log(200)))),
        frames=round(math.exp(rng.uniform(math.log(40), math.log(400)))),
        dt=dt, noise=float(rng.uniform(0, 0.02)) if rng.uniform() < 0.7 else 0.0,
        texture=float(rng.uniform(0.1, 0.4)) if rng.uniform() < 0.3 else 0.0,
        exact=exact, uint8=bool(not exact and rng.uniform() < 0.5),
        split=str(rng.choice(["none", "random"])), seed=int(rng.integers(2 ** 31)))
