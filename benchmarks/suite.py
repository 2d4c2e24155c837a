"""The estimator's defaults on systems nobody tuned them to: one command, one table.

Each system is a small image data set written here from a seed (nothing is downloaded); every
row fits ``LatentSINDy(latent_dim=...)`` with the library's defaults only, and measures on
the test sequences:

- one-step: the image MSE of ``predict`` over that of "nothing moves" (the next frame taken
  to be the current one), as a ratio (> 1: better than nothing moves);
- rollout: the same over the whole sequence, simulated from its first frame;
- reconstruction ceiling: the one-step ratio a perfect latent step would reach, the next
  frames encoded and decoded (what the autoencoder's pictures allow the dynamics);
- terms: active SINDy terms, and how many of them hold an action;
- law: for a video of a known law, whether it was recovered;
- the wall time of the fit.

    python benchmarks/suite.py                           # every system, seeds 0 1 2
    python benchmarks/suite.py --systems disc --seeds 0..7
    python benchmarks/suite.py --systems push --seeds 0 1     # the pushing world
    python benchmarks/suite.py --set batch_size=500 prune=absolute   # another setting, A/B
    python benchmarks/suite.py --systems dmc --seeds 0     # where dm_control is installed
    python benchmarks/suite.py --systems video --seeds 0..9 --omega2 1.44   # 20-60 min a seed
    python benchmarks/suite.py --smoke                     # lorenz, one seed, one epoch (tests)

The video row fits in continuous time (``time="continuous", derivative_order=2``) and is
judged by the law it recovers: z̈ = c sin z with c within 2 % of −ω².

``--set`` changes a training setting for every row (to compare against the defaults in the
same run); the table says which. Rows run in ``--workers`` processes of one torch thread.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from latent_sindy.script_args import (
    check_output_file,
    parse_with_smoke,
    positive_float,
    positive_int,
    seed_range,
)

SEQUENCES, STEPS = 60, 8


@dataclass(frozen=True)
class System:
    """A data generator and the latent size a user would pick for it; ``law``: a video of a
    known continuous-time law (``law(seed) -> (data, true coefficient)``), fitted in
    continuous time and judged by the law it recovers instead of by prediction."""

    make: object  # (seed) -> SequenceData
    latent_dim: int
    what: str
    law: bool = False


def _render(centres: np.ndarray, shape: tuple[int, int], radius: float, colour: np.ndarray,
            background: np.ndarray) -> np.ndarray:
    """Frames (..., C, H, W) uint8 of a soft-edged disc at ``centres`` (..., 2) in pixels."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = np.hypot(xx - centres[..., 0, None, None], yy - centres[..., 1, None, None])
    alpha = 1.0 / (1.0 + np.exp((d - radius) / 0.5))  # (..., H, W)
    img = background[:, None, None] + alpha[..., None, :, :] * (colour - background)[:, None, None]
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def _disc(seed: int, shape=(20, 28), channels=3, speed=0.2, radius=3.0, actions=True):
    """A disc moved by a 2-D velocity (pixels per step: ``speed`` of the image's short side
    per unit action), or, without actions, turning on a circle at a fixed rate."""
    from latent_sindy import SequenceData

    rng = np.random.default_rng(seed)
    h, w = shape
    colour = np.array([230, 60, 40][:channels] if channels == 3 else [220] * channels, float)
    background = np.array([20, 30, 90][:channels] if channels == 3 else [30] * channels, float)
    lo = np.array([radius + 1, radius + 1])
    hi = np.array([w - radius - 2, h - radius - 2])
    if actions:
        u = rng.uniform(-1, 1, (SEQUENCES, STEPS, 2)).astype(np.float32)
        p = np.empty((SEQUENCES, STEPS + 1, 2))
        p[:, 0] = rng.uniform(lo, hi, (SEQUENCES, 2))
        for t in range(STEPS):
            p[:, t + 1] = np.clip(p[:, t] + speed * min(h, w) * u[:, t], lo, hi)
        images = _render(p, shape, radius, colour, background)
        return SequenceData(images, u, [-1, -1], [1, 1], seed=seed)
    phase = rng.uniform(0, 2 * np.pi, SEQUENCES)[:, None] + 0.3 * np.arange(STEPS + 1)
    r = rng.uniform(0.15, 0.3, SEQUENCES)[:, None] * min(h, w)
    centre = np.array([w / 2, h / 2])
    p = centre + np.stack([r * np.cos(phase), r * np.sin(phase)], -1)
    return SequenceData(_render(p, shape, radius, colour, background), seed=seed)


def _lorenz(seed: int, dt: float = 0.02):
    """Lorenz (σ 10, ρ 28, β 8/3) seen through a fixed spatial embedding, the SINDy
    autoencoder paper's set-up: x(y) = Σ_i u_i(y) z_i + Σ_i u_{3+i}(y) z_i³ with the Legendre
    polynomials u_1..u_6 on 256 points, shown as a float image (1, 16, 16) in [0, 1]; starts
    on the attractor, no actions."""
    from latent_sindy import SequenceData

    rng = np.random.default_rng(seed)

    def rhs(z):
        return np.stack([10 * (z[:, 1] - z[:, 0]), z[:, 0] * (28 - z[:, 2]) - z[:, 1],
                         z[:, 0] * z[:, 1] - 8 / 3 * z[:, 2]], 1)

    def rk4(z, h):
        k1 = rhs(z)
        k2 = rhs(z + h / 2 * k1)
        k3 = rhs(z + h / 2 * k2)
        return z + h / 6 * (k1 + 2 * k2 + 2 * k3 + rhs(z + h * k3))

    z = rng.normal(0, 10, (SEQUENCES, 3)) + np.array([0.0, 0.0, 25.0])
    for _ in range(500):  # onto the attractor
        z = rk4(z, 0.01)
    path = [z]
    for _ in range(STEPS):
        for _ in range(4):
            z = rk4(z, dt / 4)
        path.append(z)
    z = np.stack(path, 1) / 20  # (N, T+1, 3), about unit size
    y = np.linspace(-1, 1, 256)
    modes = np.stack([np.polynomial.legendre.Legendre.basis(i)(y) for i in range(6)])
    x = z @ modes[:3] + z ** 3 @ modes[3:]  # (N, T+1, 256)
    x = (x - x.min()) / (x.max() - x.min())
    return SequenceData(x.reshape(SEQUENCES, STEPS + 1, 1, 16, 16).astype(np.float32),
                        seed=seed, dt=dt)


def _pendulum(seed: int):
    """The controlled pendulum's images (two stacked 48x48 frames) under random torques."""
    from latent_sindy.plugins import get_world

    return get_world("pendulum").collect(SEQUENCES, STEPS, seed=seed)


def _push(seed: int):
    """The pushing world's 32x32 overhead images of a Panda pushing a block, random pushes
    (collected into a temporary file and read back, as a user would)."""
    import tempfile
    from pathlib import Path

    from latent_sindy.data.store import read_sequences
    from latent_sindy.worlds.push.collect import CollectionPlan, collect

    with tempfile.TemporaryDirectory() as tmp:
        path = collect(Path(tmp) / "push.h5", CollectionPlan(SEQUENCES, STEPS, seed),
                       workers=1)
        return read_sequences(path)


#: ω² of the pendulum video (θ̈ = −ω² sin θ): not the benchmark's 1 (``--omega2``).
OMEGA2 = [1.44]


def _video(seed: int):
    """The pendulum video benchmark's generator at ω² = :data:`OMEGA2` (every 5th frame of
    51x51, exact derivatives, 100/10/10 trajectories; the data seed 0 for every model seed)."""
    from latent_sindy.worlds.pendulum.video import pendulum_video

    return pendulum_video(omega2=OMEGA2[0], frames_every=5)


def _dmc(seed: int):
    """The DeepMind Control suite's cartpole-swingup, two stacked 32x32 RGB frames, each
    random action held 8 control steps (PlaNet's repeat)."""
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.plugin import DmcWorld

    return DmcWorld(DmcConfig(task="cartpole-swingup", size=32)).collect(SEQUENCES, STEPS,
                                                                         seed=seed)


SYSTEMS: dict[str, System] = {
    "disc": System(lambda s: _disc(s), 2, "RGB 20x28 disc, 2-D velocity, 0.2 of a side a step"),
    "disc-gray": System(lambda s: _disc(s, (16, 16), 1, 0.1, 2.5), 2,
                        "gray 16x16 disc, 2-D velocity, 0.1 of a side a step"),
    "disc-slow": System(lambda s: _disc(s, (32, 32), 3, 0.05, 4.0), 2,
                        "RGB 32x32 disc, 2-D velocity, 0.05 of a side a step"),
    "orbit": System(lambda s: _disc(s, (24, 24), 1, actions=False), 2,
                    "gray 24x24 disc on a circle (no actions), 0.3 rad a step"),
    "lorenz": System(_lorenz, 3, "Lorenz through a fixed 256-point embedding (no actions)"),
    "pendulum": System(_pendulum, 3, "controlled pendulum, two stacked 48x48 frames"),
    "push": System(_push, 4, "Panda pushing a block, 32x32 overhead RGB, random pushes"),
    "video": System(_video, 1, "pendulum video, 51x51, θ̈ = −ω² sin θ (ω² = --omega2)",
                    law=True),
}
if importlib.util.find_spec("dm_control") is not None:  # the dmc extra: a row where installed
    SYSTEMS["dmc"] = System(_dmc, 6, "dm_control cartpole-swingup, two stacked 32x32 RGB frames")


def _setting(text: str) -> tuple[str, object]:
    key, eq, value = text.partition("=")
    if not eq or not key:
        raise argparse.ArgumentTypeError(f"{text!r} is not KEY=VALUE (e.g. batch_size=500)")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def _check_settings(p: argparse.ArgumentParser, pairs: list[tuple[str, object]]) -> dict:
    """The --set settings as fit takes them, or p.error before any fit runs: a key given
    twice, one that is no training setting (with the closest), or a value TrainConfig
    refuses."""
    from latent_sindy.configs import from_json
    from latent_sindy.errors import UserError
    from latent_sindy.training.config import TrainConfig, check_fit_settings

    settings = dict(pairs)
    if len(settings) < len(pairs):
        p.error("--set: a KEY is given twice; give each setting once")
    try:
        check_fit_settings(dict(settings), None)
    except UserError as e:
        p.error(f"--set: {e}")
    try:
        from_json(TrainConfig, settings, "--set")
    except UserError as e:
        p.error(str(e))
    return settings


def run_row(name: str, seed: int, settings: dict[str, object]) -> dict[str, object]:
    """Fit ``name``'s data of ``seed`` with the defaults (and ``settings``) and measure it; a
    fit that fails is a row with its error (and a failing benchmark)."""
    try:
        return _measure(name, seed, settings)
    except Exception as e:  # (the table shows it; the other rows go on)
        return {"system": name, "seed": seed, "error": f"{type(e).__name__}: {e}",
                "one_step": math.nan, "rollout": math.nan, "terms": 0, "action_terms": 0,
                "wall_s": math.nan, "kept_epoch": None}


def _measure(name: str, seed: int, settings: dict[str, object]) -> dict[str, object]:
    import torch

    from latent_sindy import LatentSINDy

    torch.set_num_threads(1)
    system = SYSTEMS[name]
    data = system.make(seed)
    if system.law:
        return _law(name, seed, data, settings)
    t0 = time.perf_counter()
    est = LatentSINDy(system.latent_dim, seed=seed).fit(data, **settings)
    wall = time.perf_counter() - t0
    test = data.split("test")
    x = test.images.astype(np.float64)
    nu = test.actions.shape[-1]
    frames = test.images[:, :-1].reshape(-1, *test.frame_shape)
    u = test.actions.reshape(len(frames), nu)
    pred = est.predict(frames, u).astype(np.float64).reshape(x[:, 1:].shape)
    one = float(((pred - x[:, 1:]) ** 2).mean())
    still = float(((x[:, :-1] - x[:, 1:]) ** 2).mean())
    rolled = np.stack([est.simulate(test.images[i, 0], test.actions[i])[1]
                       for i in range(test.n)]).astype(np.float64)
    roll = float(((rolled[:, 1:] - x[:, 1:]) ** 2).mean())
    roll_still = float(((x[:, :1] - x[:, 1:]) ** 2).mean())
    following = test.images[:, 1:].reshape(-1, *test.frame_shape)
    seen = est.simulate(following, np.zeros((len(following), 0, nu), np.float32))[1]
    recon = float(((seen[:, 0].astype(np.float64).reshape(x[:, 1:].shape) - x[:, 1:]) ** 2).mean())
    dyn = est.model_.dynamics
    mask = dyn.mask.cpu().numpy()  # (p, nz)
    names = list(dyn.library.names)
    action_terms = int(sum(mask[k].sum() for k, n in enumerate(names) if "u" in n))
    return {"system": name, "seed": seed, "one_step": still / one, "rollout": roll_still / roll,
            "ceiling": still / recon,
            "terms": int(mask.sum()), "action_terms": action_terms, "actions": nu,
            "wall_s": wall, "kept_epoch": est.kept_["epoch"]}


def _law(name: str, seed: int, data, settings: dict[str, object]) -> dict[str, object]:
    """The continuous-time defaults on a pendulum video: whether the equation is
    z̈ = c sin z with c within 2 % of −ω² (the sign of z is the model's choice)."""
    from latent_sindy import LatentSINDy

    t0 = time.perf_counter()
    est = LatentSINDy(1, time="continuous", derivative_order=2, seed=seed).fit(data, **settings)
    wall = time.perf_counter() - t0
    names, coef = est.get_feature_names(), est.coefficients()[0]
    active = [n for n, c in zip(names, coef, strict=True) if c != 0]
    c = float(coef[names.index("sin(z0)")]) if active == ["sin(z0)"] else math.nan
    return {"system": name, "seed": seed, "one_step": math.nan, "rollout": math.nan,
            "terms": len(active), "action_terms": 0, "actions": 0, "wall_s": wall,
            "kept_epoch": est.kept_["epoch"], "law": c, "omega2": OMEGA2[0],
            "recovered": bool(abs(c / OMEGA2[0] + 1) <= 0.02), "equation": est.equations()[0]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=list(SYSTEMS))
    p.add_argument("--seeds", nargs="+", type=seed_range, default=[[0, 1, 2]],
                   help="seeds: 0 1 2, 0..7 or 0,3,5")
    p.add_argument("--set", nargs="*", type=_setting, default=[], metavar="KEY=VALUE",
                   help="training settings for every row (TrainConfig fields)")
    p.add_argument("--workers", type=positive_int, default=2)
    p.add_argument("--json", help="also write the rows to this file")
    p.add_argument("--omega2", type=positive_float, default=OMEGA2[0],
                   help="ω² of the pendulum video (the video system)")
    args = parse_with_smoke(p, argv, {"systems": ["lorenz"], "seeds": [[0]],
                                      "set": [("epochs", 1)], "workers": 1})
    # every mistake is refused here, before the first fit (argparse's line, exit status 2)
    settings = _check_settings(p, args.set)
    check_output_file(p, args.json, "--json")
    seeds = [s for group in args.seeds for s in group]
    if len(set(seeds)) < len(seeds):
        p.error(f"--seeds: a seed is given twice ({' '.join(map(str, seeds))})")
    OMEGA2[0] = args.omega2
    jobs = [(n, s) for n in args.systems for s in seeds]
    print(f"{len(jobs)} fits, settings: {settings or 'the defaults'}", file=sys.stderr)
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:
        futures = [pool.submit(run_row, n, s, settings) for n, s in jobs]
        for f in futures:
            rows.append(f.result())
            r = rows[-1]
            if "error" in r:
                print(f"  {r['system']} seed {r['seed']}: FAILED {r['error']}", file=sys.stderr)
                continue
            if "law" in r:
                print(f"  {r['system']} seed {r['seed']}: {r['equation']}, recovered "
                      f"{'yes' if r['recovered'] else 'no'}, {r['wall_s']:.0f} s",
                      file=sys.stderr)
                continue
            print(f"  {r['system']} seed {r['seed']}: one-step {r['one_step']:.1f}x (the "
                  f"reconstructions allow {r['ceiling']:.1f}x), rollout {r['rollout']:.1f}x, "
                  f"{r['terms']} terms ({r['action_terms']} with u), {r['wall_s']:.0f} s",
                  file=sys.stderr)
    print(table(rows, args.systems))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"settings": settings, "rows": rows}, f, indent=1)
    bad = [r for r in rows if "error" in r or ("law" in r and not r["recovered"])]
    return 1 if bad else 0


def table(rows: list[dict[str, object]], systems: list[str]) -> str:
    """The markdown table of the rows, one line a system ("-": not measured there)."""
    out = ["\n| system | seeds | one-step vs nothing moves (min / median) | seeds >= 3x | "
           "reconstruction ceiling (median) | rollout (median) | terms (median) | "
           "action terms kept | law recovered | wall s (median) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for name in systems:
        rs = [r for r in rows if r["system"] == name and "error" not in r]
        failed = sum(r["system"] == name and "error" in r for r in rows)
        if not rs:
            out.append(f"| {name} | {failed} failed | - | - | - | - | - | - | - | - |")
            continue
        one = [r["one_step"] for r in rs]
        law = [r for r in rs if "law" in r]
        acted = sum(r["action_terms"] > 0 for r in rs)
        out.append(
            f"| {name} | {len(rs)}{f' ({failed} failed)' if failed else ''} | "
            + ("- | - | - | - | " if law else
               f"{min(one):.1f}x / {np.median(one):.1f}x | {sum(o >= 3 for o in one)} of "
               f"{len(rs)} | {np.median([r['ceiling'] for r in rs]):.1f}x | "
               f"{np.median([r['rollout'] for r in rs]):.1f}x | ")
            + f"{np.median([r['terms'] for r in rs]):.0f} | "
            + (f"{acted} of {len(rs)}" if rs[0]["actions"] else "-") + " | "
            + (f"{sum(r['recovered'] for r in law)} of {len(law)} at ω² = {law[0]['omega2']:g}"
               if law else "-")
            + f" | {np.median([r['wall_s'] for r in rs]):.0f} |")
    return "\n".join(out)


if __name__ == "__main__":
    raise SystemExit(main())
