"""Which pushing world should be the default? Measures each named world design side by side.

For every design (``latent_sindy.worlds.push.config.ENV_PRESETS``: "symmetric", "marked", "paper"):

  (i)   look-alike test: pairs of poses whose images are identical (theta and theta + pi/2 of
        the uniform square block), pushed with the same random action from a fresh world:
        the fraction whose next images differ (the same picture and push should never lead
        to different pictures; a marked block has no such pairs);
  (ii)  reach: the fraction of pushes that execute (start pose uniform in the workspace,
        action uniform in the world's box), overall and in 8 bins of the push direction
        relative to the direction from the robot's base to the block (0 = away from it);
  (iii) control with perfect information: ~150 random trajectories of 10 pushes collected
        with ``latent_sindy.worlds.push.collect``, a small residual MLP fitted on the true poses
        encoded as the images can show them, (x, y, cos 2 pi theta/P, sin 2 pi theta/P) with
        P the world's ``angle_period``, and actions with angles as cos/sin, then the project's
        MPPI (cost: squared distance to the goal position) on random tasks: success within 20
        pushes under the course criterion (0.1 m) and the strict one (0.02 m, 10 degrees mod P).

Rates come with 95 % Wilson intervals. Two worker processes, torch on one thread; about 6
minutes on 2 cores with the defaults.

    PYTHONPATH=src python benchmarks/world_designs.py --seed 0
    PYTHONPATH=src python benchmarks/world_designs.py --designs symmetric marked --pairs 10 \\
        --pushes 60 --trajectories 20 --tasks 5          # a quick look (about 2 minutes)
"""

from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from latent_sindy.worlds.push.episodes import wilson_interval

DESIGNS = ("symmetric", "marked", "paper")
N_BINS = 8


# --------------------------------------------------------------------------- statistics
wilson = wilson_interval  # 95 % Wilson score interval of a binomial rate k/n


def rate(k: int, n: int) -> str:
    if n == 0:
        return "n/a"
    lo, hi = wilson(k, n)
    return f"{100 * k / n:5.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] ({k}/{n})"


# --------------------------------------------------------------------------- worker side
_envs: dict = {}


def _env(design: str):
    if design not in _envs:
        from latent_sindy.worlds.push.config import PushEnvConfig
        from latent_sindy.worlds.push.panda_push import PandaPushEnv

        _envs[design] = PandaPushEnv(PushEnvConfig.named(design))
    return _envs[design]


def _worker_init() -> None:
    import torch

    torch.set_num_threads(1)


def push_direction(cfg, pose: np.ndarray, action: np.ndarray) -> float:
    """World angle of a push's direction."""
    return float(action[1] if cfg.push == "symmetric" else pose[2] + action[1])


def probe_job(job: tuple[str, int, int, int]) -> list[dict]:
    """Pushes `first`..`first + n - 1` of the seeded reach / look-alike sample of a design."""
    design, seed, first, n = job
    env = _env(design)
    cfg = env.config
    out = []
    for i in range(first, first + n):
        rng = np.random.default_rng([seed, i])
        pose = rng.uniform(cfg.workspace_low, cfg.workspace_high)
        action = rng.uniform(cfg.action_low, cfg.action_high).astype(np.float32)
        turned = pose + np.array([0.0, 0.0, math.pi / 2])
        obs0, _ = env.reset(options={"start": pose, "goal": pose})
        obs1, *_, info = env.step(action)
        rec = {"executed": bool(info["push_executed"]),
               "rel": float(np.angle(np.exp(1j * (push_direction(cfg, pose, action)
                                                  - math.atan2(pose[1], pose[0]))))),
               "alike": None, "diverged": None}
        if i % 10 == 0:  # every tenth sample also serves the look-alike test
            obs0b, _ = env.reset(options={"start": turned, "goal": turned})
            rec["alike"] = bool(np.array_equal(obs0, obs0b))
            if rec["alike"]:
                obs1b, *_ = env.step(action)
                rec["diverged"] = not np.array_equal(obs1, obs1b)
        out.append(rec)
    return out


def control_job(job: tuple) -> list[dict]:
    """Closed-loop episodes `tasks` of a design with the reference model (a state dict)."""
    design, state, stats, tasks, seed, K, H, sigma, max_steps = job
    import torch

    from latent_sindy.control.mppi import MPPI, MPPIConfig

    env = _env(design)
    cfg = env.config
    model = make_mlp()
    model.load_state_dict(state)
    model.eval()
    step = model_step(model, stats)
    out = []
    for t in tasks:
        rng = np.random.default_rng([seed, 10_000 + t])
        start = rng.uniform(cfg.workspace_low, cfg.workspace_high)
        goal = rng.uniform(cfg.workspace_low, cfg.workspace_high)
        _, info = env.reset(options={"start": start, "goal": goal})
        g = torch.tensor(goal[:2], dtype=torch.float32)

        def cost(z: torch.Tensor, g=g) -> torch.Tensor:  # (..., 4) -> (...)
            return ((z[..., :2] - g) ** 2).sum(-1)

        mcfg = MPPIConfig(nu=cfg.action_dim, K=K, H=H, sigma=sigma, lambda_=0.01,
                          low=cfg.action_low, high=cfg.action_high, u_init=(0.0, 0.0, 0.5),
                          seed=int(rng.integers(2**31)))
        mppi = MPPI(step, cost, mcfg)
        # pushes until each criterion first held (0: at the start), None: never
        reached = 0 if info["is_success"] else None
        strict = 0 if info["is_success_strict"] else None
        for k in range(1, max_steps + 1):
            if reached is not None and strict is not None:
                break
            z = torch.tensor(encode_pose(info["pose"], cfg.angle_period), dtype=torch.float32)
            u, _ = mppi.command(z)
            _, _, terminated, _, info = env.step(u.numpy())
            if info["is_success"] and reached is None:
                reached = k
            if info["is_success_strict"] and strict is None:
                strict = k
            if terminated:
                break
        out.append({"success": reached is not None, "strict": strict is not None,
                    "steps": reached, "final_distance": float(info["distance"])})
    return out


# --------------------------------------------------------------------------- the reference model
def encode_pose(pose, period: float) -> np.ndarray:
    """(x, y, theta) -> (x, y, cos 2 pi theta/P, sin 2 pi theta/P): what an image can show."""
    pose = np.asarray(pose, dtype=np.float64)
    a = 2 * math.pi * pose[..., 2] / period
    return np.stack([pose[..., 0], pose[..., 1], np.cos(a), np.sin(a)], axis=-1)


def encode_action(u):
    """[p, angle, ell] -> [p, cos angle, sin angle, ell] (numpy array or torch tensor)."""
    if isinstance(u, np.ndarray):
        return np.stack([u[..., 0], np.cos(u[..., 1]), np.sin(u[..., 1]), u[..., 2]], -1)
    import torch

    return torch.stack([u[..., 0], torch.cos(u[..., 1]), torch.sin(u[..., 1]), u[..., 2]], -1)


def make_mlp():
    import torch

    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(8, 128), torch.nn.SiLU(),
                               torch.nn.Linear(128, 128), torch.nn.SiLU(),
                               torch.nn.Linear(128, 4))


def model_step(model, stats: dict):
    """``step(z (K, 4), u (K, 3)) -> (K, 4)``: z + MLP(normalised [z, encoded u])."""
    import torch

    mu, sd, dsd = (torch.tensor(stats[k], dtype=torch.float32) for k in ("mu", "sd", "dsd"))

    def step(z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        x = (torch.cat([z, encode_action(u)], -1) - mu) / sd
        return z + model(x) * dsd

    return step


def fit_reference(data, cfg, epochs: int, seed: int) -> tuple[dict, dict, float]:
    """Fit the residual MLP on all transitions of `data`; returns (state dict, stats, loss)."""
    import torch

    z = encode_pose(data.poses[:, :-1], cfg.angle_period).reshape(-1, 4)
    zn = encode_pose(data.poses[:, 1:], cfg.angle_period).reshape(-1, 4)
    u = encode_action(data.actions.astype(np.float64)).reshape(-1, 4)
    x = np.concatenate([z, u], 1)
    dz = zn - z
    stats = {"mu": x.mean(0), "sd": x.std(0) + 1e-6, "dsd": dz.std(0) + 1e-6}
    X = torch.tensor((x - stats["mu"]) / stats["sd"], dtype=torch.float32)
    Y = torch.tensor(dz / stats["dsd"], dtype=torch.float32)
    model = make_mlp()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    gen = torch.Generator().manual_seed(seed)
    n_val = max(1, len(X) // 10)
    perm = torch.randperm(len(X), generator=gen)
    val, train = perm[:n_val], perm[n_val:]
    for epoch in range(epochs):
        for idx in torch.randperm(len(train), generator=gen).split(256):
            b = train[idx]
            loss = ((model(X[b]) - Y[b]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        if epoch == epochs // 2:
            for group in opt.param_groups:
                group["lr"] = 1e-3
    with torch.no_grad():
        val_loss = float(((model(X[val]) - Y[val]) ** 2).mean())
    return model.state_dict(), stats, val_loss


# --------------------------------------------------------------------------- driver
@dataclass
class Result:
    design: str
    probes: list
    control: list
    val_loss: float
    seconds: dict


def chunks(n: int, size: int):
    return [(i, min(size, n - i)) for i in range(0, n, size)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--designs", nargs="+", default=list(DESIGNS), choices=DESIGNS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pushes", type=int, default=300, help="random pushes for reach (ii)")
    ap.add_argument("--pairs", type=int, default=30,
                    help="look-alike pairs (i): every tenth reach push is repeated a quarter "
                         "turn on, so reach uses max(pushes, 10 * pairs) pushes")
    ap.add_argument("--trajectories", type=int, default=150, help="training trajectories (iii)")
    ap.add_argument("--steps", type=int, default=10, help="pushes per training trajectory")
    ap.add_argument("--epochs", type=int, default=150, help="reference MLP epochs")
    ap.add_argument("--tasks", type=int, default=40, help="random closed-loop tasks (iii)")
    ap.add_argument("--samples", type=int, default=300, help="MPPI K")
    ap.add_argument("--horizon", type=int, default=8, help="MPPI H")
    ap.add_argument("--sigma", type=float, nargs=3, default=(0.2, 1.0, 0.05),
                    help="MPPI noise variances of p, the push angle and ell (the angle needs "
                         "room: with 0.3 the symmetric world reached 4 of 12 goals, with 1.0 "
                         "12 of 12)")
    ap.add_argument("--max-steps", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2, choices=(1, 2))
    ap.add_argument("--cache", type=Path, default=None,
                    help="folder to keep the collected trajectories in (reused when present)")
    args = ap.parse_args()
    n_probe = max(args.pushes, 10 * args.pairs)

    import torch

    torch.set_num_threads(1)
    from latent_sindy.data import read_sequences
    from latent_sindy.worlds.push.collect import CollectionPlan, collect
    from latent_sindy.worlds.push.config import PushEnvConfig

    t_all = time.perf_counter()
    ctx = mp.get_context("spawn")
    results: dict[str, Result] = {}
    with ctx.Pool(args.workers, initializer=_worker_init) as pool, \
            tempfile.TemporaryDirectory() as tmp:
        cache = args.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        # (i) and (ii): all designs' probes at once, in chunks over the workers
        t0 = time.perf_counter()
        jobs = [(d, args.seed, i, n) for d in args.designs for i, n in chunks(n_probe, 25)]
        probes: dict[str, list] = {d: [] for d in args.designs}
        for job, res in zip(jobs, pool.imap(probe_job, jobs), strict=True):
            probes[job[0]] += res
        t_probe = time.perf_counter() - t0
        for d in args.designs:
            cfg = PushEnvConfig.named(d)
            t0 = time.perf_counter()
            plan = CollectionPlan(trajectories=args.trajectories, steps=args.steps,
                                  seed=args.seed, val_fraction=0.0, test_fraction=0.0, env=cfg)
            path = collect(cache / f"{d}_{args.trajectories}x{args.steps}_s{args.seed}.h5",
                           plan, workers=args.workers)
            t_collect = time.perf_counter() - t0
            t0 = time.perf_counter()
            state, stats, val_loss = fit_reference(read_sequences(path), cfg, args.epochs,
                                                   args.seed)
            t_fit = time.perf_counter() - t0
            t0 = time.perf_counter()
            per = -(-args.tasks // args.workers)
            cjobs = [(d, state, stats, list(range(i, min(i + per, args.tasks))), args.seed,
                      args.samples, args.horizon, tuple(args.sigma), args.max_steps)
                     for i in range(0, args.tasks, per)]
            control = [r for res in pool.map(control_job, cjobs) for r in res]
            results[d] = Result(d, probes[d], control, val_loss,
                                {"collect": t_collect, "fit": t_fit,
                                 "control": time.perf_counter() - t0})
            print(f"[{d}: collected in {t_collect:.0f} s, fitted in {t_fit:.0f} s, "
                  f"controlled in {time.perf_counter() - t0:.0f} s]", flush=True)
    report(results, args, t_probe, time.perf_counter() - t_all)


def report(results: dict[str, Result], args, t_probe: float, total: float) -> None:
    from latent_sindy.worlds.push.config import PushEnvConfig

    print(f"\nworld designs, seed {args.seed}: {args.pushes}+ random pushes each, "
          f"{args.trajectories}x{args.steps} training pushes, {args.tasks} tasks, "
          f"MPPI K={args.samples} H={args.horizon}, {args.max_steps} pushes at most\n")
    head = ["", *results]
    rows = []

    def row(name, fn):
        rows.append([name, *[fn(r) for r in results.values()]])

    row("push / block", lambda r: f"{PushEnvConfig.named(r.design).push} / "
                                  f"{PushEnvConfig.named(r.design).block_look}")
    row("angle period",
        lambda r: f"{math.degrees(PushEnvConfig.named(r.design).angle_period):.0f}°")

    def alike(r):
        pairs = [p for p in r.probes if p["alike"] is not None]
        same = [p for p in pairs if p["alike"]]
        return f"{len(same)}/{len(pairs)} pairs look alike"
    row("(i) θ, θ+90° images identical", alike)

    def diverged(r):
        same = [p for p in r.probes if p["alike"]]
        return rate(sum(p["diverged"] for p in same), len(same))
    row("(i) next images differ", diverged)
    row("(ii) pushes executed", lambda r: rate(sum(p["executed"] for p in r.probes),
                                               len(r.probes)))
    row("(iii) reference val. loss", lambda r: f"{r.val_loss:.4f} (normalised MSE)")
    row("(iii) success, course 0.1 m", lambda r: rate(sum(c["success"] for c in r.control),
                                                      len(r.control)))
    row("(iii) success, strict", lambda r: rate(sum(c["strict"] for c in r.control),
                                                len(r.control)))

    def steps(r):
        s = [c["steps"] for c in r.control if c["success"]]
        return f"{np.mean(s):.1f}" if s else "n/a"
    row("(iii) mean pushes to goal", steps)
    row("(iii) median final distance",
        lambda r: f"{1000 * np.median([c['final_distance'] for c in r.control]):.0f} mm")
    row("time: collect / fit / control",
        lambda r: " / ".join(f"{r.seconds[k]:.0f}" for k in ("collect", "fit", "control"))
        + " s")
    print_table(head, rows)

    print("\n(ii) pushes executed by direction (push direction minus the direction from the "
          "base to the block; 0° = away from the base):\n")
    centres = np.arange(N_BINS) * 360 / N_BINS
    centres = np.where(centres > 180, centres - 360, centres)
    rows = []
    for c in centres:
        def by_dir(r, c=c):
            rel = np.degrees([p["rel"] for p in r.probes])
            sel = np.abs((rel - c + 180) % 360 - 180) < 180 / N_BINS
            ex = np.array([p["executed"] for p in r.probes])[sel]
            return rate(int(ex.sum()), int(sel.sum()))
        rows.append([f"{c:+.0f}°", *[by_dir(r) for r in results.values()]])
    print_table(head, rows)
    print(f"\nprobes {t_probe:.0f} s, total {total:.0f} s")


def print_table(head: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows, strict=True)]
    line = "| " + " | ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)) + " |"
    print(line)
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print("| " + " | ".join(str(x).ljust(w) for x, w in zip(r, widths, strict=True)) + " |")


if __name__ == "__main__":
    main()
