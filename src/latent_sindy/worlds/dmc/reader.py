"""The pose of one coloured body with a part hanging from it, read from frames by image
moments (nothing learned): the cart-pole's cart and pole, a pendulum's pivot and rod.

From training frames, the background (the per-pixel median) and the object's colour (the
mean direction of the largest differences from it). A frame's weight map is the squared
positive part of its difference along that colour (a shadow, darker, weighs nothing); its
mode (the peak of the map blurred by σ, refined by mean shift in a σ window) finds the body
the rest hangs from. The mode is pulled toward what hangs; with ``body`` (the body's half
width and height) the body's centre is then the centroid of the weight in a box of that size
about it, leaving out the strip along what hangs beyond the box, three times over; with
``edges`` (the default) it is then the midpoint of the body's edges, where the weight summed
across the body falls to half (to a fraction of a pixel), and what hangs turns about a pivot
fitted on the training frames: (k x, y + c) from the body's centre (x, y), so that the line
of what hangs passes through it (k < 1 where the pivot lies behind the face the camera sees).
On the cart-pole each step read the angle nearer the physics angle (RESULTS.md). The
direction φ from that centre (or pivot) to the centroid of the weight farther than ``inner``
from it (and outside the body's box, with ``edges``) is the turn of what hangs. A frame is
``seen`` where the peak reaches ``min_peak`` of the training frames' median peak, the mode
lies within ``edge`` of the centre (image coordinates, -1 to 1), and, with ``edges``, the
body lies whole in the frame with the size and weight of the training frames' (a body cut
by the frame's edge, or a frame of what hangs alone, reads nothing meaningful).

The latent of two stacked frames (:meth:`ColourPoseReader.latent`): the mode's x, (cos φ,
sin φ), the changes of both over the control step (per second), and the action held over
that step, without which a change between two frames is not a state.

    >>> reader = ColourPoseReader(64).fit(frames)       # frames (N, 3, 64, 64), uint8
    >>> reader.fit_episodes(images)                     # or episodes (E, T+1, 6, 64, 64)
    >>> pose, seen = reader.read(frames[:10])           # (10, 4): x, y, cos φ, sin φ
    >>> z, seen = reader.episode(images, actions, dt)   # one episode's (T+1, 5 + nu) latents
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from latent_sindy.errors import UserError

__all__ = ["ColourPoseReader", "pose_latent"]


def _as_unit(frames: torch.Tensor, where: str) -> torch.Tensor:
    """Frames (B, 3, H, W) as float32 in [0, 1] (uint8 divided by 255)."""
    x = torch.as_tensor(frames)
    if x.ndim != 4 or x.shape[1] != 3:
        raise UserError(f"{where}: expected RGB frames of shape (B, 3, H, W), got "
                        f"{tuple(x.shape)}")
    return x.float() / 255 if x.dtype == torch.uint8 else x.float()


class ColourPoseReader:
    """Reads (x, y, cos φ, sin φ) of a coloured body and what hangs from it.

    Args:
        size: the frames' side in pixels (square frames).
        sigma: the blur and mean-shift window, in pixels of a 64×64 frame (scaled with size).
        inner: the radius around the mode left out of the hanging part's centroid, in
            pixels of a 64×64 frame.
        edge: a frame is seen only where the mode's |x| is below this (image coordinates).
        min_peak: ... and its peak at least this share of the training frames' median peak.
        body: the body's half width and half height, in pixels of a 64×64 frame (the
            cart-pole's cart: 4 × 2); None: the body's centre is the mode.
        edges: with ``body``, the body's centre from its edges and the pivot fitted (see
            above), where the training frames show the edges (in at least half of the
            frames seen; ``found_edges`` says); False: the centroid of its box, the pivot
            at it.
    """

    background: torch.Tensor  # (3, H, W)
    colour: torch.Tensor  # (3,) unit
    peak_median: float
    #: The latent coordinates of (cos φ, sin φ) (:meth:`latent`), kept on the unit circle.
    circle = (1, 2)
    #: The latent's coordinates (one action; :meth:`latent` appends as many as it is given).
    names = ("x", "cos φ", "sin φ", "ẋ", "φ̇", "previous u0")

    def __init__(self, size: int, sigma: float = 2.0, inner: float = 4.0, edge: float = 0.75,
                 min_peak: float = 0.5, body: tuple[float, float] | None = (4.0, 2.0),
                 edges: bool = True) -> None:
        from latent_sindy.models.encoders import image_coordinates

        if isinstance(size, bool) or not isinstance(size, int) or size < 8:
            raise UserError(f"ColourPoseReader size {size!r}: use the frames' side, >= 8 pixels")
        for name, value in (("sigma", sigma), ("inner", inner), ("edge", edge),
                            ("min_peak", min_peak)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise UserError(f"ColourPoseReader {name} {value!r}: use a positive number")
        if body is not None and not (isinstance(body, tuple | list) and len(body) == 2 and all(
                isinstance(v, int | float) and math.isfinite(v) and v > 0 for v in body)):
            raise UserError(f"ColourPoseReader body {body!r}: give the body's half width and "
                            "half height (two positive numbers), or None")
        self.size = size
        self.edge = float(edge)
        self.min_peak = float(min_peak)
        self.edges = bool(edges)
        self.body = None if body is None else (body[0] * size / 64, body[1] * size / 64)
        self.xs, self.ys = image_coordinates(size, size)
        self.pixel = float(self.xs[1] - self.xs[0])
        self.sigma = sigma * size / 64
        self.inner = inner * size / 64
        self.reach = math.ceil(3 * self.sigma)
        k = torch.arange(-self.reach, self.reach + 1, dtype=torch.float32)
        g = torch.exp(-k**2 / (2 * self.sigma**2))
        self.kernel = g / g.sum()

    def fit(self, frames: torch.Tensor, chunk: int = 4096) -> ColourPoseReader:
        """The background, the object's colour and the median peak from training frames
        (N, 3, H, W) of the object in many places; returns ``self``."""
        x = _as_unit(frames, "ColourPoseReader.fit")
        if x.shape[2:] != (self.size, self.size):
            raise UserError(f"ColourPoseReader.fit: frames of {tuple(x.shape[2:])} pixels for "
                            f"a reader of size {self.size}")
        if len(x) < 3:
            raise UserError("ColourPoseReader.fit needs at least 3 frames to tell the "
                            "background from the object")
        self.background = x.median(0).values
        d = x[::3] - self.background
        n2 = d.square().sum(1)
        top = n2 > torch.quantile(n2.flatten()[::17], 0.995)
        if not bool(top.any()):
            raise UserError("ColourPoseReader.fit: the frames do not differ from their "
                            "median; give frames where the object moves")
        colour = d.permute(0, 2, 3, 1)[top].mean(0)
        self.colour = colour / colour.norm().clamp_min(1e-12)
        self.pivot = (1.0, 0.0)
        self.extent = None
        self.found_edges = self.body is not None and self.edges
        if self.found_edges:
            self._body(x[:chunk])  # the body's extent, from the first chunk's frames
        parts = [self._pose(x[i:i + chunk]) for i in range(0, len(x), chunk)]
        pose, peaks, inside = (torch.cat(v) for v in zip(*parts, strict=True))
        self.peak_median = float(peaks.median())
        seen = (peaks > self.min_peak * self.peak_median) & (pose[:, 0].abs() < self.edge)
        if self.found_edges and float(inside[seen].double().mean()) < 0.5:
            # the training frames do not show the body's edges (a background that holds the
            # body, say, where it barely moved): its box's centroid, as with edges=False
            self.found_edges = False
        if self.found_edges:
            self.pivot = self._fit_pivot(x, chunk)
        return self

    def _fit_pivot(self, x: torch.Tensor, chunk: int) -> tuple[float, float]:
        """(k, c): the pivot of what hangs lies at (k x, y + c) from the body's centre (x, y)
        (k ≠ 1 where the pivot lies deeper than the body's face the camera sees: its image
        moves less about the image's centre), fitted so the line of what hangs passes through
        it, over the training frames where what hangs is long and thin; (1, 0) without
        enough of them."""
        rows = []
        for i in range(0, len(x), chunk):
            w, mx, my, peak, inside = self._body(x[i:i + chunk])
            wo = self._hanging_weight(w, mx, my)
            m = wo.sum((1, 2)).clamp_min(1e-12)
            qx, qy = (wo.sum(1) * self.xs).sum(1) / m, (wo.sum(2) * self.ys).sum(1) / m
            ex = self.xs[None, None] - qx[:, None, None]
            ey = self.ys[None, :, None] - qy[:, None, None]
            sxx, syy = (wo * ex**2).sum((1, 2)) / m, (wo * ey**2).sum((1, 2)) / m
            sxy = (wo * ex * ey).sum((1, 2)) / m
            axis = 0.5 * torch.atan2(2 * sxy, sxx - syy)
            spread = torch.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)
            thin = (0.5 * (sxx + syy) + spread) > 20 * (0.5 * (sxx + syy) - spread)
            keep = inside & thin & (peak > self.min_peak * self.peak_median) & (
                mx.abs() < self.edge)
            nx, ny = -torch.sin(axis), torch.cos(axis)
            rows.append(torch.stack([nx * mx, ny, nx * qx + ny * qy - ny * my], -1)[keep])
        a = torch.cat(rows).double()
        if len(a) < 20:
            return 1.0, 0.0
        keep = torch.ones(len(a), dtype=torch.bool)
        for _ in range(2):  # least squares, then again without the outliers
            sol = torch.linalg.lstsq(a[keep, :2], a[keep, 2:]).solution[:, 0]
            res = (a[:, :2] @ sol - a[:, 2]).abs()
            keep = res <= 3 * 1.4826 * res[keep].median().clamp_min(1e-12)
        return float(sol[0]), float(sol[1])

    def fit_episodes(self, images: torch.Tensor) -> ColourPoseReader:
        """:meth:`fit` on episodes of two stacked frames (E, T+1, 6, H, W): their current
        frames; returns ``self``."""
        images = torch.as_tensor(images)
        if images.ndim != 5 or images.shape[2] != 6:
            raise UserError(f"ColourPoseReader.fit_episodes: expected episodes of two stacked "
                            f"RGB frames (E, T+1, 6, H, W), got {tuple(images.shape)}")
        return self.fit(images[:, :, 3:].reshape(-1, 3, *images.shape[3:]))

    def _distance2(self, mx: torch.Tensor, my: torch.Tensor) -> torch.Tensor:
        """(B, H, W) squared distance of each pixel from the points (mx, my) (B,)."""
        return ((self.xs[None, None] - mx[:, None, None]) ** 2
                + (self.ys[None, :, None] - my[:, None, None]) ** 2)

    def _pose(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Poses (B, 4), peaks (B,) and whether the body lies whole in the frame (B,)."""
        w, mx, my, peak, inside = self._body(x)
        px, py = mx, my
        if self.found_edges:
            px, py = self.pivot[0] * mx, my + self.pivot[1]
        dx, dy = self._hanging(w, px, py)
        dx, dy = dx.double(), dy.double()
        # the unit vector in float64: rounded in float32, cos² + sin² = 1 would hold only to
        # 1e-7, and a regression fits that rounding with huge cancelling coefficients
        r = torch.hypot(dx, dy).clamp_min(1e-12)
        return torch.stack([mx.double(), my.double(), dx / r, dy / r], -1), peak, inside

    def _body(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The weight map (B, H, W), the body's centre (B,) twice, the peaks (B,) and
        whether the body lies whole in the frame (B,)."""
        xs = self.xs
        ys = self.ys
        k = self.kernel
        n = self.reach
        lin = torch.relu(((x - self.background) * self.colour[:, None, None]).sum(1))
        w = lin ** 2
        b = F.conv2d(F.conv2d(w[:, None], k.view(1, 1, 1, -1), padding=(0, n)),
                     k.view(1, 1, -1, 1), padding=(n, 0))[:, 0]
        peak, at = b.flatten(1).max(1)
        mx, my = xs[at % w.shape[2]], ys[at // w.shape[2]]
        for _ in range(5):
            wg = w * torch.exp(-self._distance2(mx, my) / (2 * (self.sigma * self.pixel) ** 2))
            m = wg.sum((1, 2)).clamp_min(1e-12)
            mx, my = (wg.sum(1) * xs).sum(1) / m, (wg.sum(2) * ys).sum(1) / m
        inside = torch.ones_like(peak, dtype=torch.bool)
        if self.body is not None:
            for _ in range(3):
                mx, my = self._body_centre(w, mx, my)
            if self.found_edges:
                mx, my, inside = self._body_edges(lin, mx, my)
        return w, mx, my, peak, inside

    def _body_edges(self, lin: torch.Tensor, mx: torch.Tensor, my: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The body's centre as the midpoints of its edges (where the weight summed across
        the body falls to half its value at the centre, to a fraction of a pixel); and
        whether all four edges lie in the frame, as far apart and the body as heavy as in
        the training frames (each within a quarter: a body cut by the frame's edge, or not
        there, is not seen)."""
        hx, hy = self.body
        p = self.pixel
        rows = ((self.ys[None] - my[:, None]).abs() <= hy * p).float()  # (B, H)
        cx, wx, lx = _midpoint((lin * rows[:, :, None]).sum(1), self.xs, mx, hx / 2)
        cols = ((self.xs[None] - cx[:, None]).abs() <= hx * p).float()  # (B, W)
        cy, wy, ly = _midpoint((lin * cols[:, None, :]).sum(2), self.ys, my, hy / 2)
        if self.extent is None:  # fitting: the body's width, height and weights
            self.extent = tuple(float(v[wx > 0].median()) for v in (wx, wy, lx, ly))
        seen = torch.ones_like(wx, dtype=torch.bool)
        for v, typical in zip((wx, wy, lx, ly), self.extent, strict=True):
            seen &= (v - typical).abs() < 0.25 * typical
        return cx, cy, seen

    def _hanging(self, w: torch.Tensor, mx: torch.Tensor, my: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B,) offsets from (mx, my) of the centroid of :meth:`_hanging_weight`."""
        wo = self._hanging_weight(w, mx, my)
        m = wo.sum((1, 2)).clamp_min(1e-12)
        return (wo.sum(1) * self.xs).sum(1) / m - mx, (wo.sum(2) * self.ys).sum(1) / m - my

    def _hanging_weight(self, w: torch.Tensor, mx: torch.Tensor, my: torch.Tensor
                        ) -> torch.Tensor:
        """(B, H, W) the weight of what hangs from (mx, my): beyond ``inner`` (with the
        body's edges: and outside the body's box)."""
        wo = w * (self._distance2(mx, my) > (self.inner * self.pixel) ** 2)
        return wo * ~self._box(mx, my) if self.found_edges else wo

    def _box(self, mx: torch.Tensor, my: torch.Tensor) -> torch.Tensor:
        """(B, H, W) whether each pixel lies in the body's box about (mx, my), a pixel and
        a half of a 64×64 frame wider each way."""
        (hx, hy), margin = self.body, 1.5 * self.size / 64
        return (((self.xs[None, None] - mx[:, None, None]).abs() < (hx + margin) * self.pixel)
                & ((self.ys[None, :, None] - my[:, None, None]).abs()
                   < (hy + margin) * self.pixel))

    def _body_centre(self, w: torch.Tensor, mx: torch.Tensor, my: torch.Tensor
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """The centroid of the weight in the body's box about (mx, my) (a pixel and a half
        of a 64×64 frame wider each way), without the strip along what hangs beyond the box
        (as wide)."""
        hx, hy = self.body
        vx, vy = self._hanging(w, mx, my)
        r = torch.hypot(vx, vy).clamp_min(1e-12)
        ux, uy = (vx / r)[:, None, None], (vy / r)[:, None, None]
        dx = self.xs[None, None] - mx[:, None, None]
        dy = self.ys[None, :, None] - my[:, None, None]
        p = self.pixel
        margin = 1.5 * self.size / 64
        strip = ((dx * ux + dy * uy) > math.hypot(hx, hy) * p) & (
            (dx * uy - dy * ux).abs() < margin * p)
        wb = w * (self._box(mx, my) & ~strip)
        m = wb.sum((1, 2))
        cx = (wb.sum(1) * self.xs).sum(1) / m.clamp_min(1e-12)
        cy = (wb.sum(2) * self.ys).sum(1) / m.clamp_min(1e-12)
        return torch.where(m > 0, cx, mx), torch.where(m > 0, cy, my)

    def read(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Poses (B, 4) float64: x, y (image coordinates, y down), cos φ, sin φ (φ from the
        image's x axis towards y); and (B,) bool, whether each frame saw the object."""
        if not hasattr(self, "background"):
            raise UserError("ColourPoseReader.read before fit: fit it on training frames")
        x = _as_unit(frames, "ColourPoseReader.read")
        if x.shape[2:] != self.background.shape[1:]:
            raise UserError(f"ColourPoseReader.read: frames of {tuple(x.shape[2:])} pixels "
                            f"for a reader fitted on {tuple(self.background.shape[1:])}")
        pose, peak, inside = self._pose(x)
        return pose, ((peak > self.min_peak * self.peak_median) & (pose[:, 0].abs() < self.edge)
                      & inside)

    def latent(self, obs: torch.Tensor, previous: torch.Tensor, dt: float
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 5 + nu) latents of two stacked frames obs (B, 6, H, W) (earlier frame first)
        and the actions held between them, previous (B, nu); and (B,) whether the current
        frame saw the object."""
        obs = torch.as_tensor(obs)
        if obs.ndim != 4 or obs.shape[1] != 6:
            raise UserError(f"ColourPoseReader.latent: expected two stacked RGB frames "
                            f"(B, 6, H, W), got {tuple(obs.shape)}")
        now, seen = self.read(obs[:, 3:])
        before, _ = self.read(obs[:, :3])
        return pose_latent(now, before, previous, dt), seen

    def episode(self, images: torch.Tensor, actions: torch.Tensor, dt: float
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """One episode's latents (T+1, 5 + nu) from its stacked frames images (T+1, 6, H, W)
        and actions (T, nu), each frame read once (a frame's earlier one is the last step's;
        the first step's earlier frame is its own stack's, with no action before it)."""
        images, actions = torch.as_tensor(images), torch.as_tensor(actions)
        if images.ndim != 4 or images.shape[1] != 6 or actions.ndim != 2 or (
                len(actions) != len(images) - 1):
            raise UserError(f"ColourPoseReader.episode: expected stacked frames (T+1, 6, H, "
                            f"W) and actions (T, nu), got {tuple(images.shape)} and "
                            f"{tuple(actions.shape)}")
        now, seen = self.read(images[:, 3:])
        first, _ = self.read(images[:1, :3])
        previous = torch.cat([torch.zeros_like(actions[:1]), actions]).double()
        return pose_latent(now, torch.cat([first, now[:-1]]), previous, dt), seen


def _midpoint(profile: torch.Tensor, at: torch.Tensor, start: torch.Tensor, half: float
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The midpoint (B,) between the two places where each profile (B, N) over the
    coordinates ``at`` (N,) falls to half its median within ``half`` pixels of ``start``
    (B,), each linearly interpolated between pixels; the distance between the two (B,), 0
    where one of them lies outside; and that median (B,)."""
    n = profile.shape[1]
    p = float(at[1] - at[0])
    c = ((start - at[0]) / p).round().long().clamp(0, n - 1)
    idx = torch.arange(n)
    near = (idx[None] - c[:, None]).abs() <= max(1, round(half))
    level = torch.where(near, profile, torch.nan).nanmedian(1).values / 2
    below = profile <= level[:, None]
    lo = torch.where(below & (idx < c[:, None]), idx, -1).max(1).values
    hi = torch.where(below & (idx > c[:, None]), idx, n).min(1).values
    inside = (lo >= 0) & (hi < n) & (level > 0)

    def crossing(j: torch.Tensor, step: int) -> torch.Tensor:  # between j and j + step
        j, k = j.clamp(0, n - 1), (j + step).clamp(0, n - 1)
        a, b = profile.gather(1, j[:, None])[:, 0], profile.gather(1, k[:, None])[:, 0]
        t = ((level - a) / torch.where((b - a).abs() > 1e-12, b - a, 1.0)).clamp(0, 1)
        return at[j] + t * (at[k] - at[j])

    a, b = crossing(lo, 1), crossing(hi, -1)
    return (torch.where(inside, (a + b) / 2, start), torch.where(inside, b - a, 0.0),
            2 * level)


def pose_latent(now: torch.Tensor, before: torch.Tensor, previous: torch.Tensor, dt: float
                ) -> torch.Tensor:
    """(B, 5 + nu) latents from the poses (B, 4) of :meth:`ColourPoseReader.read` of the
    current and the earlier frame and the actions held between them (B, nu): x, cos φ, sin φ,
    the change of x and the turn of φ per second, the actions."""
    turn = torch.atan2(before[:, 2] * now[:, 3] - before[:, 3] * now[:, 2],
                       before[:, 2] * now[:, 2] + before[:, 3] * now[:, 3])
    z = torch.stack([now[:, 0], now[:, 2], now[:, 3], (now[:, 0] - before[:, 0]) / dt,
                     turn / dt], -1)
    return torch.cat([z, torch.as_tensor(previous).double().reshape(len(z), -1)], -1)
