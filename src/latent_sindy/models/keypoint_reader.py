"""A latent learned from the frames alone: keypoints of the parts that move, found by
transporting one frame's features into another (Kulkarni et al. 2019, "Transporter").

Two frames of one episode, a source and a target, differ only where something moved. A
keypoint network gives each frame ``parts`` keypoints (a spatial softmax over one feature
map each: the expected pixel coordinates); a feature network gives each frame a feature
map. The target's features are rebuilt from the source's: around every keypoint of either
frame the source's features are taken out, and around the target's keypoints the target's
are put in; a decoder draws the target frame from the result. The only way to draw the
target well is for the keypoints to sit on what moved between the two frames: the
background is copied from the source for free, so reconstruction spends nothing on it,
and a thin part (a pole) counts as much as its pixels change. Nothing in it knows what is
filmed: its one structural setting is ``parts``, the number of keypoints.

Observations are frames stacked as channels (``frames`` of them, oldest first). The latent
of one is the principal coordinates of the newest frame's keypoints (those of the training
frames' keypoints that follow something and carry more than ``min_share`` of their
variance: a keypoint that rests, or two that follow one part, add none), their change per
second since the frame before it, and the action held between the two. A frame is *seen*
where each keypoint that follows something keeps its weights as close about it as it does
in most training frames (:data:`SPREAD`): a part that leaves the frame spreads its
keypoint's weights over the rest, and such frames are left out of the fits as a hand-made
reader's unseen ones are.

Where two principal coordinates are kept and wind round the centre of the circle fitted to
them (:func:`~latent_sindy.models.geodesic_reader.winds_round`: one part turning about a
fixed pivot, as a pendulum's), they are read as the angle φ about that centre instead:
(cos φ, sin φ), the turn per second and the action, the pair being the ``circle`` that the
dynamics keep on the unit circle, as the geodesic reader does. The reader serves
:class:`~latent_sindy.read_latent.ReadLatent` like the geodesic reader
(:mod:`~latent_sindy.models.geodesic_reader`) or a world's hand-made reader.

    >>> reader = KeypointReader(frames=2, parts=4).fit_episodes(images)  # (E, T+1, C, H, W)
    >>> z, seen = reader.episode(images[0], actions[0], dt=0.05)           # (T+1, nz)

Fitting costs ``steps`` Adam updates on batches of frame pairs (about a third of a second an
update at 64×64 on 2 CPU cores, BENCHMARKS.md); a reader fitted once on some frames is kept
for the process's life and reused by any reader of the same settings fitted on the same
frames. Given a ``store`` folder, the fitted networks are also kept there, for any process:
a reader of the same settings fitted on the same frames loads them instead of training, one
process trains while the others wait for it, and a fit that was stopped resumes from its
last checkpoint (every :data:`CHECKPOINT` updates) with the same result as one that ran
through.

    >>> KeypointReader(frames=2, parts=4, store="runs/cartpole/readers").fit_episodes(images)
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F

from latent_sindy.atomic import write_atomic
from latent_sindy.errors import UserError
from latent_sindy.locks import exclusive
from latent_sindy.models.geodesic_reader import winds_round
from latent_sindy.models.reader_latent import reader_latent
from latent_sindy.models.stacked_frames import newest_and_before

__all__ = ["KeypointReader"]

#: A keypoint whose spread (root mean square distance of its softmax weights, in the
#: image's [-1, 1] units) over the training frames has a median at least this follows
#: nothing: it is left out of what a frame must show.
LIVE = 0.3
#: A frame shows a part where its keypoint's spread is at most this many times the
#: keypoint's median spread over the training frames, or one cell of the keypoint maps (a
#: part out of the frame spreads its keypoint's weights over the rest).
SPREAD = 2.0
#: The keypoints' Gaussian's standard deviation unless told (image's [-1, 1] units).
SPREAD_DEFAULT = 0.1
#: A fit kept in a ``store`` writes its progress there every this many updates.
CHECKPOINT = 250
#: What a stored fit's file says it is.
STORE_FORMAT = "latent-sindy keypoint reader 1"

#: Readers fitted in this process, by their settings and their frames' digest.
_FITTED: dict[tuple, dict[str, torch.Tensor]] = {}


def _block(cin: int, cout: int, stride: int) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, 3, stride, 1), nn.BatchNorm2d(cout), nn.ReLU()]


def _trunk(cin: int, width: int, out: int) -> nn.Sequential:
    """Images (B, cin, H, W) -> maps (B, out, ⌈H/4⌉, ⌈W/4⌉)."""
    return nn.Sequential(*_block(cin, width, 1), *_block(width, width, 2),
                         *_block(width, 2 * width, 1), *_block(2 * width, 2 * width, 2),
                         nn.Conv2d(2 * width, out, 3, 1, 1))


class Transporter(nn.Module):
    """The three networks: features, keypoints and the decoder; see the module docstring.

    Args:
        channels: colour channels of one frame.
        parts: keypoints a frame.
        width: feature maps of the first convolutions (twice that after the first halving).
        spread: the keypoints' Gaussian's standard deviation, in the image's [-1, 1] units.
    """

    def __init__(self, channels: int, parts: int, width: int = 16,
                 spread: float = SPREAD_DEFAULT) -> None:
        super().__init__()
        self.parts = parts
        self.spread = spread
        self.features = _trunk(channels, width, 2 * width)
        self.keypoint_maps = _trunk(channels, width, parts)
        self.decoder = nn.Sequential(
            *_block(2 * width, 2 * width, 1), nn.Upsample(scale_factor=2),
            *_block(2 * width, width, 1), nn.Upsample(scale_factor=2),
            *_block(width, width, 1), nn.Conv2d(width, channels, 3, 1, 1))
        # Channels-last weights and inputs take oneDNN's NHWC convolutions on CPU, faster
        # here (BENCHMARKS.md)
        self.to(memory_format=torch.channels_last)

    @staticmethod
    def _grid(h: int, w: int, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        ys = torch.linspace(-1.0, 1.0, h, dtype=like.dtype, device=like.device)
        xs = torch.linspace(-1.0, 1.0, w, dtype=like.dtype, device=like.device)
        return torch.meshgrid(ys, xs, indexing="ij")

    def keypoints(self, x: torch.Tensor, spread: bool = False
                  ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Frames (B, C, H, W) -> keypoints (B, parts, 2): (x right, y down) in [-1, 1];
        with ``spread``, also each keypoint's distribution's spread (B, parts): the root
        mean square distance of its softmax weights from it."""
        maps = self.keypoint_maps(x.contiguous(memory_format=torch.channels_last))
        p = torch.softmax(maps.flatten(2), -1).view_as(maps)
        gy, gx = self._grid(*maps.shape[-2:], maps)
        mx, my = (p * gx).sum((2, 3)), (p * gy).sum((2, 3))
        points = torch.stack([mx, my], -1)
        if not spread:
            return points
        d2 = (gx - mx[..., None, None]) ** 2 + (gy - my[..., None, None]) ** 2
        return points, (p * d2).sum((2, 3)).sqrt()

    def _gaussians(self, points: torch.Tensor, h: int, w: int) -> torch.Tensor:
        gy, gx = self._grid(h, w, points)
        d2 = (gx - points[..., 0, None, None]) ** 2 + (gy - points[..., 1, None, None]) ** 2
        return torch.exp(-d2 / (2 * self.spread ** 2))  # (B, parts, h, w)

    def forward(self, source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The target frames (B, C, H, W) drawn from the source's features, transported."""
        both = torch.cat([source, target]).contiguous(memory_format=torch.channels_last)
        feats = self.features(both)
        h, w = feats.shape[-2:]
        fs, ft = feats.chunk(2)
        gs, gt = self._gaussians(self.keypoints(both), h, w).chunk(2)
        f = fs
        for k in range(self.parts):
            a, b = gs[:, k:k + 1], gt[:, k:k + 1]
            f = (1 - a) * (1 - b) * f + b * ft
        drawn = self.decoder(f)
        return F.interpolate(drawn, size=source.shape[-2:], mode="bilinear",
                             align_corners=False) if drawn.shape[-2:] != source.shape[-2:] \
            else drawn


class KeypointReader:
    """Keypoints of the parts that move, learned from training frames; see the module
    docstring.

    Args:
        frames: frames stacked as channels in one observation (their colours split evenly;
            with one frame the rates are 0: nothing shows them).
        parts: keypoints a frame (its one structural setting).
        spread: the keypoints' Gaussian's standard deviation, in the image's [-1, 1] units
            (how much of a part one keypoint carries when it transports it).
        steps: Adam updates of the fit, on batches of ``batch`` frame pairs.
        lr: Adam's learning rate.
        width: the networks' first feature maps.
        min_share: a principal coordinate of the keypoints is kept where it carries at least
            this share of their variance.
        seed: the networks' start and the pairs drawn.
        device: where the networks train ("cpu", "cuda").
        progress: a progress bar of the fit's updates on stderr.
        store: a folder where fitted networks are kept and stopped fits resume (see the
            module docstring); None: kept in this process only.
        angle: read two principal coordinates as an angle about their circle's centre
            (True: the two largest), never (False), or where two are kept and wind round
            (None).
    """

    def __init__(self, frames: int = 2, parts: int = 4, steps: int = 6000, batch: int = 32,
                 lr: float = 1e-3, width: int = 16, min_share: float = 0.01, seed: int = 0,
                 device: str = "cpu", progress: bool = True,
                 store: str | os.PathLike | None = None, angle: bool | None = None,
                 spread: float = SPREAD_DEFAULT) -> None:
        for name, value in (("frames", frames), ("parts", parts), ("steps", steps),
                            ("batch", batch), ("width", width)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise UserError(f"KeypointReader {name}={value!r}: use an integer >= 1")
        for name, value, high in (("lr", lr, float("inf")), ("min_share", min_share, 1.0),
                                  ("spread", spread, 2.0)):
            if isinstance(value, bool) or not isinstance(value, int | float) or not (
                    0.0 < value < high):
                raise UserError(f"KeypointReader {name}={value!r}: use a number in (0, "
                                f"{high})")
        if angle not in (None, True, False):
            raise UserError(f"KeypointReader angle={angle!r}: use None (from the data), False "
                            "or True")
        self.angle = angle
        self.frames, self.parts, self.steps, self.batch = frames, parts, steps, batch
        self.lr, self.width, self.min_share, self.seed = lr, width, min_share, seed
        self.spread = float(spread)
        self.device = torch.device(device)
        self.progress = progress
        self.store = None if store is None else Path(store)
        if self.store is not None and self.store.exists() and not self.store.is_dir():
            raise UserError(f"KeypointReader store={str(store)!r} is a file: give a folder")
        self.circle: tuple[int, int] | None = None
        self.names: tuple[str, ...] = ()

    # ------------------------------------------------------------------ fitting
    def _split(self, obs: torch.Tensor, where: str) -> tuple[torch.Tensor, torch.Tensor]:
        """Observations (B, C, H, W) -> their newest frames and the frames before those."""
        return newest_and_before(obs, self.frames, f"KeypointReader.{where}")

    def _float(self, frames: torch.Tensor) -> torch.Tensor:
        x = frames.float()
        return x / 255.0 if frames.dtype == torch.uint8 else x

    def _settings(self) -> tuple:
        # (the default spread is left out: fits stored before it was a setting stay found)
        return (self.frames, self.parts, self.steps, self.batch, self.lr, self.width,
                self.seed, str(self.device)) + (
            () if self.spread == SPREAD_DEFAULT else (f"spread={self.spread!r}",))

    def fit_episodes(self, images: torch.Tensor) -> KeypointReader:
        """Learn the keypoints from training episodes' observations (E, T+1, C, H, W)."""
        images = torch.as_tensor(images)
        if images.ndim != 5 or images.shape[1] < 2:
            raise UserError(f"KeypointReader.fit_episodes: expected episodes (E, T+1, C, H, "
                            f"W) of at least 2 observations, got {tuple(images.shape)}")
        e, t = images.shape[:2]
        newest = self._split(images.flatten(0, 1), "fit_episodes")[0]
        frames = self._float(newest).reshape(e, t, *newest.shape[1:])
        self.shape_ = tuple(images.shape[2:])
        digest = hashlib.sha1(newest.contiguous().numpy().tobytes()).hexdigest()
        key = (*self._settings(), digest, tuple(newest.shape))
        torch.manual_seed(self.seed)
        self.net_ = Transporter(frames.shape[2], self.parts, self.width, self.spread
                                ).to(self.device)
        self.mean_ = frames.mean((0, 1, 3, 4)).view(-1, 1, 1)
        if key in _FITTED:
            self.net_.load_state_dict(_FITTED[key])
        else:
            if self.store is None:
                self._train(frames)
            else:
                self._train_stored(frames, key)
            _FITTED[key] = {k: v.detach().clone() for k, v in self.net_.state_dict().items()}
        self.net_.eval().requires_grad_(False)
        points, spread = self._points(frames.flatten(0, 1))
        typical = spread.median(0).values
        self.typical_spread_ = typical
        self.live_ = typical < LIVE
        if not bool(self.live_.any()):
            self.live_ = typical == typical.min()
        # (a spread under one cell of the keypoint maps is as sharp as they draw)
        cell = 2.0 / max(max(self.net_.keypoint_maps(frames[0, :1] - self.mean_)
                             .shape[-2:]) - 1, 1)
        self.limit_ = (SPREAD * typical).clamp_min(cell)
        seen = self._seen(spread)
        if int(seen.sum()) <= 2:
            seen = torch.ones_like(seen)
        self.seen_share_ = float(seen.double().mean())
        points = points[seen]
        self.centre_ = points.mean(0)
        # a keypoint that follows nothing wanders with its diffuse weights: noise, no state
        centred = (points - self.centre_) * self.live_.repeat_interleave(2).double()
        _, s, v = torch.linalg.svd(centred, full_matrices=False)
        share = s ** 2 / (s ** 2).sum().clamp_min(1e-30)
        kept = 2 if self.angle else max(1, int((share >= self.min_share).sum()))
        self.axes_ = v[:kept].T  # (2 · parts, kept), 0 on the keypoints that follow nothing
        self.share_ = share[:kept]
        self.turns_ = False
        if kept == 2 and self.angle is not False:
            coords = centred @ self.axes_
            self.pivot_ = circle_centre(coords)
            self.turns_ = bool(self.angle or winds_round(coords - self.pivot_))
        self.circle = (0, 1) if self.turns_ else None
        self.names = (("cos φ", "sin φ", "φ'") if self.turns_ else
                      tuple(f"k{i}" for i in range(kept)) + tuple(
                          f"k{i}'" for i in range(kept)))
        return self

    def record(self) -> dict:
        """What the fit found, JSON-ready: which keypoints follow something (their typical
        spread), the principal coordinates kept and their shares of the variance, whether
        they are read as an angle, the share of training frames seen and the last loss;
        ``summary``, the same in a line."""
        if not hasattr(self, "axes_"):
            raise UserError("KeypointReader.record before fit_episodes: fit it first")
        live = [bool(v) for v in self.live_]
        shares = [round(float(v), 4) for v in self.share_]
        kept = ("read as an angle" if self.turns_ else
                f"{len(shares)} principal coordinate(s) of "
                + ", ".join(f"{v:.1%}" for v in shares) + " of the variance")
        return {"reader": "keypoints", "parts": self.parts, "spread": self.spread,
                "live": live,
                "typical_spread": [round(float(v), 4) for v in self.typical_spread_],
                "variance_shares": shares, "angle": self.turns_,
                "seen_share": self.seen_share_, "loss": getattr(self, "loss_", None),
                "summary": f"{sum(live)} of {self.parts} keypoints follow something; {kept}"}

    def _train_stored(self, frames: torch.Tensor, key: tuple) -> None:
        """The networks from the store where a fit of ``key`` is there, else trained (from its
        checkpoint where one is there) and kept there; one process at a time per key."""
        text = json.dumps([str(k) for k in key])
        path = self.store / f"keypoints-{hashlib.sha1(text.encode()).hexdigest()[:16]}.pt"
        with exclusive(path, "keypoint reader's fit", "store", wait=True):
            if path.exists():
                stored = _load(path, text, done=True)
                self.net_.load_state_dict(stored["net"])
                self.loss_ = float(stored["loss"])
                return
            partial = path.with_name(path.stem + ".partial.pt")
            self._train(frames, partial, text)
            write_atomic(path, lambda f: torch.save(
                {"format": STORE_FORMAT, "key": text, "net": self.net_.state_dict(),
                 "loss": self.loss_}, f))
            partial.unlink(missing_ok=True)

    def _train(self, frames: torch.Tensor, checkpoint: Path | None = None, text: str = ""
               ) -> None:
        """``steps`` updates of the networks; with a ``checkpoint`` file, resumed from it
        where it is there and written to every :data:`CHECKPOINT` updates."""
        from latent_sindy.progress import bar

        e, t = frames.shape[:2]
        gen = torch.Generator().manual_seed(self.seed)
        self.net_.train()
        opt = torch.optim.Adam(self.net_.parameters(), self.lr)
        start = 0
        if checkpoint is not None and checkpoint.exists():
            state = _load(checkpoint, text, done=False)
            self.net_.load_state_dict(state["net"])
            opt.load_state_dict(state["optimizer"])
            gen.set_state(state["generator"])
            start = int(state["step"])
        centred = frames - self.mean_
        steps = (bar(range(start, self.steps), total=self.steps, initial=start,
                     desc="keypoints", unit="update") if self.progress
                 else range(start, self.steps))
        loss = torch.tensor(float("nan"))
        for step in steps:
            ep = torch.randint(0, e, (self.batch,), generator=gen)
            i = torch.randint(0, t, (self.batch,), generator=gen)
            j = torch.randint(0, t, (self.batch,), generator=gen)
            source = centred[ep, i].to(self.device)
            target = centred[ep, j].to(self.device)
            loss = F.mse_loss(self.net_(source, target), target)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if checkpoint is not None and (step + 1) % CHECKPOINT == 0 and step + 1 < self.steps:
                payload = {"format": STORE_FORMAT, "key": text, "step": step + 1,
                           "net": self.net_.state_dict(), "optimizer": opt.state_dict(),
                           "generator": gen.get_state()}
                write_atomic(checkpoint, lambda f, payload=payload: torch.save(payload, f))
        self.loss_ = float(loss.detach())

    # ------------------------------------------------------------------ reading
    @torch.no_grad()
    def _points(self, frames: torch.Tensor, chunk: int = 512
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Keypoints (B, 2 · parts) and their spreads (B, parts), float64, of single frames
        (B, C, H, W) in [0, 1]."""
        points, spreads = [], []
        for i in range(0, len(frames), chunk):
            p, s = self.net_.keypoints((frames[i:i + chunk] - self.mean_).to(self.device),
                                       spread=True)
            points.append(p.flatten(1).cpu())
            spreads.append(s.cpu())
        return torch.cat(points).double(), torch.cat(spreads).double()

    def _seen(self, spread: torch.Tensor) -> torch.Tensor:
        """(B,) bool: every live keypoint's spread within its limit."""
        return (spread[:, self.live_] <= self.limit_[self.live_]).all(1)

    def read(self, frames: torch.Tensor) -> torch.Tensor:
        """The keypoints' principal coordinates (B, kept) float64 of single frames
        (B, C / frames, H, W)."""
        return self.read_seen(frames)[0]

    def read_seen(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The keypoints' principal coordinates (B, kept) float64 of single frames
        (B, C / frames, H, W), and (B,) bool: whether each frame shows every part the
        reader follows (each live keypoint's spread within its limit)."""
        if not hasattr(self, "axes_"):
            raise UserError("KeypointReader.read before fit_episodes: fit it on training "
                            "episodes first")
        frames = torch.as_tensor(frames)
        if tuple(frames.shape[1:]) != (self.shape_[0] // self.frames, *self.shape_[1:]):
            raise UserError(f"KeypointReader.read: frames of {tuple(frames.shape[1:])} for a "
                            f"reader fitted on observations {self.shape_} of {self.frames} "
                            "frames")
        points, spread = self._points(self._float(frames))
        return (points - self.centre_) @ self.axes_, self._seen(spread)

    def _latent(self, now: torch.Tensor, before: torch.Tensor, previous: torch.Tensor,
                dt: float) -> torch.Tensor:
        return reader_latent(now, before, previous, dt, self.pivot_ if self.turns_ else None)

    def latent(self, obs: torch.Tensor, previous: torch.Tensor, dt: float
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """Latents (B, 2 · kept + nu; an angle's 3 + nu) of observations (B, C, H, W) and
        the actions held since the frame before the newest (B, nu); and (B,) bool: both
        frames show every part the reader follows."""
        newest, earlier = self._split(torch.as_tensor(obs), "latent")
        now, seen = self.read_seen(newest)
        before, seen_before = self.read_seen(earlier) if self.frames > 1 else (now, seen)
        return self._latent(now, before, previous, dt), seen & seen_before

    def episode(self, images: torch.Tensor, actions: torch.Tensor, dt: float
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """One episode's latents (T+1, 2 · kept + nu; an angle's 3 + nu) from its
        observations (T+1, C, H, W) and actions (T, nu), each newest frame read once (the
        first step's earlier frame is its own observation's, with no action before it)."""
        images, actions = torch.as_tensor(images), torch.as_tensor(actions)
        if images.ndim != 4 or actions.ndim != 2 or len(actions) != len(images) - 1:
            raise UserError(f"KeypointReader.episode: expected observations (T+1, C, H, W) "
                            f"and actions (T, nu), got {tuple(images.shape)} and "
                            f"{tuple(actions.shape)}")
        newest, earlier = self._split(images, "episode")
        now, seen = self.read_seen(newest)
        first, seen_first = (self.read_seen(earlier[:1]) if self.frames > 1
                             else (now[:1], seen[:1]))
        previous = torch.cat([torch.zeros_like(actions[:1]), actions]).double()
        both = seen & torch.cat([seen_first, seen[:-1]])
        return self._latent(now, torch.cat([first, now[:-1]]), previous, dt), both


def circle_centre(points: torch.Tensor) -> torch.Tensor:
    """The centre (2,) of the circle fitted to points (N, 2) by least squares on
    |p|² = 2 c·p + k (Kåsa's fit); their mean where they lie on a line."""
    p = points.double()
    design = torch.cat([2 * p, torch.ones(len(p), 1, dtype=p.dtype)], 1)
    target = (p ** 2).sum(1, keepdim=True)
    solution = torch.linalg.lstsq(design, target, driver="gelsd").solution[:2, 0]
    spread = float((p - p.mean(0)).norm(dim=1).max())
    if not bool(torch.isfinite(solution).all()) or float(
            (solution - p.mean(0)).norm()) > 100 * max(spread, 1e-12):
        return p.mean(0)
    return solution


def _load(path: Path, text: str, done: bool) -> dict:
    """A stored fit (``done``) or checkpoint of the reader whose settings and frames read
    ``text``, weights only (no code runs); UserError naming the file where it is damaged or
    another fit's."""
    what = "fit" if done else "checkpoint"
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(obj, dict) or obj.get("format") != STORE_FORMAT:
            raise ValueError("not a keypoint reader's file")
        if obj.get("key") != text:
            raise ValueError("another fit's (other settings or frames)")
        if not done and not 0 < int(obj["step"]):
            raise ValueError(f"step {obj['step']!r}")
        return obj
    except (OSError, RuntimeError, EOFError, ValueError, KeyError, TypeError,
            pickle.UnpicklingError) as e:
        why = (str(e).strip().splitlines() or [type(e).__name__])[0]  # (torch's run long)
        raise UserError(f"{path}: the keypoint reader's stored {what} cannot be used ({why}); "
                        "delete it to fit again") from e
