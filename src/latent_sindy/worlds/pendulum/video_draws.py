"""Videos drawn from a family of systems: the estimator judged on layouts nobody chose.

A :class:`VideoDraw` is one video: a system (a damped pendulum, a damped spring sliding a
block along a line, or two independent damped pendulums), its parameters, and how it is
filmed (frame side, blob width, where the motion sits in the frame, how many trajectories, how
long, how often sampled, pixel noise, a static background, exact derivatives or none).
:func:`draw` picks every one of them at random from wide ranges (:data:`RANGES`), so a
benchmark over many draws measures how a default does on videos it was not tuned on.

    >>> import numpy as np
    >>> from latent_sindy.worlds.pendulum.video_draws import draw
    >>> d = draw(np.random.default_rng(3))
    >>> video = d.video()               # SequenceData: frames, maybe exact derivatives
    >>> d.law()                         # the true law in the latent's coordinates
    >>> d.judge(model)                  # did a fitted LatentSINDy recover it, and why not

The frame spans [−1, 1]² (x left to right, y bottom to top); a blob at p is
exp(−|P − p|²/w). The derivatives are exact by the chain rule through the blob's path p(q):
ẋ = ∇f·ṗ, ẍ = ṗᵀ∇²f ṗ + ∇f·p̈ with ṗ = J q̇, p̈ = J q̈ + (∂²p/∂q²) q̇².
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from latent_sindy.data.sequence import SequenceData
from latent_sindy.errors import UserError

__all__ = ["RANGES", "SYSTEMS", "VideoDraw", "draw", "judge_equations", "law_text", "true_law"]

SYSTEMS = ("pendulum", "spring", "two_pendulums")
"""The systems of the family: θ̈ = −ω² sin θ − c θ̇ (a blob on a circle); x″ = −k x − c x′
(a blob sliding on a line); two pendulums of their own ω² and c, side by side (latent_dim=2)."""

RANGES: dict[str, tuple[float, float]] = {
    "omega2": (0.3, 4.0),          # ω² (the spring's k)
    "damping_ratio": (0.0, 0.3),   # c/ω, with c itself at most 0.4
    "size": (24, 80),              # frame side in pixels
    "trajectories": (20, 200),
    "frames": (40, 400),           # per trajectory
    "dt": (0.01, 0.15),            # seconds between frames, at least 8 frames a period
    "noise": (0.0, 0.02),          # pixel noise, a share of the frames' spread
}
"""The ranges :func:`draw` samples from (sizes and counts log-uniformly)."""

MAX_DAMPING = 0.4
UNDAMPED_SHARE = 0.3
"""The share of draws with no friction at all (c = 0: the frictionless law)."""
MIN_FRAMES_PER_PERIOD = 8
_SUBSTEPS = 20


@dataclass(frozen=True)
class VideoDraw:
    """One video of the family: what is filmed and how (see the module's docstring)."""

    system: str = "pendulum"
    omega2: tuple[float, ...] = (1.0,)
    """ω² (the spring's k), one per blob."""
    damping: tuple[float, ...] = (0.0,)
    """c of −c q̇, one per blob."""
    size: int = 51
    width: float = 0.02
    """The blob's squared width w in exp(−d²/w), frame units ([−1, 1] across)."""
    centre: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
    """Each blob's pivot (pendulum) or rest position (spring)."""
    radius: tuple[float, ...] = (0.6,)
    """The pendulum's length, or the spring's largest excursion, in frame units."""
    direction: tuple[float, ...] = (0.0,)
    """The spring's line (its angle from the x axis, radians); unused by pendulums."""
    trajectories: int = 100
    frames: int = 100
    dt: float = 0.05
    noise: float = 0.0
    """Gaussian pixel noise, a share of the clean frames' standard deviation."""
    background: float = 0.0
    """Amplitude of a static smooth background (0: none)."""
    exact: bool = True
    """The video carries its exact image derivatives (else the library estimates them)."""
    seed: int = 0
    extras: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if self.system not in SYSTEMS:
            raise UserError(f"system {self.system!r}: use one of {', '.join(SYSTEMS)}")
        blobs = 2 if self.system == "two_pendulums" else 1
        for name in ("omega2", "damping", "centre", "radius", "direction"):
            if len(getattr(self, name)) != blobs:
                raise UserError(f"{name} {getattr(self, name)!r}: give one per blob ({blobs})")
        if min(self.omega2) <= 0 or min(self.damping) < 0:
            raise UserError(f"omega2 {self.omega2}, damping {self.damping}: use ω² > 0, c >= 0")

    @property
    def latent_dim(self) -> int:
        return 2 if self.system == "two_pendulums" else 1

    # ------------------------------------------------------------------ the truth
    def law(self) -> list[dict[str, float]]:
        """The true second-order law of each latent coordinate, term -> coefficient, in the
        library's names ("sin(z0)", "z0", "z0'"), for the blob the coordinate reads (two
        pendulums: the first blob's as z0; :meth:`judge` also accepts them swapped)."""
        return true_law(self.system, self.omega2, self.damping)

    def law_text(self) -> list[str]:
        return law_text(self.law())

    def judge(self, model: Any) -> dict[str, Any]:
        """Whether a fitted continuous-time ``model`` (a LatentSINDy) wrote the true law."""
        return judge_equations(self, model.get_feature_names(), model.coefficients())

    # ------------------------------------------------------------------ the video
    def states(self) -> np.ndarray:
        """(N, F, blobs, 3): each blob's q, q̇, q̈ at every frame."""
        rng = np.random.default_rng([self.seed, 1])
        n, f = self.trajectories, self.frames
        out = np.empty((n, f, self.latent_dim, 3))
        for b, (w2, c) in enumerate(zip(self.omega2, self.damping, strict=True)):
            start = _starts(self.system, n, w2, rng)
            out[:, :, b] = _integrate(self.system, start, f, self.dt, w2, c)
        return out

    def video(self) -> SequenceData:
        """The video as :class:`SequenceData` (float32 frames in [0, 1]; exact derivatives
        when :attr:`exact`; the true q, q̇ as states; 80/10/10 % of trajectories train,
        validation, test)."""
        q = self.states()  # (N, F, B, 3)
        axis = np.linspace(-1.0, 1.0, self.size)
        X, Y = np.meshgrid(axis, axis[::-1])
        n, f = q.shape[:2]
        shape = (n, f, 1, self.size, self.size)
        x = np.zeros(shape, np.float32)
        dx = np.zeros(shape, np.float32) if self.exact else None
        ddx = np.zeros(shape, np.float32) if self.exact else None
        for b in range(self.latent_dim):
            for i in range(n):  # one trajectory at a time: float64 temporaries stay small
                p, dp, ddp = self._path(b, q[i, :, b])
                img, d1, d2 = _blob(X, Y, p, dp, ddp, self.width)
                x[i, :, 0] += img
                if self.exact:
                    dx[i, :, 0] += d1
                    ddx[i, :, 0] += d2
        rng = np.random.default_rng([self.seed, 2])
        if self.background > 0:
            x += self.background * _background(X, Y, rng).astype(np.float32)
        if self.noise > 0:  # one trajectory at a time: no float64 array of the whole video
            sd = self.noise * float(x.std())
            for i in range(n):
                x[i] += sd * rng.standard_normal(x.shape[1:], dtype=np.float32)
        top = float(x.max())
        low = float(x.min())
        scale = 1.0 / (top - low)  # frames in [0, 1]; derivatives scaled alike
        x = np.clip((x - low) * scale, 0.0, 1.0)  # (float32 rounding may pass 1 by an ulp)
        if self.exact:
            dx *= scale
            ddx *= scale
        counts = _split_counts(n)
        split = np.repeat(np.arange(3, dtype=np.uint8), counts)
        names = tuple(n for b in range(self.latent_dim) for n in (f"q{b}", f"q{b}_dot"))
        states = q[..., :2].reshape(n, f, -1).astype(np.float32)
        return SequenceData(
            x, None, states=states, state_names=names, split=split, dt=self.dt,
            world="pendulum-video", images_dot=dx, images_ddot=ddx,
            record={"video_draw": self.to_dict()}, seed=self.seed,
            source=f"<video draw {self.seed}: {self.system}>")

    def _path(self, b: int, q: np.ndarray) -> tuple[np.ndarray, ...]:
        """The blob's centre p, ṗ, p̈ (F, 2) along q, q̇, q̈ (F, 3)."""
        th, w, a = q[:, 0], q[:, 1], q[:, 2]
        cx, cy = self.centre[b]
        r = self.radius[b]
        if self.system == "spring":
            d = np.array([math.cos(self.direction[b]), math.sin(self.direction[b])])
            p = np.array([cx, cy]) + r * th[:, None] * d
            return p, r * w[:, None] * d, r * a[:, None] * d
        s, c = np.sin(th), np.cos(th)  # the pendulum hangs down at θ = 0
        p = np.stack([cx + r * s, cy - r * c], axis=1)
        dp = np.stack([r * c * w, r * s * w], axis=1)
        ddp = np.stack([r * (c * a - s * w ** 2), r * (s * a + c * w ** 2)], axis=1)
        return p, dp, ddp

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("extras")
        return d

    def describe(self) -> str:
        law = "; ".join(f"z{i}'' = {t}" for i, t in enumerate(self.law_text()))
        return (f"{self.system} [{law}], {self.trajectories}x{self.frames} frames of "
                f"{self.size}px at dt {self.dt:.3g}, noise {self.noise:.3g}, background "
                f"{self.background:.2g}, {'exact derivatives' if self.exact else 'frames only'}")


def _split_counts(n: int) -> list[int]:
    val = max(1, round(0.1 * n))
    test = max(1, round(0.1 * n)) if n >= 3 else 0
    return [n - val - test, val, test]


def _starts(system: str, n: int, w2: float, rng: np.random.Generator) -> np.ndarray:
    """n starts (q, q̇) that stay bounded: pendulums below the top (energy under 0.99 of
    the separatrix's), springs within an excursion of 1."""
    out: list[np.ndarray] = []
    omega = math.sqrt(w2)
    count = 0
    while count < n:
        q = rng.uniform(-math.pi if system != "spring" else -1.0,
                        math.pi if system != "spring" else 1.0, 2 * n)
        v = rng.uniform(-2.1 * omega, 2.1 * omega, 2 * n) if system != "spring" \
            else rng.uniform(-omega, omega, 2 * n)
        if system == "spring":
            ok = q ** 2 + v ** 2 / w2 <= 1.0
        else:
            ok = np.abs(v ** 2 / 2 - w2 * np.cos(q)) <= 0.99 * w2
        out.append(np.stack([q[ok], v[ok]], axis=1))
        count += int(ok.sum())
    return np.concatenate(out)[:n]


def _accel(system: str, q: np.ndarray, v: np.ndarray, w2: float, c: float) -> np.ndarray:
    return (-w2 * q if system == "spring" else -w2 * np.sin(q)) - c * v


def _integrate(system: str, start: np.ndarray, frames: int, dt: float, w2: float,
               c: float) -> np.ndarray:
    """(n, frames, 3): q, q̇, q̈ by classic Runge-Kutta at dt/20, float64."""
    x = np.asarray(start, np.float64).copy()
    out = np.empty((len(x), frames, 3))
    h = dt / _SUBSTEPS

    def rhs(s: np.ndarray) -> np.ndarray:
        return np.stack([s[:, 1], _accel(system, s[:, 0], s[:, 1], w2, c)], axis=1)

    for k in range(frames):
        out[:, k, :2] = x
        if k == frames - 1:
            break
        for _ in range(_SUBSTEPS):
            k1 = rhs(x)
            k2 = rhs(x + h / 2 * k1)
            k3 = rhs(x + h / 2 * k2)
            k4 = rhs(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    out[:, :, 2] = _accel(system, out[:, :, 0], out[:, :, 1], w2, c)
    return out


def _blob(X: np.ndarray, Y: np.ndarray, p: np.ndarray, dp: np.ndarray, ddp: np.ndarray,
          w: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A blob's frames f, ḟ, f̈ (F, H, W) along its centre's path p, ṗ, p̈ (F, 2)."""
    a = X[None] - p[:, 0, None, None]  # (F, H, W)
    b = Y[None] - p[:, 1, None, None]
    f = np.exp(-(a ** 2 + b ** 2) / w)
    gx, gy = 2 * a / w, 2 * b / w  # ∇_p f = f (gx, gy)
    vx, vy = dp[:, 0, None, None], dp[:, 1, None, None]
    ax, ay = ddp[:, 0, None, None], ddp[:, 1, None, None]
    grad_v = gx * vx + gy * vy
    f1 = f * grad_v
    # ṗᵀ ∇²f ṗ with ∇²_p f = f (g gᵀ − (2/w) I)
    f2 = f * (grad_v ** 2 - (2 / w) * (vx ** 2 + vy ** 2) + gx * ax + gy * ay)
    return f, f1, f2


def _background(X: np.ndarray, Y: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A smooth static pattern in [0, 1]: a tilt plus three broad bumps."""
    tilt = rng.normal(0.0, 0.3, 2)
    g = tilt[0] * X + tilt[1] * Y
    for _ in range(3):
        cx, cy = rng.uniform(-1, 1, 2)
        g = g + rng.uniform(-1, 1) * np.exp(-((X - cx) ** 2 + (Y - cy) ** 2) / rng.uniform(0.2, 1))
    return (g - g.min()) / max(float(np.ptp(g)), 1e-12)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def draw(rng: np.random.Generator, system: str | None = None,
         exact: bool | None = None) -> VideoDraw:
    """One video of the family, every choice drawn from ``rng`` within :data:`RANGES`
    (``system`` and ``exact``: fixed instead of drawn). The draw's own seed (its noise and
    starts) comes from ``rng`` too, so the same generator state gives the same video."""
    drawn = str(rng.choice(["pendulum", "pendulum", "spring", "two_pendulums"]))
    system = system or drawn  # (drawn either way: the draws after it stay the same)
    blobs = 2 if system == "two_pendulums" else 1
    lo, hi = RANGES["omega2"]
    omega2 = tuple(float(rng.uniform(lo, hi)) for _ in range(blobs))
    damping = tuple(
        0.0 if rng.uniform() < UNDAMPED_SHARE
        else float(rng.uniform(0, min(MAX_DAMPING, RANGES["damping_ratio"][1] * math.sqrt(w2))))
        for w2 in omega2)
    size = round(_log_uniform(rng, *RANGES["size"]))
    # the blob at least about 1.2 pixels wide (std), at most a tenth of the frame
    pixel = 2.0 / size
    width = _log_uniform(rng, max(0.004, 3.0 * pixel ** 2), 0.03)
    margin = 2.0 * math.sqrt(width / 2) + pixel
    if blobs == 1:
        radius = (float(rng.uniform(0.35, 0.8)),)
        room = max(0.0, 1.0 - margin - radius[0])
        centre = ((float(rng.uniform(-room, room)), float(rng.uniform(-room, room))),)
    else:  # two pendulums, one in each half of the frame
        r = float(rng.uniform(0.2, 0.42))
        radius = (r, float(rng.uniform(0.2, 0.42)))
        centre = tuple((s * 0.5, float(rng.uniform(-0.1, 0.1))) for s in (-1.0, 1.0))
    direction = tuple(float(rng.uniform(0, math.pi)) for _ in range(blobs))
    if system == "spring":  # the line must fit: the excursion along it from the centre
        radius = (float(rng.uniform(0.35, 0.8)),)
        room = max(0.0, 1.0 - margin - radius[0])
        centre = ((float(rng.uniform(-room, room)), float(rng.uniform(-room, room))),)
    period = 2 * math.pi / math.sqrt(max(omega2))
    dt = _log_uniform(rng, RANGES["dt"][0], min(RANGES["dt"][1], period / MIN_FRAMES_PER_PERIOD))
    trajectories = round(_log_uniform(rng, *RANGES["trajectories"]))
    frames = round(_log_uniform(rng, *RANGES["frames"]))
    noise = float(rng.uniform(*RANGES["noise"])) if rng.uniform() < 0.7 else 0.0
    background = float(rng.uniform(0.1, 0.5)) if rng.uniform() < 0.3 else 0.0
    with_rates = bool(rng.uniform() < 0.5)
    exact = with_rates if exact is None else exact
    return VideoDraw(system=system, omega2=omega2, damping=damping, size=size, width=width,
                     centre=centre, radius=radius, direction=direction,
                     trajectories=trajectories, frames=frames, dt=dt, noise=noise,
                     background=background, exact=exact,
                     seed=int(rng.integers(2 ** 31)))


def true_law(system: str, omega2: tuple[float, ...], damping: tuple[float, ...]
             ) -> list[dict[str, float]]:
    """Each latent's law, term -> coefficient in the library's names: −ω² sin z (a spring's
    −k z) and, where c > 0, −c z'."""
    out = []
    for i, (w2, c) in enumerate(zip(omega2, damping, strict=True)):
        terms = {f"sin(z{i})" if system != "spring" else f"z{i}": -w2}
        if c > 0:
            terms[f"z{i}'"] = -c
        out.append(terms)
    return out


def law_text(law: list[dict[str, float]]) -> list[str]:
    """Each latent's law as a line of signed terms."""
    return [" ".join(f"{v:+.4g} {k}" for k, v in terms.items()) for terms in law]


_SWAP = re.compile(r"z([01])")


def _swapped(name: str) -> str:
    return _SWAP.sub(lambda m: f"z{1 - int(m.group(1))}", name)


def judge_equations(d: VideoDraw, names: list[str], coef: np.ndarray,
                    tolerance: float = 0.05, friction_tolerance: float = 0.10
                    ) -> dict[str, Any]:
    """Did the coefficients ``coef`` (latents × terms ``names``) write ``d``'s true law?

    Every true term present with its coefficient within ``tolerance`` (friction, the z'
    term, within ``friction_tolerance``), and no other term, except a constant for the
    spring (its latent's zero may sit anywhere on the line: z̈ = −k (z − z*) − c ż). The
    latent's sign is free (each law is odd in z), and two pendulums may come in either
    order. Returns ``recovered`` and, when not, ``why``: "all terms pruned", "missed
    TERM", "wrong term TERM" or "TERM off by P %"."""
    coef = np.asarray(coef, dtype=float)
    law = d.law()
    orders = [law] if len(law) == 1 else [law, [
        {_swapped(k): v for k, v in law[1].items()}, {_swapped(k): v for k, v in law[0].items()}]]
    if not np.any(coef):
        return {"recovered": False, "why": "all terms pruned"}
    best: dict[str, Any] | None = None
    for truth in orders:
        whys = []
        for i, terms in enumerate(truth):
            found = {n: float(c) for n, c in zip(names, coef[i], strict=True) if c != 0}
            if d.system == "spring":
                found.pop("1", None)
            whys += _compare(terms, found, tolerance, friction_tolerance)
        verdict = {"recovered": not whys, "why": "; ".join(whys)}
        if best is None or len(whys) < len(best["why"].split("; ")):
            best = verdict
        if not whys:
            return verdict
    return best


def _compare(terms: dict[str, float], found: dict[str, float], tol: float,
             friction_tol: float) -> list[str]:
    whys = [f"wrong term {n}" for n in found if n not in terms]
    for n, v in terms.items():
        if n not in found:
            whys.append(f"missed {n}")
            continue
        limit = friction_tol if n.endswith("'") else tol
        off = abs(found[n] - v) / abs(v)
        if not off <= limit:  # (NaN: off)
            whys.append(f"{n} off by {100 * off:.0f} %")
    return whys
